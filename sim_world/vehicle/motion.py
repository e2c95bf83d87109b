"""The motion laws of the airframe: how one step moves it toward what a setpoint asks.

As PX4's trajectory generator does, within speed, acceleration and jerk limits (MPC_ACC_HOR,
MPC_ACC_UP_MAX / _DOWN_MAX, MPC_JERK_AUTO), horizontally and vertically apart, braking in time to
stop on the target (`step_limited`); without limits, straight and at once (`step_toward`). Pure
functions of NED tuples: the airframe (dynamics.py) keeps the state and the clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

Vec3 = tuple[float, float, float]

SNAP_M = 0.005           # this close to its target and slower than SNAP_M_S, the vehicle is on it
SNAP_M_S = 0.05
PASS_M = 0.05            # a step that goes this close by its target has reached it
BRAKE_SHARE = 0.8        # plan braking with this share of the deceleration: the margin a jerk-limited start needs


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
