"""A simulated camera on *any* autopilot's vehicle: the field rendered from MAVLink telemetry.

:class:`~tcm_companion.sim.scene.truth_camera.SimulatedCamera` renders from the mock autopilot's
exact truth, so it can only fly the mock. :class:`AutopilotSimCamera` renders the same
simulated field from the pose a real flight controller reports — ArduCopter SITL, PX4
SITL, the mock over a socket — so the daemon can run against a real autopilot with a
simulated ball on a collision course (``[camera] source = "sim_autopilot"``).

The link. The camera has its *own* MAVLink connection (``url``: ``tcp:HOST:PORT``,
``udpin:HOST:PORT``, ``udpout:HOST:PORT`` or ``serial:PATH:BAUD``, the transports of
:mod:`tcm_companion.io.transports`, reopened with backoff when lost), framed by the
project's :class:`~tcm_companion.mavlink.codec.MavlinkCodec` (MAVLink 2, our dialect,
which includes ``common``; no process-global pymavlink state is touched). It runs in a
background thread with its own asyncio loop (a :class:`~tcm_companion.io.link_thread.LinkThread`,
like the SITL drivers' ground station) and:

- sends a HEARTBEAT (``MAV_TYPE_CAMERA``, ``MAV_AUTOPILOT_INVALID``) at 1 Hz as system
  ``system_id`` (1), component ``component_id`` (100, ``MAV_COMP_ID_CAMERA``);
- follows the first autopilot HEARTBEAT it hears (``autopilot != MAV_AUTOPILOT_INVALID``)
  as its target, ``target`` (1/1) until then, and takes telemetry from that target only;
- asks it with ``MAV_CMD_SET_MESSAGE_INTERVAL`` for ATTITUDE and LOCAL_POSITION_NED at
  ``attitude_hz`` / ``position_hz`` (50 Hz). ArduPilot keeps message intervals per link,
  so the other links (the daemon's, a GCS's) are not disturbed. A stream not heard for
  0.5 s is asked for again once a second — after a reboot (which forgets the rates), a
  lost link, or before the EKF has an origin (ArduPilot accepts the request but sends no
  LOCAL_POSITION_NED until then);
- feeds every ATTITUDE / LOCAL_POSITION_NED to a
  :class:`~tcm_companion.core.telemetry.TelemetryBuffer`, stamped with its receive time on
  the companion monotonic clock (:func:`~tcm_companion.io.aio.monotonic_us`): the
  autopilot's boot clock is mapped to the companion clock by the same lower-envelope fit
  the pipeline uses, and a reboot (boot time going back) restarts the fit.

The frames. ``read()`` ticks at ``fps`` on absolute deadlines of the companion clock
(``t0 + k / fps``). For the tick ``t`` it waits — interruptibly, at most ``pose_wait_s``
(80 ms) — until the buffer holds an attitude sample at or after ``t``, then renders the
field from ``position_at(t)`` and ``attitude_at(t)`` and returns ``(image, t)``: the
capture time is the tick, the image arrives a pose wait plus a render later (a camera with
a readout delay). Without a pose (no LOCAL_POSITION_NED yet, link down, attitude too old)
it returns ``(None, t)``, which the reader counts as an empty frame. If reading fell more
than a frame period behind, the ticks already past are skipped (``skipped_ticks``) and
the newest past tick is rendered, so capture-to-delivery latency stays bounded.

The field is :func:`~tcm_companion.sim.scene.world.field_world` with its track along
``heading_deg`` (clockwise from north, default 0 = north) through the autopilot's local
NED origin, the ground at ``d = 0`` (the origin's — for ArduPilot the home — altitude).
Its clutter keeps out of a rectangle 18 m either way along the track, 7 m left and 14 m
right of it; a vehicle flying further out may meet trees, posts and a building.

The scene (:class:`SceneConfig`) adds balls in the same local NED frame:

- ``"crossing"`` — a red ball on a collision course. It is launched at the first rendered
  tick where the vehicle flies steadily: horizontal speed ≥ ``launch_min_speed_mps``
  (1 m/s) and velocity within ``launch_steady_mps`` (0.3 m/s, norm of the 3-D difference)
  of its value ``launch_steady_s`` (1 s) earlier, over a run of frames with a pose at
  least that long. With ``p`` the vehicle's position at launch, ``v`` its velocity (the
  mean over the frames of that last second, so that telemetry noise does not aim the
  ball), ``v_h`` the horizontal part of ``v``, ``ψ`` its direction and
  ``T = contact_s``: the meeting point is ``meet = p + v_h T`` (at the vehicle's
  altitude); the ball comes *from* bearing ``ψ + side_deg`` (90° = from the right of the
  vehicle's track, 0° = from straight ahead), i.e. moves horizontally along
  ``ψ + side_deg + 180°`` at ``ball_speed_mps``, starting at ``meet - v_ball T``, so it
  reaches ``meet`` exactly when the vehicle would, if the vehicle kept its velocity. The
  bearing from the vehicle to the ball is then constant while it closes.
- ``"headon"`` — a stationary ball, placed at launch (same condition) at
  ``p + v_h T`` plus ``headon_drop_m`` (0.2 m) down, so the vehicle flies straight at it
  but not along a perfectly degenerate line through its centre.
- ``"static"`` — balls at fixed ``(n_m, e_m, d_m, radius_m)``, present from the start.

A launched ball's scene time (what the renderer moves it by) is seconds since the launch
tick on the companion clock. :attr:`AutopilotSimCamera.launch` records where and when it
was launched, :meth:`AutopilotSimCamera.truth_at` gives the pose a frame was rendered from
and the balls' centres, for scoring.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core.frames import FloatArray
from ...core.telemetry import AttitudeSample, PositionSample, TelemetryBuffer
from ...io.aio import monotonic_us
from ...io.cameras.base import CameraError, CameraGone, FrameSource
from ...io.cameras.settings import SIM_SCENE_KINDS, SimSceneKind, StaticBall
from ...io.link_thread import LinkThread
from ...io.transports import TransportError
from ...mavlink import tcm_dialect as mav
from ...mavlink.codec import MavlinkCodec
from ...mavlink.samples import sample_from_message
from .world import BALL_ALBEDO_RGB, BALL_RADIUS_M, Ball, Trajectory, World, vec3

if TYPE_CHECKING:
    from ...core.camera import CameraModel
    from .render import Renderer

__all__ = [
    "AutopilotSimCamera",
    "Launch",
    "RigView",
    "SceneConfig",
    "SceneTruth",
    "check_url",
    "plan_launch",
]

log = logging.getLogger(__name__)

Vec3 = tuple[float, float, float]

_STREAM_TIMEOUT_US = 500_000  # a stream not heard for this long is asked for again
_REQUEST_PERIOD_US = 1_000_000  # at most one request per stream per second
_HEARTBEAT_PERIOD_US = 1_000_000
_TX_TICK_S = 0.1
_TRUTH_RECORDS = 1024  # rendered frames whose pose truth_at() remembers


# --------------------------------------------------------------------------------------
# The scene
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SceneConfig:
    """What the simulated field holds besides its clutter (see the module docstring).

    Times in s, speeds in m/s, angles in degrees (``side_deg`` clockwise from the
    vehicle's horizontal velocity), positions in the autopilot's local NED metres.
    """

    kind: SimSceneKind = "crossing"
    contact_s: float = 7.0  # launch to predicted contact (crossing, headon)
    ball_speed_mps: float = 1.5  # crossing: the ball's ground speed
    side_deg: float = 90.0  # crossing: the ball comes from this side (90 = right)
    ball_radius_m: float = BALL_RADIUS_M  # crossing / headon
    headon_drop_m: float = 0.2  # headon: ball centre this far below the vehicle's path
    static_balls: tuple[StaticBall, ...] = ()  # static: (n_m, e_m, d_m, radius_m) each
    launch_min_speed_mps: float = 1.0  # launch: horizontal speed at least this ...
    launch_steady_mps: float = 0.3  # ... and velocity within this of its value ...
    launch_steady_s: float = 1.0  # ... this long before

    def __post_init__(self) -> None:
        if self.kind not in SIM_SCENE_KINDS:
            raise ValueError(
                f"scene kind must be one of {list(SIM_SCENE_KINDS)}, got {self.kind!r}"
            )
        checks = (
            ("contact_s", self.contact_s > 0),
            ("ball_speed_mps", self.ball_speed_mps >= 0),
            ("side_deg", -360.0 <= self.side_deg <= 360.0),
            ("ball_radius_m", self.ball_radius_m > 0),
            ("headon_drop_m", True),
            ("launch_min_speed_mps", self.launch_min_speed_mps > 0),
            ("launch_steady_mps", self.launch_steady_mps > 0),
            ("launch_steady_s", self.launch_steady_s > 0),
        )
        for name, ok in checks:
            value = getattr(self, name)
            if not (math.isfinite(value) and ok):
                raise ValueError(f"scene {name} out of range: {value!r}")
        for ball in self.static_balls:
            if len(ball) != 4 or not all(math.isfinite(x) for x in ball) or not ball[3] > 0:
                raise ValueError(f"static ball must be (n_m, e_m, d_m, radius_m > 0), got {ball!r}")

    @property
    def launched(self) -> bool:
        """True for the scenes whose ball is launched from the vehicle's motion."""
        return self.kind in ("crossing", "headon")

    def static_ball_objects(self) -> tuple[Ball, ...]:
        """The balls of a ``"static"`` scene (object ids 1, 2, ...); none otherwise."""
        if self.kind != "static":
            return ()
        return tuple(
            Ball(Trajectory.static((n, e, d)), radius_m=r, albedo_rgb=BALL_ALBEDO_RGB, object_id=i)
            for i, (n, e, d, r) in enumerate(self.static_balls, start=1)
        )


@dataclass(frozen=True)
class Launch:
    """A launched ball: when (companion clock, µs), from which vehicle state, and where to."""

    launch_us: int  # the ball's scene time 0 (the tick it appeared in)
    vehicle_pos_ned_m: Vec3  # vehicle at launch, local NED
    vehicle_vel_ned_mps: Vec3
    meet_ned_m: Vec3  # where the vehicle would be at contact at constant velocity
    contact_us: int  # predicted contact: launch_us + contact_s
    ball: Ball

    @property
    def trajectory(self) -> Trajectory:
        """The ball's centre, NED m, against seconds since ``launch_us``."""
        return self.ball.trajectory


def plan_launch(
    scene: SceneConfig, launch_us: int, pos_ned_m: FloatArray, vel_ned_mps: FloatArray
) -> Launch:
    """The ball of ``scene`` launched at ``launch_us`` from a vehicle at ``pos_ned_m``
    flying at ``vel_ned_mps`` (local NED; see the module docstring for the geometry).
    ``scene.kind`` must be ``"crossing"`` or ``"headon"``; the horizontal speed must not
    be zero."""
    if not scene.launched:
        raise ValueError(f"a {scene.kind!r} scene has nothing to launch")
    p = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
    v = np.asarray(vel_ned_mps, dtype=np.float64).reshape(3)
    v_h = np.array([v[0], v[1], 0.0])
    speed = float(np.hypot(v[0], v[1]))
    if not speed > 0:
        raise ValueError("cannot launch: the vehicle has no horizontal velocity")
    T = scene.contact_s
    meet = p + v_h * T
    if scene.kind == "crossing":
        psi = math.atan2(v[1], v[0])
        from_rad = psi + math.radians(scene.side_deg)
        v_ball = -scene.ball_speed_mps * np.array([math.cos(from_rad), math.sin(from_rad), 0.0])
        trajectory = Trajectory.linear(vec3(meet - v_ball * T), vec3(v_ball))
    else:
        trajectory = Trajectory.static(vec3(meet + np.array([0.0, 0.0, scene.headon_drop_m])))
    ball = Ball(trajectory, radius_m=scene.ball_radius_m, albedo_rgb=BALL_ALBEDO_RGB)
    return Launch(
        int(launch_us), vec3(p), vec3(v), vec3(meet), int(launch_us) + round(T * 1e6), ball
    )


@dataclass(frozen=True)
class SceneTruth:
    """The simulated truth at companion time ``t_us``, for scoring.

    ``pos_ned_m`` / ``R_ned_from_body``: the vehicle pose a frame rendered at ``t_us``
    used (``rendered``), else the telemetry's pose at ``t_us`` (None when unknown).
    ``ball_centres_ned_m`` / ``ball_radii_m``: every ball present at ``t_us``;
    ``scene_t_s``: seconds since the launch (None before it, and for a static scene).
    """

    t_us: int
    scene_t_s: float | None
    pos_ned_m: FloatArray | None
    R_ned_from_body: FloatArray | None
    rendered: bool
    ball_centres_ned_m: tuple[FloatArray, ...]
    ball_radii_m: tuple[float, ...]


def check_url(url: str) -> None:
    """Raise :class:`CameraError` when ``url`` is not a transport URL (nothing is opened)."""
    from ...io.transports import TransportError, open_transport

    try:
        open_transport(url)
    except (TransportError, ValueError, TypeError) as exc:
        raise CameraError(str(exc)) from None


# --------------------------------------------------------------------------------------
# The MAVLink link (a background thread with its own event loop)
# --------------------------------------------------------------------------------------
class _Link:
    """The camera's own MAVLink connection: heartbeat, stream requests, telemetry in.

    The protocol is here; a :class:`~tcm_companion.io.link_thread.LinkThread` moves the
    bytes. ``on_sample(sample)`` is called from the link's thread for every ATTITUDE and
    LOCAL_POSITION_NED of the target autopilot, stamped with ``clock_us()`` at receipt.
    """

    def __init__(
        self,
        url: str,
        system_id: int,
        component_id: int,
        target: tuple[int, int],
        intervals_us: dict[int, int],
        on_sample: Callable[[AttitudeSample | PositionSample], None],
        clock_us: Callable[[], int],
    ) -> None:
        self.url = url
        self.system_id = system_id
        self.component_id = component_id
        self.target = target
        self.target_locked = False  # an autopilot heartbeat chose the target
        self.intervals_us = dict(intervals_us)
        self.on_sample = on_sample
        self.clock_us = clock_us
        self.messages: Counter[str] = Counter()  # received, by type (any sender)
        self.stats: Counter[str] = Counter()  # heartbeats_sent, interval_requests, ...
        self._stats_lock = threading.Lock()
        self._last_rx_us: dict[int, int] = {}
        self._last_req_us: dict[int, int] = {}
        self._next_heartbeat_us = 0
        self._codec = MavlinkCodec(system_id, component_id)
        self._thread = LinkThread(
            url,
            on_data=self._receive,
            on_tick=self._transmit,
            on_link_down=lambda: self._count("link_down"),
            initial_backoff_s=0.1,
            max_backoff_s=1.0,
            name=f"sim_autopilot link {url}",
        )

    # -- from the camera's thread --------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> None:
        """Start the thread and open the transport; :class:`CameraError` if it cannot.

        A TCP or serial link whose peer is not there yet is *not* an error: it is retried
        in the background (frames have no pose meanwhile)."""
        try:
            self._thread.start(timeout_s)
        except TransportError as exc:
            raise CameraError(str(exc)) from None

    def stop(self, timeout_s: float = 2.0) -> bool:
        """Close the transport and end the thread; True if it ended within ``timeout_s``."""
        return self._thread.stop(timeout_s)

    @property
    def alive(self) -> bool:
        return self._thread.alive

    def snapshot(self) -> tuple[dict[str, int], dict[str, int]]:
        """``(messages by type, link counters)``, copied consistently."""
        with self._stats_lock:
            stats = dict(self.stats)
        if self._thread.send_errors:
            stats["send_errors"] = self._thread.send_errors
        with self._stats_lock:
            return dict(self.messages), stats

    def _count(self, key: str, n: int = 1) -> None:
        with self._stats_lock:
            self.stats[key] += n

    # -- the link's thread ---------------------------------------------------------------
    def _receive(self, data: bytes) -> None:
        now = int(self.clock_us())
        for msg in self._codec.feed(data):
            try:
                self._handle(msg, now)
            except Exception:  # a hostile value: count it, carry on
                self._count("handler_errors")

    def _handle(self, msg: Any, now_us: int) -> None:
        kind = msg.get_type()
        with self._stats_lock:
            self.messages[kind] += 1
        src = (int(msg.get_srcSystem()), int(msg.get_srcComponent()))
        mid = int(msg.get_msgId())
        if mid == mav.MAVLINK_MSG_ID_HEARTBEAT:
            if int(msg.autopilot) != mav.MAV_AUTOPILOT_INVALID and not self.target_locked:
                if src != self.target:
                    log.info("sim_autopilot: following autopilot %d/%d", *src)
                    self._last_req_us.clear()
                self.target, self.target_locked = src, True
            return
        if src != self.target:
            return
        if mid == mav.MAVLINK_MSG_ID_COMMAND_ACK:
            if int(msg.command) == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
                ok = int(msg.result) == mav.MAV_RESULT_ACCEPTED
                self._count("interval_accepted" if ok else "interval_refused")
            return
        if mid in self.intervals_us:
            sample = sample_from_message(msg, now_us)
            if sample is not None:
                self._last_rx_us[mid] = now_us
                self.on_sample(sample)

    def _transmit(self) -> tuple[list[bytes], float]:
        """The frames due now (heartbeat, stream requests) and the time to the next tick."""
        codec = self._codec
        m = codec.mav
        now = int(self.clock_us())
        out: list[bytes] = []
        if now >= self._next_heartbeat_us:
            out.append(
                codec.encode(
                    m.heartbeat_encode(
                        mav.MAV_TYPE_CAMERA,
                        mav.MAV_AUTOPILOT_INVALID,
                        0,
                        0,
                        mav.MAV_STATE_ACTIVE,
                    )
                )
            )
            self._count("heartbeats_sent")
            self._next_heartbeat_us = now + _HEARTBEAT_PERIOD_US
        for mid, interval in self.intervals_us.items():
            heard = self._last_rx_us.get(mid)
            asked = self._last_req_us.get(mid)
            if heard is not None and now - heard <= _STREAM_TIMEOUT_US:
                continue
            if asked is not None and now - asked < _REQUEST_PERIOD_US:
                continue
            self._last_req_us[mid] = now
            tsys, tcomp = self.target
            cmd = m.command_long_encode(
                tsys, tcomp, mav.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid, interval, 0, 0, 0, 0, 0
            )
            out.append(codec.encode(cmd))
            self._count("interval_requests")
        return out, _TX_TICK_S


# --------------------------------------------------------------------------------------
# The camera
# --------------------------------------------------------------------------------------
class AutopilotSimCamera(FrameSource):
    """The simulated field seen from the pose the autopilot at ``url`` reports.

    ``camera_model``: the lens and image size (its mount is applied by the renderer);
    ``scene``: what is in the field (:class:`SceneConfig`, default a crossing ball);
    ``fps``: ticks per second on the companion clock; ``heading_deg``: the field's track
    direction, clockwise from north; ``seed``: the sensor-noise sequence; ``noise_dn``:
    sensor noise σ in digital numbers; ``system_id`` / ``component_id``: this camera's
    MAVLink identity; ``target``: the autopilot's ``(system, component)`` until its
    heartbeat is heard; ``attitude_hz`` / ``position_hz``: stream rates asked for;
    ``pose_wait_s``: how long a tick waits for the attitude sample after it. ``clock_us``
    is the companion monotonic clock (µs) every time here is on.
    """

    live = True

    def __init__(
        self,
        camera_model: CameraModel,
        url: str = "tcp:127.0.0.1:5763",
        scene: SceneConfig | None = None,
        *,
        fps: float = 25.0,
        heading_deg: float = 0.0,
        seed: int = 0,
        noise_dn: float = 2.5,
        system_id: int = 1,
        component_id: int = mav.MAV_COMP_ID_CAMERA,
        target: tuple[int, int] = (1, 1),
        attitude_hz: float = 50.0,
        position_hz: float = 50.0,
        pose_wait_s: float = 0.08,
        clock_us: Callable[[], int] = monotonic_us,
        fisheye_fov_deg: float = 180.0,
        name: str | None = None,
        views: Sequence[tuple[str, CameraModel]] = (),
    ) -> None:
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be positive, got {fps!r}")
        if not noise_dn >= 0:
            raise ValueError(f"noise_dn must be >= 0, got {noise_dn!r}")
        if not (attitude_hz > 0 and position_hz > 0 and pose_wait_s >= 0):
            raise ValueError("attitude_hz and position_hz must be > 0, pose_wait_s >= 0")
        if not (1 <= system_id <= 255 and 1 <= component_id <= 255):
            raise ValueError("system_id and component_id must be in 1..255")
        self.scene = scene if scene is not None else SceneConfig()
        super().__init__(
            name or f"sim_autopilot-{self.scene.kind}", camera_model.width, camera_model.height
        )
        self.camera_model = camera_model
        self.url = url
        self.fps = float(fps)
        self.heading_deg = float(heading_deg)
        self.seed = seed
        self.noise_dn = float(noise_dn)
        self.system_id = system_id
        self.component_id = component_id
        self.target = target
        self.intervals_us = {
            mav.MAVLINK_MSG_ID_ATTITUDE: round(1e6 / attitude_hz),
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: round(1e6 / position_hz),
        }
        self.pose_wait_us = round(pose_wait_s * 1e6)
        self.clock_us = clock_us
        self.fisheye_fov_deg = fisheye_fov_deg
        self._period_us = 1e6 / self.fps
        self._rng = np.random.default_rng(np.random.SeedSequence([20160628, seed, 3]))
        self._renderer: Renderer | None = None
        self._base_world: World | None = None
        self._balls_shown: tuple[Ball, ...] | None = None
        self._cond = threading.Condition()
        self._interrupted = threading.Event()
        self._buffer = TelemetryBuffer()
        self._link: _Link | None = None
        self._open = False
        self._t0_us: int | None = None
        self._k = 0
        self._pose_since_us: int | None = None  # first tick of the current run with a pose
        self._recent_vel: deque[tuple[int, FloatArray]] = deque()  # (tick, vel) of that run
        self.launch: Launch | None = None  # kept across reopening
        self._truth: deque[tuple[int, FloatArray, FloatArray]] = deque(maxlen=_TRUTH_RECORDS)
        # Counters (cumulative over reopenings).
        self.rendered = 0  # images returned
        self.no_pose = 0  # (None, t) returned: no position or attitude at the tick
        self.skipped_ticks = 0  # ticks passed over because reading fell behind
        self.pose_timeouts = 0  # the attitude after the tick did not come within pose_wait
        self.render_s_total = 0.0  # time spent rendering
        self.pose_wait_s_total = 0.0  # time from a tick until its pose was there (rendered)
        self._links_opened = 0
        self._clock_resets = 0
        self._past_messages: Counter[str] = Counter()
        self._past_link_stats: Counter[str] = Counter()
        # A rig: the other cameras, rendered from this one's pose at its ticks.
        self.views = [RigView(self, view_name, model) for view_name, model in views]

    # -- properties for callers --------------------------------------------------------
    @property
    def renderer(self) -> Renderer:
        """The ray caster of the field (built once: ~1.5 s the first time in a process)."""
        if self._renderer is None:
            from .render import Renderer
            from .world import field_world

            self._base_world = field_world((), math.radians(self.heading_deg))
            balls = self.scene.static_ball_objects()
            self._renderer = Renderer(
                self._base_world.with_balls(balls),
                self.camera_model,
                fisheye_fov_deg=self.fisheye_fov_deg,
                seed=self.seed,
            )
            self._balls_shown = balls
        return self._renderer

    @property
    def launch_us(self) -> int | None:
        """Companion time (µs) the ball was launched at, or None (not yet, or static)."""
        return self.launch.launch_us if self.launch is not None else None

    @property
    def trajectory(self) -> Trajectory | None:
        """The launched ball's trajectory (NED m against s since :attr:`launch_us`)."""
        return self.launch.trajectory if self.launch is not None else None

    @property
    def autopilot(self) -> tuple[int, int]:
        """The ``(system, component)`` telemetry is taken from."""
        return self._link.target if self._link is not None else self.target

    def stats(self) -> dict[str, Any]:
        """Counters: frames, pose waits, render time, the link's and messages per type."""
        messages, link = Counter(self._past_messages), Counter(self._past_link_stats)
        if self._link is not None:
            m, s = self._link.snapshot()
            messages.update(m)
            link.update(s)
        with self._cond:
            resets = self._clock_resets + self._buffer.clock.resets
        n = max(self.rendered, 1)
        return {
            "rendered": self.rendered,
            "no_pose": self.no_pose,
            "skipped_ticks": self.skipped_ticks,
            "pose_timeouts": self.pose_timeouts,
            "render_ms_mean": 1e3 * self.render_s_total / n,
            "pose_wait_ms_mean": 1e3 * self.pose_wait_s_total / n,
            "clock_resets": resets,
            "links_opened": self._links_opened,
            "link": dict(link),
            "messages": dict(messages),
        }

    # -- FrameSource ---------------------------------------------------------------------
    def open(self) -> None:
        self._interrupted.clear()
        try:
            _ = self.renderer
        except Exception as exc:
            raise CameraError(f"camera {self.name}: cannot build the renderer: {exc}") from exc
        self._close_link()
        with self._cond:
            self._clock_resets += self._buffer.clock.resets
            self._buffer = TelemetryBuffer()
        link = _Link(
            self.url,
            self.system_id,
            self.component_id,
            self.target,
            self.intervals_us,
            self._on_sample,
            self.clock_us,
        )
        link.start()  # raises CameraError
        self._link = link
        self._links_opened += 1
        self._t0_us, self._k, self._open = None, 0, True
        self._pose_since_us = None
        self._recent_vel.clear()

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if not self._open or self._link is None:
            raise CameraGone(f"camera {self.name}: not open")
        if not self._link.alive:
            raise CameraGone(f"camera {self.name}: MAVLink link {self.url} ended")
        tick_us = self._next_tick()
        now = int(self.clock_us())
        if tick_us > now:
            self._interrupted.wait((tick_us - now) / 1e6)
        if self._interrupted.is_set():
            return None, tick_us
        pose = self._pose_at(tick_us)
        if pose is None:
            self.no_pose += 1
            self._pose_since_us = None
            self._recent_vel.clear()
            for view in self.views:
                view.deliver(None, tick_us)
            return None, tick_us
        if self._pose_since_us is None:
            self._pose_since_us = tick_us
        pos_ned_m, vel_ned_mps, R_ned_from_body, vel_before = pose
        self.pose_wait_s_total += max(0, int(self.clock_us()) - tick_us) / 1e6
        if self.scene.launched and self.launch is None:
            self._maybe_launch(tick_us, pos_ned_m, vel_ned_mps, vel_before)
        renderer = self.renderer
        balls, t_s = self._balls_at(tick_us)
        if balls != self._balls_shown:
            assert self._base_world is not None
            renderer.world = self._base_world.with_balls(balls)
            self._balls_shown = balls
        t_render = time.perf_counter()
        image = renderer.render(
            t_s, pos_ned_m, R_ned_from_body, noise_dn=self.noise_dn, rng=self._rng
        )
        self.render_s_total += time.perf_counter() - t_render
        self.rendered += 1
        self._truth.append((tick_us, pos_ned_m, R_ned_from_body))
        for view in self.views:
            view.render(t_s, pos_ned_m, R_ned_from_body, tick_us)
        return image, tick_us

    def interrupt(self) -> None:
        self._interrupted.set()
        with self._cond:
            self._cond.notify_all()

    def close(self) -> None:
        self._open = False
        self._close_link()
        for view in self.views:
            view.deliver(None, None)  # wakes a view waiting for a frame

    # -- scoring -------------------------------------------------------------------------
    def truth_at(self, t_us: int) -> SceneTruth:
        """The pose a frame at ``t_us`` was rendered from (else the telemetry's at ``t_us``)
        and the balls' NED centres at ``t_us`` (companion clock, µs)."""
        pos: FloatArray | None = None
        R: FloatArray | None = None
        rendered = False
        for tick, p, r in reversed(self._truth):
            if tick == t_us:
                pos, R, rendered = p, r, True
                break
            if tick < t_us:
                break
        if not rendered:
            with self._cond:
                pv = self._buffer.position_at(int(t_us))
                R = self._buffer.attitude_at(int(t_us))
            pos = pv[0] if pv is not None else None
        balls, t_s = self._balls_at(int(t_us))
        return SceneTruth(
            int(t_us),
            t_s if self.launch is not None and balls else None,
            pos,
            R,
            rendered,
            tuple(np.asarray(b.centre_ned_m(t_s), dtype=np.float64) for b in balls),
            tuple(float(b.radius_m) for b in balls),
        )

    # -- internals -----------------------------------------------------------------------
    def _close_link(self) -> None:
        link, self._link = self._link, None
        if link is None:
            return
        if not link.stop():
            log.warning("camera %s: MAVLink link thread did not end within 2 s", self.name)
        m, s = link.snapshot()
        self._past_messages.update(m)
        self._past_link_stats.update(s)

    def _on_sample(self, sample: AttitudeSample | PositionSample) -> None:
        with self._cond:
            self._buffer.add(sample)
            if isinstance(sample, AttitudeSample):
                self._cond.notify_all()

    def _tick_us(self, k: int) -> int:
        assert self._t0_us is not None
        return self._t0_us + round(k * self._period_us)

    def _next_tick(self) -> int:
        now = int(self.clock_us())
        if self._t0_us is None:
            self._t0_us, k = now + round(self._period_us), 0
        else:
            k = self._k
            if now > self._tick_us(k) + self._period_us:
                # More than a frame behind: skip to the newest tick already past.
                k_new = max(k, math.floor((now - self._t0_us) / self._period_us))
                while self._tick_us(k_new) > now and k_new > k:
                    k_new -= 1
                self.skipped_ticks += k_new - k
                k = k_new
        self._k = k + 1
        return self._tick_us(k)

    def _pose_at(
        self, tick_us: int
    ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray | None] | None:
        """``(pos_ned_m, vel_ned_mps, R_ned_from_body, vel_ned_mps launch_steady_s earlier)``
        at ``tick_us`` once the attitude after it is in (or ``pose_wait`` has passed)."""
        deadline = tick_us + self.pose_wait_us
        with self._cond:
            while not self._interrupted.is_set():
                latest = self._buffer.latest_attitude_time_us()
                if latest is not None and latest >= tick_us:
                    break
                remaining = deadline - int(self.clock_us())
                if remaining <= 0:
                    self.pose_timeouts += 1
                    break
                self._cond.wait(remaining / 1e6)
            R = self._buffer.attitude_at(tick_us)
            pv = self._buffer.position_at(tick_us)
            before = None
            if self.scene.launched and self.launch is None:
                back_us = tick_us - round(self.scene.launch_steady_s * 1e6)
                before = self._buffer.position_at(back_us)
        if R is None or pv is None:
            return None
        return (
            np.asarray(pv[0], dtype=np.float64),
            np.asarray(pv[1], dtype=np.float64),
            np.asarray(R, dtype=np.float64),
            None if before is None else np.asarray(before[1], dtype=np.float64),
        )

    def _maybe_launch(
        self,
        tick_us: int,
        pos_ned_m: FloatArray,
        vel_ned_mps: FloatArray,
        vel_before_ned_mps: FloatArray | None,
    ) -> None:
        scene = self.scene
        window_us = round(scene.launch_steady_s * 1e6)
        self._recent_vel.append((tick_us, vel_ned_mps))
        while self._recent_vel and self._recent_vel[0][0] < tick_us - window_us:
            self._recent_vel.popleft()
        # Steady for launch_steady_s: judged on telemetry actually received over that
        # time (the buffer would extrapolate a little before its first sample).
        since = self._pose_since_us
        if since is None or tick_us - since < window_us or vel_before_ned_mps is None:
            return
        if float(np.hypot(vel_ned_mps[0], vel_ned_mps[1])) < scene.launch_min_speed_mps:
            return
        if float(np.linalg.norm(vel_ned_mps - vel_before_ned_mps)) > scene.launch_steady_mps:
            return
        # The velocity extrapolated: the mean over the steady window (this frame's ticks),
        # so one noisy sample does not aim the ball.
        mean_vel = np.mean([v for _, v in self._recent_vel], axis=0)
        launch = plan_launch(scene, tick_us, pos_ned_m, mean_vel)
        self.launch = launch
        start = launch.ball.centre_ned_m(0.0)
        log.info(
            "sim_autopilot: %s ball launched at NED (%.1f, %.1f, %.1f) m moving (%.2f, %.2f) "
            "m/s; vehicle at (%.1f, %.1f, %.1f) m flying (%.2f, %.2f, %.2f) m/s; predicted "
            "contact in %.1f s at (%.1f, %.1f, %.1f) m",
            scene.kind,
            *start,
            *launch.trajectory.linear_velocity_ned_mps[:2],
            *launch.vehicle_pos_ned_m,
            *launch.vehicle_vel_ned_mps,
            scene.contact_s,
            *launch.meet_ned_m,
        )

    def _balls_at(self, t_us: int) -> tuple[tuple[Ball, ...], float]:
        """The balls present at ``t_us`` and the renderer's scene time (s since launch)."""
        if self.scene.kind == "static":
            return self.scene.static_ball_objects(), 0.0
        launch = self.launch
        if launch is None or t_us < launch.launch_us:
            return (), 0.0
        return (launch.ball,), (t_us - launch.launch_us) / 1e6


class RigView(FrameSource):
    """Another camera of a rig on the :class:`AutopilotSimCamera` ``primary``: its lens
    ``camera_model`` rendered from the primary's pose at the primary's ticks (one pose, one
    clock for the whole rig), by the primary's reader thread, right after its own image.
    ``read()`` returns the newest frame not yet returned (an older one not read in time is
    dropped, counted in ``skipped``), waiting for it at most ``wait_s``; a tick without a
    pose is ``(None, tick)``, as from the primary. Its field and balls are the primary's.
    """

    live = True

    def __init__(
        self,
        primary: AutopilotSimCamera,
        name: str,
        camera_model: CameraModel,
        wait_s: float = 0.5,
    ) -> None:
        super().__init__(f"{primary.name}-{name}", camera_model.width, camera_model.height)
        self.primary = primary
        self.camera_model = camera_model
        self.wait_s = float(wait_s)
        self._renderer: Renderer | None = None
        self._balls_shown: tuple[Ball, ...] | None = None
        self._cond = threading.Condition()
        self._slot: tuple[np.ndarray | None, int] | None = None
        self._last_tick_us: int | None = None
        self._open = False
        self._interrupted = False
        self.rendered = 0
        self.skipped = 0  # frames replaced before they were read
        self.render_s_total = 0.0

    # -- from the primary's reader thread ---------------------------------------------
    def render(
        self, t_s: float, pos_ned_m: FloatArray, R_ned_from_body: FloatArray, tick_us: int
    ) -> None:
        """Render this view of the primary's tick ``tick_us`` and hand it over."""
        p = self.primary
        base = p._base_world
        assert base is not None and p._balls_shown is not None  # the primary rendered
        if self._renderer is None:
            from .render import Renderer

            self._renderer = Renderer(
                base.with_balls(p._balls_shown),
                self.camera_model,
                fisheye_fov_deg=p.fisheye_fov_deg,
                seed=p.seed,
            )
            self._balls_shown = p._balls_shown
        elif p._balls_shown != self._balls_shown:
            self._renderer.world = base.with_balls(p._balls_shown)
            self._balls_shown = p._balls_shown
        t = time.perf_counter()
        image = self._renderer.render(
            t_s, pos_ned_m, R_ned_from_body, noise_dn=p.noise_dn, rng=p._rng
        )
        self.render_s_total += time.perf_counter() - t
        self.rendered += 1
        self.deliver(image, tick_us)

    def deliver(self, image: np.ndarray | None, tick_us: int | None) -> None:
        """Put one frame in the slot (``tick_us`` None: the primary closed; wake up)."""
        with self._cond:
            if tick_us is not None:
                if self._slot is not None:
                    self.skipped += 1
                self._slot = (image, tick_us)
            self._cond.notify_all()

    # -- FrameSource ---------------------------------------------------------------------
    def open(self) -> None:
        with self._cond:
            self._open, self._interrupted, self._slot = True, False, None

    def read(self) -> tuple[np.ndarray | None, int | None]:
        if not self._open:
            raise CameraGone(f"camera {self.name}: not open")
        deadline = time.monotonic() + self.wait_s
        with self._cond:
            while self._slot is None and not self._interrupted:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cond.wait(left)
            if self._slot is None:
                # Nothing from the primary (not started, or it lost its link): an empty
                # frame now, which the reader counts as rejected.
                return None, int(self.primary.clock_us())
            image, tick_us = self._slot
            self._slot = None
        self._last_tick_us = tick_us
        return image, tick_us

    def interrupt(self) -> None:
        with self._cond:
            self._interrupted = True
            self._cond.notify_all()

    def close(self) -> None:
        self._open = False
