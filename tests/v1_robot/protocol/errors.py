"""Errors that carry a one-line message meant for the user.

Every part raises a subclass of `UavRobotsError` for bad input; the CLI prints
`error: <message>` and exits 2 instead of showing a traceback.
"""


class UavRobotsError(Exception):
    """A problem with the user's input or the environment, explained in one line."""


class MapError(UavRobotsError):
    """A map or scenario file is missing or malformed, or a placement is impossible."""


class ProtocolError(UavRobotsError):
    """Bytes on a key do not decode to the expected message (garbage, wrong schema or version)."""


class PlanningError(UavRobotsError):
    """No valid plan: unreachable goal, unknown planner, time limit hit, incomplete method."""


class MissionError(UavRobotsError):
    """The mission cannot go on: a process died, a robot was lost, the vehicle refused."""
