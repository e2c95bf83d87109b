"""The airframe: where the vehicle is, how it moves toward what the autopilot asks, and
whether it stands on the ground.

The physics is kinematic: the vehicle moves straight toward its target (or at the
velocity it is given) within its horizontal speed and climb limits and, as PX4's
trajectory generator does, within acceleration and jerk limits (MPC_ACC_HOR,
MPC_ACC_UP_MAX / _DOWN_MAX, MPC_JERK_AUTO): a speed change ramps, and the vehicle
brakes in time to stop on its target (`step_limited`, motion.py). Without limits (a setpoint's
default) it moves as `step_toward` says, every speed change instant. Its attitude follows from that motion as a
multicopter's does: the tilt that produces the horizontal acceleration
(atan(a / g), forward acceleration = nose down, rightward = roll right, capped
at MAX_TILT_DEG), the acceleration being each step's velocity change spread over
the attitude loop's lag TILT_TAU_S (first order); plus, in the air,
a small seeded hover wobble (two incommensurate sines per axis). A camera fixed
to the body (sim_world.camera, `gimbal=0`) sees the floor through this attitude. `time_scale`
simulated seconds pass per wall second, so a demo need not wait for real flight.

Frames: local NED with the origin at home (the warehouse grid's top-left corner, at
ground level; see protocol/geo.py). Altitude is positive up from home; `down` is
its negative.
"""
from __future__ import annotations

import enum
import math
import random
import threading
import time
from typing import Callable, NamedTuple, Protocol

from .journal import Journal
from .motion import Motion, Setpoint, Vec3, step_limited, step_toward, step_yaw

GROUND_EPS_M = 0.01  # at or below this altitude the vehicle touches the ground
LIFTOFF_ALT_M = 0.1  # above this altitude the land detector calls it airborne
YAW_RATE_RAD_S = math.radians(90.0)
GRAVITY_M_S2 = 9.81
TERMINAL_SPEED_M_S = 20.0
# A touchdown faster than this is a crash, not a landing (PX4 lands at MPC_LAND_SPEED, 0.7 m/s, and its
# land detector calls nothing faster than LNDMC_Z_VEL_MAX, 0.5 m/s, landed): the journal records
# "hit the ground at X m/s", falling (motors off) or flown into the ground alike.
HARD_TOUCHDOWN_M_S = 3.0
PHYSICS_PERIOD_S = 0.02  # wall time between steps
MAX_STEP_S = 0.05        # a longer step (a high time scale) is taken in substeps: the limits need short ones
TILT_TAU_S = 0.2         # attitude loop's lag: how long a change of velocity takes to fly
MAX_TILT_DEG = 20.0      # PX4 allows MPC_TILTMAX_AIR = 45; a survey flight stays well under it


class Contact(enum.Enum):
    """A change the land detector saw in one step; the value is what the journal records."""

    LIFTOFF = "liftoff"
    TOUCHDOWN = "landed"


class State(NamedTuple):
    """One consistent reading of the airframe (NED metres, m/s, radians, rad/s)."""

    pos: Vec3
    vel: Vec3
    yaw: float
    roll: float = 0.0
    pitch: float = 0.0
    roll_rate: float = 0.0
    pitch_rate: float = 0.0


def tilt_for(accel_n: float, accel_e: float, yaw: float) -> tuple[float, float]:
    """(roll, pitch) that point the thrust so as to accelerate horizontally by (accel_n, accel_e)."""
    fwd = accel_n * math.cos(yaw) + accel_e * math.sin(yaw)
    right = -accel_n * math.sin(yaw) + accel_e * math.cos(yaw)
    cap = math.radians(MAX_TILT_DEG)
    roll = math.atan2(right, GRAVITY_M_S2)
    pitch = -math.atan2(fwd, GRAVITY_M_S2)
    return max(-cap, min(cap, roll)), max(-cap, min(cap, pitch))


