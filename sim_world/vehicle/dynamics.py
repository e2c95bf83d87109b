"""The airframe: where the vehicle is, how it moves toward what the autopilot asks, and
whether it stands on the ground.

The physics is kinematic: the vehicle moves straight toward its target (or at the
velocity it is given) within its horizontal speed and climb limits and, as PX4's
trajectory generator does, within acceleration and jerk limits (MPC_ACC_HOR,
MPC_ACC_UP_MAX / _DOWN_MAX, MPC_JERK_AUTO): a speed change ramps, and the vehicle
brakes in time to stop on its target (`step_limited`). Without limits (a setpoint's
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
from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol

from .journal import Journal

Vec3 = tuple[float, float, float]

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
SNAP_M = 0.005           # this close to its target and slower than SNAP_M_S, the vehicle is on it
SNAP_M_S = 0.05
PASS_M = 0.05            # a step that goes this close by its target has reached it
BRAKE_SHARE = 0.8        # plan braking with this share of the deceleration: the margin a jerk-limited start needs
TILT_TAU_S = 0.2         # attitude loop's lag: how long a change of velocity takes to fly
MAX_TILT_DEG = 20.0      # PX4 allows MPC_TILTMAX_AIR = 45; a survey flight stays well under it


def step_toward(pos: Vec3, target: Vec3, speed_xy: float, speed_up: float, speed_down: float, dt: float) -> Vec3:
    """Move `pos` toward `target` (NED) for `dt` s, capping horizontal and vertical speed
    separately, without overshooting. Returns the new position."""
    dn, de, dd = target[0] - pos[0], target[1] - pos[1], target[2] - pos[2]
    dist_xy = math.hypot(dn, de)
    reach = speed_xy * dt
    if dist_xy > reach > 0:
        dn, de = dn * reach / dist_xy, de * reach / dist_xy
    elif reach <= 0:
        dn = de = 0.0
    # down is positive: dd < 0 climbs
    dd = max(-speed_up * dt, min(speed_down * dt, dd))
    return pos[0] + dn, pos[1] + de, pos[2] + dd


def brake_speed(dist: float, accel: float, jerk: float) -> float:
    """The highest speed from which braking stops within `dist` m: deceleration up to `accel`,
    reached at `jerk` (stopping from v takes v^2 / 2a plus v a / 2j while the braking builds up)."""
    if dist <= 0:
        return 0.0
    if not math.isfinite(accel):
        return math.inf
    c = accel * accel / (2 * jerk) if math.isfinite(jerk) else 0.0
    return -c + math.sqrt(c * c + 2 * accel * dist)


def _norm(v) -> float:
    return math.sqrt(sum(x * x for x in v))


def approach(vel: tuple, acc: tuple, want: tuple, accel: float, jerk: float, dt: float) -> tuple[tuple, tuple]:
    """(velocity, acceleration) after `dt` s of changing `vel` toward `want`: the acceleration at
    most `accel` and changing at most `jerk` per second. It aims from the velocity it would reach
    by easing its acceleration off now, so that it arrives at `want` rather than overshooting it."""
    ease = _norm(acc) / (2 * jerk) if math.isfinite(jerk) else 0.0
    dv = tuple(w - v - a * ease for w, v, a in zip(want, vel, acc))
    gap = _norm(dv)
    mag = min(accel, gap / dt, math.sqrt(2 * jerk * gap) if math.isfinite(jerk) else math.inf) if gap > 0 else 0.0
    wanted = tuple(x * mag / gap for x in dv) if gap > 0 else tuple(0.0 for _ in dv)
    da = tuple(w - a for w, a in zip(wanted, acc))
    change, room = _norm(da), jerk * dt
    new_acc = tuple(a + x * room / change for a, x in zip(acc, da)) if change > room else wanted
    return tuple(v + a * dt for v, a in zip(vel, new_acc)), new_acc


def ahead(pos: tuple, vel: tuple, acc: tuple, jerk: float) -> tuple:
    """Where the vehicle will be once it has eased its acceleration off to zero (at `jerk`)."""
    t = _norm(acc) / jerk if math.isfinite(jerk) else 0.0
    return tuple(p + v * t + a * t * t / 3 for p, v, a in zip(pos, vel, acc))


@dataclass(frozen=True)
class Motion:
    """Position, velocity and commanded acceleration of the airframe (NED)."""

    pos: Vec3
    vel: Vec3
    acc: Vec3


def _toward(pos: tuple, vel: tuple, acc: tuple, target: tuple, cap: float, accel: float, jerk: float) -> tuple:
    """The velocity to aim for on the way to `target`: at most `cap`, and slow enough to brake in time
    (judged from where the vehicle will be once it stops accelerating)."""
    there = ahead(pos, vel, acc, jerk)
    gap = tuple(t - p for t, p in zip(target, there))
    dist = _norm(gap)
    if dist == 0 or sum(x * y for x, y in zip(gap, (t - p for t, p in zip(target, pos)))) < 0:
        return tuple(0.0 for _ in gap)  # it will be past the target: stop
    speed = min(cap, brake_speed(dist, accel * BRAKE_SHARE, jerk))
    return tuple(x * speed / dist for x in gap)


def step_limited(m: Motion, sp: "Setpoint", dt: float) -> Motion:
    """One step of `dt` s toward `sp` within its speed, acceleration and jerk limits: horizontally
    and vertically apart, as PX4's trajectory generator does; never past the target (within it
    and nearly stopped, the vehicle is put on it)."""
    n, e, d = m.pos
    vh, ah = (m.vel[0], m.vel[1]), (m.acc[0], m.acc[1])
    fly_h = sp.velocity is not None and sp.velocity[0] is not None and sp.velocity[1] is not None
    fly_z = sp.velocity is not None and sp.velocity[2] is not None
    # horizontal
    if fly_h:
        want = sp.velocity[:2]
        speed = math.hypot(*want)
        if speed > sp.speed_xy:
            want = tuple(x * sp.speed_xy / speed for x in want) if speed > 0 else (0.0, 0.0)
        target_h = None
    elif sp.speed_xy > 0:
        target_h = sp.target[:2]
        want = _toward((n, e), vh, ah, target_h, sp.speed_xy, sp.accel_xy, sp.jerk)
    else:  # a vertical leg: brake to a stop where it is
        want, target_h = (0.0, 0.0), None
    vh2, ah2 = approach(vh, ah, want, sp.accel_xy, sp.jerk, dt)
    n2, e2 = n + (vh[0] + vh2[0]) / 2 * dt, e + (vh[1] + vh2[1]) / 2 * dt
    if target_h is not None and _arrived((n, e), (n2, e2), target_h, vh2):
        (n2, e2), vh2, ah2 = target_h, (0.0, 0.0), (0.0, 0.0)
    # vertical (down is positive: a climb accelerates upward, bound by the up limit; stopping it, by the down one)
    vz, az = m.vel[2], m.acc[2]
    if fly_z:
        want_z, target_z = max(-sp.speed_up, min(sp.speed_down, sp.velocity[2])), None
    else:
        target_z = sp.target[2]
        descending = target_z > d
        (want_z,) = _toward((d,), (vz,), (az,), (target_z,), sp.speed_down if descending else sp.speed_up,
                            sp.accel_up if descending else sp.accel_down, sp.jerk)
    limit_z = sp.accel_up if want_z < vz else sp.accel_down
    (vz2,), (az2,) = approach((vz,), (az,), (want_z,), limit_z, sp.jerk, dt)
    d2 = d + (vz + vz2) / 2 * dt
    if target_z is not None and _arrived((d,), (d2,), (target_z,), (vz2,)):
        d2, vz2, az2 = target_z, 0.0, 0.0
    return Motion((n2, e2, d2), (vh2[0], vh2[1], vz2), (ah2[0], ah2[1], az2))


def _arrived(before: tuple, after: tuple, target: tuple, vel: tuple) -> bool:
    """Whether a step from `before` to `after` reached `target`: went through it (within PASS_M),
    or came within SNAP_M nearly stopped."""
    gap1 = tuple(t - a for t, a in zip(target, after))
    if _norm(gap1) <= SNAP_M and _norm(vel) <= SNAP_M_S:
        return True
    step = tuple(a - b for a, b in zip(after, before))
    length2 = sum(x * x for x in step)
    if length2 == 0:
        return False
    along = sum(x * (t - b) for x, t, b in zip(step, target, before)) / length2
    if not 0 < along < 1:
        return False
    closest = tuple(b + x * along for b, x in zip(before, step))
    return _norm(tuple(t - c for t, c in zip(target, closest))) <= PASS_M


def step_yaw(yaw: float, target: float, rate: float, dt: float) -> float:
    """Turn from `yaw` toward `target` (radians) at most `rate * dt`, the short way round."""
    diff = (target - yaw + math.pi) % (2 * math.pi) - math.pi
    diff = max(-rate * dt, min(rate * dt, diff))
    return (yaw + diff + math.pi) % (2 * math.pi) - math.pi


@dataclass(frozen=True)
class Setpoint:
    """Where the autopilot wants the airframe for one step (or, given `velocity`, how it wants it
    to move), how fast it may go and how quickly it may change speed (infinite: at once)."""

    target: Vec3 | None  # NED, within the ceiling; None with a velocity
    yaw: float
    speed_xy: float
    speed_up: float
    speed_down: float
    velocity: tuple | None = None  # NED m/s: fly at this velocity rather than to the target (None: per axis)
    accel_xy: float = math.inf
    accel_up: float = math.inf
    accel_down: float = math.inf
    jerk: float = math.inf

    @property
    def limited(self) -> bool:
        return self.velocity is not None or math.isfinite(self.accel_xy)


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
