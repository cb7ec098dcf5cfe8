"""What the room-map rules can reach on the benchmark's floor plans, whatever the segmentation.

    python -m benchmarks.roommap_ceiling                 # ../shared/floorplans, 400 poses
    python -m benchmarks.roommap_ceiling --poses 100 --furnished --join-across-doorways

Run from the repository root. Per map, ``--poses`` poses are drawn uniformly (seeded) over
the ground-truth rooms' cells and labelled with their true room, a robot that went
everywhere and segmented perfectly; the room map (``lessmap.floorplan.roommap``) is scored
with the benchmark's per-room precision and recall, with rule 3 (doorway regions) and
without it. The doorway regions alone (no poses) are the geometry's own segmentation. The
last column labels every free cell with its true room, and furniture by rule 6: the best
such a map can score (with furniture, the cells under a piece joined to a wall count in
the ground truth and in no such map).
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

from lessmap.floorplan.grid import load_grid, room_labels
from lessmap.floorplan.metric import precision_recall
from lessmap.floorplan.roommap import RoomMapParams, nearest_samples, passage_regions, room_map

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    """Print one row per map and the means, precision / recall in percent."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.roommap_ceiling")
    parser.add_argument("--floorplans", type=Path, default=ROOT / ".." / "shared" / "floorplans")
    parser.add_argument("--poses", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--furnished", action="store_true", help="the maps with furniture")
    parser.add_argument(
        "--join-across-doorways", action="store_true", help="rule 5 off, as in lessmap rooms"
    )
    parser.add_argument(
        "--no-furniture-rooms", action="store_true", help="rule 6 off: furniture unlabelled"
    )
    parser.add_argument(
        "--furniture-max-m",
        type=float,
        default=RoomMapParams().furniture_max_m,
        help="free-standing obstacles up to this long are furniture (0: off)",
    )
    args = parser.parse_args(argv)
    names = sorted(
        p.name.removesuffix("_gt_segmentation.png")
        for p in args.floorplans.glob("*_gt_segmentation.png")
    )
    if not names:
        sys.stderr.write(f"no *_gt_segmentation.png in {args.floorplans}\n")
        return 1
    params = RoomMapParams(
        split_at_doorways=not args.join_across_doorways,
        furniture_max_m=args.furniture_max_m,
        furniture_rooms=not args.no_furniture_rooms,
    )
    columns = ("nearest pose", "with doorways", "doorways alone", "true rooms")
    print("| map | " + " | ".join(columns) + " |")
    print("|---|" + "---|" * len(columns))
    scores: dict[str, list[tuple[float, float]]] = {c: [] for c in columns}
    for name in names:
        suffix = "_furnitures" if args.furnished else ""
        grid = load_grid(args.floorplans / f"{name}{suffix}.png")
        truth = room_labels(args.floorplans / f"{name}_gt_segmentation.png", min_room_m2=0.0)
        rng = np.random.default_rng(args.seed)
        cells = np.argwhere((truth > 0) & grid.free)
        pick = cells[rng.choice(len(cells), size=min(args.poses, len(cells)), replace=False)]
        xy = grid.cell_to_xy(pick[:, 0].astype(float), pick[:, 1].astype(float))
        labels = truth[pick[:, 0], pick[:, 1]].astype(np.int64)
        field = nearest_samples(grid, xy, params)
        regions = passage_regions(grid, params)
        assert regions is not None  # the default door width: rule 3 is on
        with_doorways = room_map(field, labels, regions, params)
        free_truth = np.where(grid.free, truth, 0).astype(np.int32)
        if regions.furniture is not None:
            free_truth = regions.furniture.label(free_truth)
        maps = (room_map(field, labels), with_doorways, regions.doorways, free_truth)
        row = []
        for column, labelled in zip(columns, maps, strict=True):
            score = precision_recall(labelled, truth)
            scores[column].append((score.precision, score.recall))
            row.append(f"{100 * score.precision:.1f} / {100 * score.recall:.1f}")
        print(f"| {name} | " + " | ".join(row) + " |")
    means = []
    for pairs in scores.values():
        precision = 100 * statistics.fmean(p for p, _ in pairs)
        recall = 100 * statistics.fmean(r for _, r in pairs)
        means.append(f"{precision:.1f} / {recall:.1f}")
    print("| mean | " + " | ".join(means) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
