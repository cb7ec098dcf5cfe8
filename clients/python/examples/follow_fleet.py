"""Print every transition of the `example` fleet for 20 seconds, then each robot's state."""

from __future__ import annotations

import time

import lessmap_client


def main() -> None:
    """Follow the fleet, then query the states."""
    with lessmap_client.connect() as conn:
        # history=True: transitions published before we joined come first, then live ones.
        with conn.subscribe_transitions("example", history=True) as sub:
            deadline = time.monotonic() + 20.0
            while (left := deadline - time.monotonic()) > 0:
                t = sub.recv(timeout_s=left)
                if t is None:
                    break
                print(  # noqa: T201
                    f"{t.robot}: frame {t.seq} {t.reason} ncut={t.ncut} lambda2={t.lambda2} "
                    f"closed submap {t.closed.id} ({len(t.closed.features)} features)"
                )
        for state in conn.states("example"):
            print(state.robot, state.frames_applied, "frames,", state.transitions, "transitions")  # noqa: T201


if __name__ == "__main__":
    main()
