"""What one mission can hold: how many robots the camera tells apart, how large a floor the survey covers.

The fleet: robot i carries ArUco marker i of DICT_4X4_1000 (sim_world.camera draws it,
uav_agent.perception.markers reads it; the landmarks use DICT_5X5_1000, ids of their own),
so a fleet has at most 1,000 robots, ids 0..999.

The floor: a mission's cost grows with its cells more than with its fleet. The survey takes an
image per ~30,000 cells (19 px a cell on the 12 MP camera, from ~100 m) and flies a lawn-mower
over them, about 5 m of flight per 1,000 cells of 1 m: the paper's 450x450 floor takes 9 images
and 1.2 km, 1800x1800 108 images and 16.6 km, 4200x4200 567 images and 89 km
(`uav_agent.survey.survey_poses`). The vehicle's pack lasts ~2,200 s at the 20 m/s survey speed
(44 km; `sim_world/vehicle/params.py`), and a repair's fresh look may fly the whole survey again,
so a mission's floor is at most 1800x1800 cells (16 times the paper's), whose survey takes 37 %
of the pack. Planning and the world grow more slowly (docs/getting-started.md, "Limits").
"""
from __future__ import annotations

from protocol.errors import MapError, UavRobotsError
from protocol.grid import MAX_GRID_SIDE
from protocol.mapfile import check_size

MARKER_FAMILY = "DICT_4X4_1000"   # the robots' markers
MAX_FLEET = 1000                  # ids 0..999: the dictionary's markers
MAX_FLOOR_CELLS = 1800 * 1800     # a mission's floor (a plan alone may be larger: protocol.mapfile.MAX_CELLS)


def check_fleet(robots: int, option: str = "--robots") -> None:
    """One line naming the reason when `robots` is more than a mission's camera can tell apart."""
    if robots > MAX_FLEET:
        raise UavRobotsError(f"{option} {robots}: a fleet has at most {MAX_FLEET} robots: the UAV's camera "
                             f"tells robot i by ArUco marker i of {MARKER_FAMILY}, ids 0..{MAX_FLEET - 1}")


def check_floor(width: int, height: int, what: str) -> None:
    """One line when a mission's floor is larger than its survey covers (before it is built or read)."""
    if max(width, height) <= MAX_GRID_SIDE and width * height > MAX_FLOOR_CELLS:
        raise MapError(f"{what}: a {width}x{height} floor is {width * height:,} cells, more than a mission's "
                       f"{MAX_FLOOR_CELLS:,} (1800x1800, 16 times the paper's 450x450: a larger survey leaves the "
                       "vehicle's battery no room for a repair's fresh look)")
    check_size(width, height, what)   # the protocol's cells a side
