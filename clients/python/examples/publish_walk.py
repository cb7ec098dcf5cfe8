"""A robot walks from one room into another; lessmap should report one transition.

Run `lessmap serve` first, then `python follow_fleet.py` in another terminal, then this.
"""

from __future__ import annotations

import random
import time

import lessmap_client

ROOM_A = range(20)  # landmark IDs on the walls of room A
ROOM_B = range(100, 120)  # and of room B


def main() -> None:
    """Publish 40 frames in room A, a door, then 40 frames in room B."""
    rng = random.Random(1)
    with lessmap_client.connect() as conn:  # tcp/127.0.0.1:7447, the router of `lessmap serve`
        if not conn.wait_for_service(10.0):
            msg = "no lessmap service is running (start `lessmap serve`)"
            raise SystemExit(msg)
        with conn.robot("example", "walker") as robot:  # closing sends the SessionEnd
            for step in range(84):
                if step < 40:
                    seen = rng.sample(ROOM_A, 12)
                elif step < 44:  # in the door: a bit of both rooms
                    seen = rng.sample(ROOM_A, 4) + rng.sample(ROOM_B, 4)
                else:
                    seen = rng.sample(ROOM_B, 12)
                seq = robot.publish(seen)
                print(f"frame {seq}: {len(seen)} features")  # noqa: T201
                time.sleep(0.05)


if __name__ == "__main__":
    main()
