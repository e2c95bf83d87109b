"""The navigation estimate: what the autopilot believes of its own position and attitude.

A real autopilot knows its state only through its estimator (PX4's EKF2): its position is off
by an error that wanders slowly (GPS drift, a vision system's) plus noise on every sample. Here
the estimate is the truth plus a horizontal bias (a first-order Gauss-Markov process per axis, of
standard deviation `position_bias_m` and correlation time BIAS_TAU_S, on simulated time; no
vertical one, so that the ground stays where the land detector finds it) plus white
noise (`position_noise_m`, `attitude_noise_deg`) drawn afresh for every message. The autopilot
flies in the estimate's frame (it holds where it believes it is, so the airframe sits off by
the bias), telemetry reports the estimate, and the world's camera sees the truth. With the
options at 0 (the default) the estimate is the truth.
"""
from __future__ import annotations

import math
import random
import threading

from .config import VehicleConfig
from .motion import Vec3

BIAS_TAU_S = 300.0  # how long the position error takes to wander to a new value (a GPS's drift: minutes)
KNOT_S = 1.0        # the bias is drawn once a simulated second and interpolated between: a drift, not a jitter


class Estimator:
    def __init__(self, config: VehicleConfig, lock: threading.RLock):
        self._lock = lock
        self._noise = config.position_noise_m
        self._sigma = config.position_bias_m
        self._attitude_noise = math.radians(config.attitude_noise_deg)
        self._rng = random.Random(config.seed * 7919 + 101)
        start = [self._rng.gauss(0.0, self._sigma) if self._sigma else 0.0 for _ in range(2)]
        self._knots = (start, self._step(start))  # the bias now and a second later
        self._since = 0.0
        self._bias = start + [0.0]

    @property
    def exact(self) -> bool:
        return not (self._noise or self._sigma or self._attitude_noise)

    def _step(self, bias: list[float]) -> list[float]:
        """The Gauss-Markov bias one knot later."""
        keep = math.exp(-KNOT_S / BIAS_TAU_S)
        spread = self._sigma * math.sqrt(1.0 - keep * keep)
        return [b * keep + self._rng.gauss(0.0, spread) for b in bias]

    def advance(self, dt: float) -> None:
        """Let the bias wander for `dt` simulated seconds (smoothly: the controller follows its estimate, and a
        bias that jumped every physics step would shake the airframe)."""
        if not self._sigma or dt <= 0:
            return
        with self._lock:
            self._since += dt
            while self._since >= KNOT_S:
                self._since -= KNOT_S
                self._knots = (self._knots[1], self._step(self._knots[1]))
            f = self._since / KNOT_S
            a, b = self._knots
            self._bias = [a[i] + (b[i] - a[i]) * f for i in range(2)] + [0.0]

    @property
    def bias(self) -> Vec3:
        """The estimate's slowly wandering error (NED m): estimate = truth + bias (+ noise)."""
        with self._lock:
            return tuple(self._bias)

    def believed(self, true_pos: Vec3) -> Vec3:
        """Where the autopilot believes it is (the bias only: the controller's filtered view)."""
        b = self.bias
        return true_pos[0] + b[0], true_pos[1] + b[1], true_pos[2] + b[2]

    def truth_of(self, believed_pos: Vec3) -> Vec3:
        """The true point the autopilot reaches when it flies to `believed_pos`."""
        b = self.bias
        return believed_pos[0] - b[0], believed_pos[1] - b[1], believed_pos[2] - b[2]

    def position(self, true_pos: Vec3) -> Vec3:
        """One reported position sample: believed, plus white noise."""
        n, e, d = self.believed(true_pos)
        if not self._noise:
            return n, e, d
        with self._lock:
            g = self._rng.gauss
            return n + g(0.0, self._noise), e + g(0.0, self._noise), d + g(0.0, self._noise)

    def attitude(self, roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
        """One reported attitude sample (radians), yaw wrapped to [-pi, pi)."""
        if self._attitude_noise:
            with self._lock:
                g = self._rng.gauss
                roll, pitch, yaw = (roll + g(0.0, self._attitude_noise), pitch + g(0.0, self._attitude_noise),
                                    yaw + g(0.0, self._attitude_noise))
        return roll, pitch, (yaw + math.pi) % (2 * math.pi) - math.pi

    def accuracy(self) -> tuple[float, float]:
        """(horizontal, vertical) 1-sigma accuracy the estimator claims, metres (ESTIMATOR_STATUS)."""
        spread = math.hypot(self._noise, self._sigma)
        return max(0.05, spread * math.sqrt(2)), max(0.05, spread)
