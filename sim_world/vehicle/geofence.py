"""The geofence, as PX4's GF_MAX_HOR_DIST / GF_MAX_VER_DIST draw it: a cylinder around home
(0 disables a limit). Targets beyond it are refused or pulled back onto it; a vehicle
beyond it has breached it (GF_ACTION says what then)."""
from __future__ import annotations

import math

from .motion import Vec3
from .params import Params

FENCE_SLACK_M = 0.05  # a vehicle parked on the fence (a clamped target) is not outside it


class Geofence:
    def __init__(self, params: Params):
        self._params = params

    def _limits(self) -> tuple[float, float]:
        hor, ver = self._params.get("GF_MAX_HOR_DIST"), self._params.get("GF_MAX_VER_DIST")
        return (hor if hor > 0 else math.inf), (ver if ver > 0 else math.inf)

    @property
    def enabled(self) -> bool:
        return any(math.isfinite(limit) for limit in self._limits())

    def violation(self, point: Vec3) -> str | None:
        """Why `point` (NED from home) is outside the fence, None if inside."""
        hor, ver = self._limits()
        dist, alt = math.hypot(point[0], point[1]), -point[2]
        if dist > hor + FENCE_SLACK_M:
            return f"{dist:.0f} m from home, max {hor:g} m"
        if alt > ver + FENCE_SLACK_M:
            return f"{alt:.0f} m high, max {ver:g} m"
        return None

    def clamp(self, point: Vec3) -> Vec3:
        """`point` pulled back onto the fence along the line from home."""
        hor, ver = self._limits()
        n, e, d = point
        dist = math.hypot(n, e)
        if dist > hor:
            n, e = n * hor / dist, e * hor / dist
        return n, e, max(d, -ver)
