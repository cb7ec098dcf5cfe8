"""Print every transition of the `example` fleet for 20 seconds, then each robot's state."""

from __future__ import annotations

from lessmap_client import FleetClient


def main() -> None:
    """Follow the fleet, then query the states."""
    with FleetClient("example") as fleet:
        for t in fleet.transitions(timeout_s=20):
            print(  # noqa: T201
                f"{t.robot}: frame {t.seq} {t.reason} ncut={t.ncut} lambda2={t.lambda2} "
                f"closed submap {t.closed.id} ({len(t.closed.features)} features)"
            )
        for state in fleet.states():
            print(state.robot, state.frames_applied, "frames,", state.transitions, "transitions")  # noqa: T201


if __name__ == "__main__":
    main()
