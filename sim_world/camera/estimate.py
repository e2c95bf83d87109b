"""The vehicle's own estimate of its pose, as an autopilot's EKF would publish it.

Each axis' error is a slowly drifting bias (a first-order Gauss-Markov process,
correlation time BIAS_TAU_S, as optical-flow and visual odometry drift) plus white
noise; together they have the stated 1-sigma (BIAS_SHARE of the variance is bias).
North and east take `pose_sigma_m`, down a quarter of it (a rangefinder holds
height better), yaw `yaw_sigma_deg`; roll and pitch `attitude_sigma_deg`, white
(a gyro-accelerometer attitude has no drift worth the name). Seeded, so a run is
reproducible for the same sequence of exposure times.
"""
from __future__ import annotations

import math
import threading

import numpy as np

from .model import CameraModel
from .render import CameraPose, as_pose

BIAS_TAU_S = 30.0
BIAS_SHARE = 0.8


class PoseEstimator:
    def __init__(self, model: CameraModel, seed: int = 0) -> None:
        yaw = math.radians(model.yaw_sigma_deg)
        self.sigma = np.array([model.pose_sigma_m, model.pose_sigma_m, model.pose_sigma_m / 4, yaw])
        self.attitude_sigma = math.radians(model.attitude_sigma_deg)
        self._rng = np.random.default_rng([seed, 0x5EED])
        self._bias: np.ndarray | None = None
        self._t: float | None = None
        self._lock = threading.Lock()

    @property
    def exact(self) -> bool:
        return not (self.sigma.any() or self.attitude_sigma)

    def estimate(self, truth: CameraPose | tuple, time_s: float) -> CameraPose:
        """The published pose for the true `truth` at `time_s` (simulated seconds)."""
        p = as_pose(truth)
        if self.exact:
            return p
        with self._lock:
            sb, sw = self.sigma * math.sqrt(BIAS_SHARE), self.sigma * math.sqrt(1 - BIAS_SHARE)
            if self._bias is None or self._t is None:
                self._bias = sb * self._rng.standard_normal(4)
            else:
                a = math.exp(-max(0.0, time_s - self._t) / BIAS_TAU_S)
                self._bias = a * self._bias + math.sqrt(1 - a * a) * sb * self._rng.standard_normal(4)
            self._t = time_s
            err = self._bias + sw * self._rng.standard_normal(4)
            att = self.attitude_sigma * self._rng.standard_normal(2)
        yaw = (p.yaw_rad + err[3] + math.pi) % (2 * math.pi) - math.pi
        return CameraPose(p.north_m + err[0], p.east_m + err[1], min(p.down_m + err[2], -1e-3), yaw,
                          p.roll_rad + att[0], p.pitch_rad + att[1])
