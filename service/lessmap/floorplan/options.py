"""Settings of a floor-plan run: sensor profiles, walking, the fleet. Standard library only.

The command line reads these for its choices and defaults without loading numpy or scipy.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["PROFILES", "FloorplanOptions", "SensorProfile", "TourOptions"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SensorProfile:
    """What a sensor sees: field of view, range, and the landmarks it picks on walls."""

    name: str
    fov_deg: float  # centred on the heading; 360 sees all around
    range_m: float
    wall_spacing_m: float  # landmarks along the walls, at least this far apart
    corners: bool = False  # add the corners of the walls
    layers: int = 1  # landmarks per wall site (a camera sees features up a wall's height)
    detection_prob: float = 0.9  # per visible landmark and frame
    false_association_prob: float = 0.005  # per detection: reported under a random other id
    max_incidence_deg: float = 80.0  # walls seen more obliquely than this give nothing


PROFILES: dict[str, SensorProfile] = {
    profile.name: profile
    for profile in (
        # A SICK LMS1xx / Hokuyo UTM-30LX class scanner with a line or point extractor.
        SensorProfile(name="laser270", fov_deg=270.0, range_m=8.0, wall_spacing_m=0.5),
        SensorProfile(name="laser360", fov_deg=360.0, range_m=8.0, wall_spacing_m=0.5),
        # Corners and a few wall points: a handful of features a frame.
        SensorProfile(name="sparse", fov_deg=360.0, range_m=8.0, wall_spacing_m=2.5, corners=True),
        # Texture every 0.1 m along the walls and at 12 heights up them: hundreds a frame.
        SensorProfile(name="camera", fov_deg=90.0, range_m=7.0, wall_spacing_m=0.1, layers=12),
    )
}


@dataclass(frozen=True, slots=True, kw_only=True)
class TourOptions:
    """How robots walk."""

    speed_m_per_frame: float = 0.1
    rate_hz: float = 10.0  # frames a second: converts the turn rate to a turn per frame
    turn_rate_deg_s: float = 90.0
    lookahead_m: float = 0.4  # the heading points at the path this far ahead
    points_per_room: tuple[int, int] = (1, 3)  # points walked to in each room, drawn
    nearest_rooms: int = 3  # the next room is one of this many nearest unvisited
    max_frames: int | None = None  # per robot


@dataclass(frozen=True, slots=True, kw_only=True)
class FloorplanOptions:
    """Fleet, sensor and walking settings of a floor-plan run."""

    sensor: SensorProfile = PROFILES["laser270"]
    robots: int = 2
    seed: int = 0
    robot_radius_m: float = 0.2
    tour: TourOptions = field(default_factory=TourOptions)
    block_m: float = 4.0  # waypoint squares on a map without rooms