class Wobble:
    """A hover's small attitude wobble: per axis two sines of seeded frequency and phase."""

    def __init__(self, amplitude_deg: float, seed: int) -> None:
        rng = random.Random(seed * 7919 + 17)
        self.amplitude = math.radians(amplitude_deg)
        self.terms = [[(w, rng.uniform(f0, f1) * 2 * math.pi, rng.uniform(0, 2 * math.pi))
                       for w, f0, f1 in ((0.7, 0.2, 0.5), (0.3, 0.8, 1.6))] for _ in range(2)]

    def at(self, t: float) -> tuple[float, float]:
        if not self.amplitude:
            return 0.0, 0.0
        roll, pitch = (self.amplitude * sum(w * math.sin(om * t + ph) for w, om, ph in axis) for axis in self.terms)
        return roll, pitch


class Pilot(Protocol):
    """What flies the airframe; asked under the lock, at every physics step."""

    def setpoint(self, dt: float, wall_now: float) -> Setpoint | None:
        """Where to go this step; None with the motors off (the airframe falls)."""

    def on_moved(self, setpoint: Setpoint) -> None:
        """The airframe has flown toward `setpoint` (before the land detector looks)."""

    def on_contact(self, contact: Contact | None) -> None:
        """The land detector's verdict for this step, None if nothing changed."""


