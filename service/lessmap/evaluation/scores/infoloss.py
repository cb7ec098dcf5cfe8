"""Information-loss ratio e of a partition (LESS-mapping §4.1, Eq. 5).

    e = Σ_{(i,j): C(i) ∩ C(j) = ∅} |H(i,j)| / Σ_{(a,b)} |H(a,b)|

H is the landmark information matrix of the 2-D SLAM problem (Jᵀ Ω J at the data set's
poses, poses marginalized out by a sparse Schur complement). Choices the paper leaves open
(in full: ``docs/design/evaluation.md``):

1. Gauge: the first pose gets a prior ``anchor_information · I₃``, far above any data set's.
2. Entries: every entry of a 2×2 landmark block counts by its absolute value; diagonal
   blocks count in the denominator only, so one submap gives e = 0.
3. Membership: a landmark belongs to every submap that observed it; a pair is lost when the
   two share none (``exclusive=True``: the submap that saw it most often only).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import sparse
from scipy.sparse import linalg as splinalg

from lessmap.errors import DatasetError

if TYPE_CHECKING:
    from collections.abc import Collection, Mapping, Sequence

    from numpy.typing import NDArray

    from lessmap.evaluation.data.dataset import SlamProblem

POSE_DIM = 3
LANDMARK_DIM = 2
DEFAULT_ANCHOR_INFORMATION = 1e9
_SCHUR_COLUMNS = 256  # columns of H_pl solved at once: bounds memory to (3m × 256) floats


@dataclass(frozen=True, slots=True, kw_only=True)
class LandmarkInformation:
    """The landmark information matrix H with the poses marginalized (n landmarks)."""

    landmark_ids: NDArray[np.int64]  # (n,) ascending; landmark i owns rows 2i, 2i + 1
    matrix: NDArray[np.float64]  # (2n, 2n) symmetric
    block_mass: NDArray[np.float64]  # (n, n) Σ |H| over each 2×2 block
    anchor_information: float
    unit_information_edges: int  # edges with no information in the data (unit used)


def _upper_to_full(upper: NDArray[np.float64], dim: int) -> NDArray[np.float64]:
    """Expand row-major upper triangles (k, dim(dim+1)/2) to symmetric (k, dim, dim)."""
    rows, cols = np.triu_indices(dim)
    full = np.zeros((upper.shape[0], dim, dim))
    full[:, rows, cols] = upper
    full[:, cols, rows] = upper
    return full


def _landmark_jacobians(problem: SlamProblem) -> NDArray[np.float64]:
    """J of h(x_p, l) = R(θ)ᵀ (l - t) w.r.t. [x, y, θ, l_x, l_y], shape (k, 2, 5)."""
    x, y, theta = problem.poses[problem.obs_pose].T
    lx, ly = problem.landmarks[problem.obs_landmark].T
    dx, dy = lx - x, ly - y
    cos, sin = np.cos(theta), np.sin(theta)
    jac = np.empty((cos.size, 2, 5))
    jac[:, 0] = np.column_stack([-cos, -sin, -sin * dx + cos * dy, cos, sin])
    jac[:, 1] = np.column_stack([sin, -cos, -cos * dx - sin * dy, -sin, cos])
    return jac


def _odometry_jacobians(problem: SlamProblem) -> NDArray[np.float64]:
    """J of [R(θ_i)ᵀ (t_j - t_i), θ_j - θ_i] w.r.t. [x_i, y_i, θ_i, x_j, y_j, θ_j], (q, 3, 6)."""
    xi, yi, ti = problem.poses[problem.odo_from].T
    xj, yj, _ = problem.poses[problem.odo_to].T
    dx, dy = xj - xi, yj - yi
    cos, sin = np.cos(ti), np.sin(ti)
    zero, one = np.zeros_like(cos), np.ones_like(cos)
    jac = np.empty((cos.size, 3, 6))
    jac[:, 0] = np.column_stack([-cos, -sin, -sin * dx + cos * dy, cos, sin, zero])
    jac[:, 1] = np.column_stack([sin, -cos, -cos * dx - sin * dy, -sin, cos, zero])
    jac[:, 2] = np.column_stack([zero, zero, -one, zero, zero, one])
    return jac


def information_matrix(
    problem: SlamProblem, anchor_information: float = DEFAULT_ANCHOR_INFORMATION
) -> sparse.csc_array:
    """Assemble the full Hessian Jᵀ Ω J with the first-pose prior.

    Args:
        problem: the linearized problem (m poses, n landmarks).
        anchor_information: weight of the prior ``anchor_information · I₃`` on pose 0.

    Returns:
        Symmetric CSC matrix of shape (3m + 2n, 3m + 2n): poses first (3 rows each, in
        frame order), then landmarks (2 rows each, in ``problem.landmark_ids`` order).
    """
    if not anchor_information > 0:
        msg = f"anchor_information must be positive, got {anchor_information!r}"
        raise ValueError(msg)
    m, n = problem.poses.shape[0], problem.landmark_ids.size
    offset = POSE_DIM * m
    size = offset + LANDMARK_DIM * n
    blocks: list[tuple[NDArray[np.float64], NDArray[np.int64]]] = []

    jac = _landmark_jacobians(problem)
    omega = _upper_to_full(problem.obs_information, 2)
    p3, l2 = POSE_DIM * problem.obs_pose, offset + LANDMARK_DIM * problem.obs_landmark
    index = np.column_stack([p3, p3 + 1, p3 + 2, l2, l2 + 1])
    blocks.append((np.einsum("kai,kab,kbj->kij", jac, omega, jac), index))

    jac = _odometry_jacobians(problem)
    omega = _upper_to_full(problem.odo_information, 3)
    fi, ti = POSE_DIM * problem.odo_from, POSE_DIM * problem.odo_to
    index = np.column_stack([fi, fi + 1, fi + 2, ti, ti + 1, ti + 2])
    blocks.append((np.einsum("kai,kab,kbj->kij", jac, omega, jac), index))

    anchor = np.arange(POSE_DIM, dtype=np.int64)[None, :]
    blocks.append((anchor_information * np.eye(POSE_DIM)[None], anchor))

    rows = np.concatenate([np.broadcast_to(i[:, :, None], h.shape).ravel() for h, i in blocks])
    cols = np.concatenate([np.broadcast_to(i[:, None, :], h.shape).ravel() for h, i in blocks])
    data = np.concatenate([h.ravel() for h, _ in blocks])
    h = sparse.coo_array((data, (rows, cols)), shape=(size, size)).tocsc()
    return sparse.csc_array(0.5 * (h + h.T))  # exactly symmetric despite rounding in Jᵀ Ω J


def marginalize(h: sparse.csc_array, keep_from: int) -> NDArray[np.float64]:
    """Schur complement on the trailing block: H_ll - H_lp H_pp⁻¹ H_pl.

    Args:
        h: symmetric matrix, shape (N, N); rows ``[0, keep_from)`` are marginalized.
        keep_from: first kept row.

    Returns:
        The dense symmetric marginal information of rows ``[keep_from, N)``.

    Raises:
        DatasetError: H_pp is singular (a pose the constraints do not determine).
    """
    h = sparse.csc_array(h)
    h_pp = h[:keep_from, :keep_from].tocsc()
    h_pl = h[:keep_from, keep_from:].tocsc()
    marginal = h[keep_from:, keep_from:].toarray()
    if keep_from == 0:
        return marginal
    try:
        lu = splinalg.splu(h_pp)
    except RuntimeError as exc:
        msg = f"the pose block of the information matrix is singular ({exc})"
        raise DatasetError(msg) from exc
    h_lp = h_pl.T.tocsr()
    for start in range(0, marginal.shape[1], _SCHUR_COLUMNS):
        stop = min(start + _SCHUR_COLUMNS, marginal.shape[1])
        solved = lu.solve(h_pl[:, start:stop].toarray())
        marginal[:, start:stop] -= h_lp @ solved
    if not np.all(np.isfinite(marginal)):
        msg = "the pose block of the information matrix is singular (non-finite marginal)"
        raise DatasetError(msg)
    symmetric: NDArray[np.float64] = 0.5 * (marginal + marginal.T)
    return symmetric


def block_mass(matrix: NDArray[np.float64], dim: int = LANDMARK_DIM) -> NDArray[np.float64]:
    """Return Σ |H| over each dim×dim block, shape (N/dim, N/dim)."""
    n = matrix.shape[0] // dim
    mass: NDArray[np.float64] = np.abs(matrix).reshape(n, dim, n, dim).sum(axis=(1, 3))
    return mass


def landmark_information(
    problem: SlamProblem, anchor_information: float = DEFAULT_ANCHOR_INFORMATION
) -> LandmarkInformation:
    """Build H, marginalize the poses and return the landmark information matrix."""
    h = information_matrix(problem, anchor_information)
    matrix = marginalize(h, POSE_DIM * problem.poses.shape[0])
    return LandmarkInformation(
        landmark_ids=problem.landmark_ids,
        matrix=matrix,
        block_mass=block_mass(matrix),
        anchor_information=anchor_information,
        unit_information_edges=problem.unit_information_edges,
    )


def landmark_submaps(
    frames: Sequence[Collection[int]],
    labels: Sequence[int] | NDArray[np.int64],
    *,
    exclusive: bool = False,
) -> dict[int, frozenset[int]]:
    """Map each landmark to the submaps whose frames observed it.

    Args:
        frames: the feature IDs of each frame, in order.
        labels: the submap of each frame (same length).
        exclusive: give each landmark one submap only, the one whose frames observed it
            most often (ties: the earliest). Eq. 5 read literally, with one cluster C(i)
            per landmark; the default rule (all observing submaps) is the main figure.
    """
    if len(frames) != len(labels):
        msg = f"{len(frames)} frames but {len(labels)} submap labels"
        raise ValueError(msg)
    sightings: dict[int, dict[int, int]] = {}
    for features, label in zip(frames, labels, strict=True):
        for feature in set(features):
            per_submap = sightings.setdefault(int(feature), {})
            per_submap[int(label)] = per_submap.get(int(label), 0) + 1
    if exclusive:
        return {
            feature: frozenset([max(counts, key=lambda s: (counts[s], -s))])
            for feature, counts in sightings.items()
        }
    return {feature: frozenset(counts) for feature, counts in sightings.items()}


def information_loss(info: LandmarkInformation, membership: Mapping[int, Collection[int]]) -> float:
    """Return e (Eq. 5) of a partition given as landmark → submaps (see the module rules).

    Raises:
        DatasetError: a landmark of H has no submap (it was never observed in a frame).
    """
    ids = info.landmark_ids.tolist()
    missing = [lid for lid in ids if not membership.get(lid)]
    if missing:
        msg = f"{len(missing)} landmarks of H are in no submap, e.g. {missing[:5]}"
        raise DatasetError(msg)
    submap_index: dict[int, int] = {}
    rows, cols = [], []
    for row, lid in enumerate(ids):
        for submap in membership[lid]:
            rows.append(row)
            cols.append(submap_index.setdefault(submap, len(submap_index)))
    member = sparse.csr_array(
        (np.ones(len(rows)), (rows, cols)), shape=(len(ids), len(submap_index))
    )
    shared = (member @ member.T).toarray() > 0
    total = float(info.block_mass.sum())
    if total == 0.0:
        return 0.0
    return float(info.block_mass[~shared].sum()) / total
