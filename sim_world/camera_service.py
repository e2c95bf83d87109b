"""The world's camera: images of the floor as seen from the vehicle's pose, served on `world/camera`
and, with --camera-mavlink or --camera-video, as a real drone's MAVLink camera component.

A part of `World` (sim_world/service.py) kept apart: the images are rendered on the camera's own
thread from what the world holds (the truth, the judge's positions under the desk's lock, the
vehicle or the followed autopilot), so these methods read the world's state and own none of it.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

from protocol.codec import encode
from protocol.errors import UavRobotsError
from protocol.messages import CameraRequest
from protocol.transport import IncomingQuery
from scenarios.landmarks import LandmarkSet

from .camera_faults import OFF, STUCK, CameraFaults
from .config import WorldConfig
from .desk import MoveDesk
from .moves import MoveJudge
from .truth import Truth

# Following an autopilot, an image waits at most this long for the telemetry after its shutter (at
# 50 Hz the next sample is 20 ms away); then the last sample is carried on at its velocity.
FOLLOW_WAIT_S = 0.25


class WorldCamera:
    """The camera's handlers and exposure, mixed into World."""

    # What the world holds and these methods read (World.__init__ sets them).
    cfg: WorldConfig
    truth: Truth
    judge: MoveJudge
    desk: MoveDesk | None
    landmarks: LandmarkSet | None
    estimator: Any
    vehicle: Any
    follower: Any
    camera_model: Any
    mavlink_camera: Any
    camera_faults: CameraFaults | None = None   # camera-off / camera-stuck (camera_faults.py); set before start()
    warn: Callable[[str], None]
    _camera_pool: ThreadPoolExecutor
    _t0: float
    _decode: Callable[..., Any]
    _next_seq: Callable[[], int]

    def _on_camera(self, q: IncomingQuery) -> None:
        request = self._decode(q, CameraRequest)
        if request is None:
            return
        faulty = self.camera_faults.state(self.camera_clock()) if self.camera_faults is not None else None
        if faulty == OFF:   # a dead camera: the query ends unanswered, as one that no longer speaks leaves it
            self.camera_faults.count(OFF)
            q.finish()
            return
        if faulty == STUCK and not request.calibration_only:   # a frozen pipeline: its last image again
            old = self.camera_faults.frozen()
            if old is None:   # frozen before it ever rendered: nothing to show
                self.camera_faults.count(OFF)
                q.finish()
                return
            self.camera_faults.count(STUCK)
            q.reply(encode(old))
            return
        if request.calibration_only:   # no render: answered at once, ahead of images being made
            from .camera import calibration_frame

            _, view, model, _, estimator, t, seq, _ = self.exposure()
            q.reply(encode(calibration_frame(view, model, estimator, t, seq)))
            return
        # The shutter opens now, as the request arrives: the vehicle may fly on while the
        # image is rendered (tens to hundreds of milliseconds, off the transport's thread).
        try:
            from .camera import clip_roi

            shutter = time.monotonic()
            shot = self.exposure()
            roi = clip_roi(shot[2], request.roi_x, request.roi_y, request.roi_width, request.roi_height)
            self._camera_pool.submit(self._render_reply, q, (*shot, roi), shutter)
        except RuntimeError:  # shutting down
            q.finish()

    def _render_reply(self, q: IncomingQuery, shot: tuple, shutter: float | None = None) -> None:
        from .camera import capture_frame

        try:
            if shutter is not None:
                shot = self.at_shutter(shot, shutter)
            frame = capture_frame(*shot)
            if self.camera_faults is not None:   # what a camera frozen later repeats
                self.camera_faults.remember(shot[6], frame)
            q.reply(encode(frame))
        except UavRobotsError as exc:
            self.warn(f"camera: {exc}")
            q.finish()
        except Exception as exc:  # noqa: BLE001 - a camera fault must not kill the world
            self.warn(f"camera failed: {type(exc).__name__}: {exc}")
            q.finish()

    def _start_camera_component(self) -> None:
        """The camera as a real drone's: a MAVLink camera component, its files over HTTP, its video."""
        c = self.cfg
        if not (c.camera_mavlink or c.camera_video):
            return
        from .camera import capture_frame
        from .camera.mavlink_camera import CameraLink, MavlinkCamera
        from .camera.stream import VideoStream, render_view, video_config

        video = (VideoStream(video_config(c.camera_video), self.camera_model, render_view(self.exposure), c.mavlink_bind)
                 if c.camera_video else None)
        expose, develop = self.exposure, lambda shot: capture_frame(*shot)
        if self.camera_faults is not None:   # the component's images fail or freeze as the query's do
            expose, develop = self.camera_faults.expose(expose), self.camera_faults.develop(develop)
        self.mavlink_camera = MavlinkCamera(CameraLink(c.camera_mavlink, (c.home_lat, c.home_lon, c.home_alt_m),
                                                       bind_host=c.mavlink_bind),
                                            self.camera_model, expose, develop, self._camera_pool.submit, video)
        self.mavlink_camera.start()
        print(f"world: {self.mavlink_camera.describe()}", flush=True)

    def at_shutter(self, shot: tuple, shutter: float) -> tuple:
        """An exposure (`exposure()`'s) seen from the followed autopilot's pose at `shutter` (time.monotonic()
        when it opened), interpolated in its telemetry once the samples after it came (waited for here,
        off the transport's thread); a world that flies its own vehicle read its pose at the shutter."""
        if self.follower is None:
            return shot
        view = self.camera_view(shutter, wait_s=FOLLOW_WAIT_S)
        if view is None:
            raise UavRobotsError(f"no pose from the autopilot on {self.cfg.autopilot_pose} yet")
        return (shot[0], view, *shot[2:])

    def camera_view(self, at: float | None = None, wait_s: float = 0.0):
        """The camera's true pose and motion in the grid's NED frame: the vehicle's, lifted by the mount height.
        Following an autopilot: its pose at the instant `at` (now), None before it sent one."""
        from .camera import VehicleView
        if self.follower is not None:
            p = self.follower.pose_at(time.monotonic() if at is None else at, wait_s)
            if p is None:
                return None
            return VehicleView(p.north_m, p.east_m, p.down_m - self.cfg.camera_height_m, *p[3:])
        if self.vehicle is None:
            # No vehicle (tests of the services): a fixed camera over the centre that sees the whole floor.
            h, w = self.truth.free.shape
            c, m = self.cfg.cell_size_m, self.camera_model
            alt = 1.1 * max(w * c * m.fx / m.width, h * c * m.fy / m.height)
            return VehicleView(-h * c / 2, w * c / 2, -alt, 0.0)
        st = self.vehicle.state()
        n, e, d = st.pos
        return VehicleView(n, e, d - self.cfg.camera_height_m, st.yaw, st.roll, st.pitch, *st.vel)

    def capture(self):
        from .camera import capture_frame

        return capture_frame(*self.exposure())

    def camera_clock(self) -> float:
        """Now on the clock the images are stamped with (their `time_s`): the vehicle's simulated seconds,
        or the world's since it started (at the followed autopilot's time scale)."""
        if self.vehicle is not None:
            return self.vehicle.sim_time_s
        scale = self.cfg.time_scale if self.follower is not None else 1.0   # simulated seconds, as the vehicle's
        return (time.monotonic() - self._t0) * scale

    def exposure(self) -> tuple:
        """What one image shows, fixed at the shutter: the scene, the camera's true view and the
        clock; capture_frame's arguments."""
        from .camera import CameraModel, PoseEstimator, Scene, VehicleView

        if self.camera_model is None:   # never started (tests of capture alone)
            self.camera_model = CameraModel()
        if self.estimator is None:
            self.estimator = PoseEstimator(self.camera_model, self.cfg.seed)
        assert self.desk is not None
        with self.desk.cv:
            robots = dict(self.judge.positions)
            traffic = self.judge.traffic
            movers = tuple((m.kind, m.cell) for m in traffic.on_floor()) if traffic is not None else ()
        scene = Scene(self.truth.free, robots, list(self.truth.goals), self.landmarks,
                      goal_pads=self.cfg.scene.goal_pads, movers=movers)
        view = self.camera_view()
        if view is None:   # no pose from the followed autopilot yet: the lens on the floor at its corner
            view = VehicleView(0.0, 0.0, -self.cfg.camera_height_m)
        t = self.camera_clock()
        seed = self._next_seq()
        return scene, view, self.camera_model, self.cfg.cell_size_m, self.estimator, t, self._next_seq(), seed