class Dynamics:
    """The airframe's state and its physics step. `ceiling()` is the highest altitude it
    may reach (a parameter, so it is asked at every use)."""

    def __init__(self, lock: threading.RLock, journal: Journal, ceiling: Callable[[], float],
                 wobble_deg: float = 0.0, seed: int = 0, heading_rad: float = 0.0):
        self._lock = lock
        self._journal = journal
        self._ceiling = ceiling
        self._pos: Vec3 = (0.0, 0.0, 0.0)
        self._vel: Vec3 = (0.0, 0.0, 0.0)
        self._cmd_acc: Vec3 = (0.0, 0.0, 0.0)  # the trajectory's acceleration (limited setpoints)
        self._yaw = (heading_rad + math.pi) % (2 * math.pi) - math.pi
        self._accel = (0.0, 0.0)         # horizontal acceleration (north, east) the attitude produces
        self._attitude = (0.0, 0.0)      # (roll, pitch) with the wobble
        self._rates = (0.0, 0.0)
        self._wobble = Wobble(wobble_deg, seed)
        self._sim_time = 0.0
        self._airborne = False
        self._max_alt = 0.0
        self._impact: float | None = None   # a fall's speed where it reached the ground, this step

    # --- readings ----------------------------------------------------------------------

    def state(self) -> State:
        with self._lock:
            return State(self._pos, self._vel, self._yaw, *self._attitude, *self._rates)

    def pose(self) -> tuple[float, float, float, float]:
        """(north, east, down, yaw_rad) in the local NED frame."""
        with self._lock:
            return (*self._pos, self._yaw)

    @property
    def position(self) -> Vec3:
        with self._lock:
            return self._pos

    @property
    def altitude(self) -> float:
        with self._lock:
            return -self._pos[2]

    @property
    def airborne(self) -> bool:
        with self._lock:
            return self._airborne

    @property
    def sim_time(self) -> float:
        with self._lock:
            return self._sim_time

    @property
    def max_altitude(self) -> float:
        with self._lock:
            return self._max_alt

    @property
    def ceiling(self) -> float:
        return self._ceiling()

    def clamp_down(self, down: float) -> float:
        """`down` kept between the ground and the ceiling."""
        return min(0.0, max(-self._ceiling(), down))

    # --- the physics -------------------------------------------------------------------

    def run(self, stop: threading.Event, time_scale: float, pilot: Pilot) -> None:
        """Step every PHYSICS_PERIOD_S of wall time until `stop`."""
        last = time.monotonic()
        while not stop.wait(PHYSICS_PERIOD_S):
            now = time.monotonic()
            try:
                self.step((now - last) * time_scale, now, pilot)
            except Exception as exc:  # never let the sky fall because of a bug in one step
                self._journal.warn(f"physics step failed: {type(exc).__name__}: {exc}")
            last = now

    def step(self, dt: float, wall_now: float, pilot: Pilot) -> None:
        """Advance `dt` simulated seconds (in substeps of at most MAX_STEP_S); `wall_now` is for
        the pilot's link timeouts."""
        count = max(1, math.ceil(dt / MAX_STEP_S - 1e-9)) if dt > 0 else 1
        for _ in range(count):
            self._step(dt / count, wall_now, pilot)

    def _step(self, dt: float, wall_now: float, pilot: Pilot) -> None:
        with self._lock:
            prev = self._pos
            self._sim_time += dt
            setpoint = pilot.setpoint(dt, wall_now)
            flown = None
            if setpoint is None:
                self._cmd_acc = (0.0, 0.0, 0.0)
                self._fall(dt)
            else:
                if setpoint.limited and dt > 0:
                    flown = step_limited(Motion(self._pos, self._vel, self._cmd_acc), setpoint, dt)
                    self._pos, self._cmd_acc = flown.pos, flown.acc
                else:
                    self._pos = step_toward(self._pos, setpoint.target, setpoint.speed_xy, setpoint.speed_up,
                                            setpoint.speed_down, dt)
                self._yaw = step_yaw(self._yaw, setpoint.yaw, YAW_RATE_RAD_S, dt)
                pilot.on_moved(setpoint)
            n, e, d = self._pos
            self._pos = (n, e, self.clamp_down(d))
            prev_vel = self._vel
            if flown is not None:
                # the trajectory's own velocity, stopped vertically where the ground or the ceiling stops it
                vz = flown.vel[2] if self._pos[2] == d else 0.0
                self._vel = (flown.vel[0], flown.vel[1], vz)
                if vz == 0.0:
                    self._cmd_acc = (*self._cmd_acc[:2], 0.0)
            else:
                self._vel = tuple((a - b) / dt for a, b in zip(self._pos, prev)) if dt > 0 else (0.0, 0.0, 0.0)
            self._step_attitude(dt, prev_vel)
            pilot.on_contact(self._detect_contact(prev_vel[2]))
            self._max_alt = max(self._max_alt, -self._pos[2])

    def _step_attitude(self, dt: float, prev_vel: Vec3) -> None:
        if dt <= 0:
            return
        # The kinematic velocity changes within a step; the airframe's acceleration is that
        # change spread by the attitude loop's lag (a first-order filter of time constant TILT_TAU_S).
        k = 1.0 - math.exp(-dt / TILT_TAU_S)
        if self._airborne:
            inst = ((self._vel[0] - prev_vel[0]) / dt, (self._vel[1] - prev_vel[1]) / dt)
        else:
            inst = (0.0, 0.0)
        self._accel = (self._accel[0] + k * (inst[0] - self._accel[0]), self._accel[1] + k * (inst[1] - self._accel[1]))
        tilt = tilt_for(self._accel[0], self._accel[1], self._yaw)
        wobble = self._wobble.at(self._sim_time) if self._airborne else (0.0, 0.0)
        attitude = (tilt[0] + wobble[0], tilt[1] + wobble[1])
        self._rates = ((attitude[0] - self._attitude[0]) / dt, (attitude[1] - self._attitude[1]) / dt)
        self._attitude = attitude

    def _fall(self, dt: float) -> None:
        if -self._pos[2] <= GROUND_EPS_M:
            self._pos = (self._pos[0], self._pos[1], 0.0)
            return
        vz = min(TERMINAL_SPEED_M_S, self._vel[2] + GRAVITY_M_S2 * dt)
        self._pos = (self._pos[0], self._pos[1], min(0.0, self._pos[2] + vz * dt))
        if self._pos[2] >= 0.0:
            self._impact = vz

    def _detect_contact(self, descent_before: float = 0.0) -> Contact | None:
        """PX4-like land detector: airborne above LIFTOFF_ALT_M, landed on touching the ground; a touchdown
        faster than HARD_TOUCHDOWN_M_S is journaled as a crash first."""
        alt = -self._pos[2]
        if not self._airborne and alt > LIFTOFF_ALT_M:
            contact = Contact.LIFTOFF
        elif self._airborne and alt <= GROUND_EPS_M:
            contact = Contact.TOUCHDOWN
        else:
            self._impact = None
            return None
        self._airborne = contact is Contact.LIFTOFF
        if contact is Contact.TOUCHDOWN:
            # A fall's speed at the ground; flown, the descent of this step or the one before (the
            # last step may cover only the last centimetres, at the full speed).
            speed = self._impact if self._impact is not None else max(self._vel[2], descent_before)
            if speed > HARD_TOUCHDOWN_M_S:
                self._journal.event(f"hit the ground at {speed:.1f} m/s (a crash: over {HARD_TOUCHDOWN_M_S:g} m/s)")
        self._impact = None
        self._journal.event(contact.value)
        return contact
