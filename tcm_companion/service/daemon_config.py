"""``[daemon]``: the service's timing and health policy, and the rules its values obey.

Each rule is written once, here: the valid range of every setting (:data:`RANGES`, which
the configuration loader checks with messages that name the file and key), the sign of
each number and the order of the attitude waits (:class:`DaemonConfig` itself, whoever
builds it), and what the live box feed needs of the rest of the configuration
(:meth:`DaemonConfig.feed_problem`, checked by the loader and by the Companion).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from .box_feed import parse_feed_url

#: The valid range of each ``[daemon]`` setting, as config.toml states it (config.py
#: checks them at load, under ``"daemon.KEY"`` in its ``RANGES``).
RANGES: dict[str, str] = {
    "attitude_lead_max_us": "[1, 1000000] µs",
    "attitude_wait_max_us": "[1, 1000000] µs",  # and >= attitude_lead_max_us
    "camera_timeout_us": "[10000, 60000000] µs",
    "attitude_timeout_us": "[10000, 60000000] µs",
    "position_timeout_us": "[10000, 60000000] µs",
    "health_interval_us": "[10000, 60000000] µs",
    "rebuild_after_errors": "[1, 100000] frames",
    "latency_window": "[1, 100000] frames",
    "opencv_threads": "[0, 1024] threads",  # 0: OpenCV's default
    "gil_switch_interval_us": "[1, 1000000] µs",
    # A frame waits this long for its boxes at most (docs/box-feed.md); a second
    # is 25 frames at 25 Hz.
    "box_wait_max_us": "[1, 1000000] µs",
    "box_feed_timeout_us": "[10000, 60000000] µs",
    "box_tracking_camera": "[0, 255]",  # an index into the cameras
    "box_tracking_latency_us": "[0, 1000000] µs",
}
#: The settings that may be 0 (every other number must be positive).
MAY_BE_ZERO = frozenset(k for k, spec in RANGES.items() if spec.startswith("[0,"))


@dataclass(frozen=True)
class DaemonConfig:
    """``[daemon]``: timing and health policy of the service (times in µs)."""

    # A frame may be this much newer than the newest attitude sample and still be
    # processed at once (extrapolated); beyond it, it waits for the next sample ...
    attitude_lead_max_us: int = 25_000
    # ... but never longer than this after its capture time.
    attitude_wait_max_us: int = 40_000
    camera_timeout_us: int = 500_000  # a camera is stale after this long without a frame
    attitude_timeout_us: int = 200_000  # ATTITUDE requested at 50 Hz
    position_timeout_us: int = 1_000_000  # LOCAL_POSITION_NED requested at 10 Hz
    health_interval_us: int = 1_000_000  # health check, watchdog ping, status line
    rebuild_after_errors: int = 5  # consecutive failing frames before a pipeline rebuild
    latency_window: int = 250  # frames in the running latency figure of the health message
    # Where parameters and the signing timestamp live when their [mavlink] paths are
    # relative. "": $STATE_DIRECTORY (systemd's StateDirectory=), else
    # $XDG_STATE_HOME/tcm-companion, else ~/.local/state/tcm-companion.
    state_dir: str = ""
    # OpenCV worker threads for the pipeline (0: OpenCV's default, one per core). One is
    # faster here: frames are small, and extra threads fight the camera threads and
    # the event loop for the cores (tcm-companion bench --daemon).
    opencv_threads: int = 1
    # Python's GIL switch interval while the daemon runs (default Python: 5000 µs): how
    # long a camera thread with a new frame may wait for the loop thread to let go.
    gil_switch_interval_us: int = 1000
    # Live boxes for [detection] backend = "boxes" (docs/box-feed.md): where another
    # process on the companion sends them, "udp:HOST:PORT" ("": no feed) ...
    box_feed: str = ""
    # ... how long after its capture a frame waits for its boxes, at most (then it is
    # processed without them: nothing detected in it, tracks coast) ...
    box_wait_max_us: int = 100_000
    # ... and the feed is stale (a fault; objects unknown) after this long without a
    # valid message.
    box_feed_timeout_us: int = 1_000_000
    # A tracking camera's CAMERA_TRACKING_IMAGE_STATUS (its rectangle) as the boxes of
    # camera box_tracking_camera (an index), stamped on receipt minus
    # box_tracking_latency_us (the message has no time).
    box_tracking: bool = False
    box_tracking_camera: int = 0
    box_tracking_latency_us: int = 50_000
    # The pipelines in worker processes, one per camera (service/workers.py): "auto"
    # when there are two cameras or more and two CPUs or more in the affinity mask; 0
    # never (in-process); 1 always. Not with a live box feed (in-process then).
    workers: Literal["auto"] | int = "auto"

    def __post_init__(self) -> None:
        # The sign of each number (the loader checks the whole range, RANGES, first).
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, int) or isinstance(value, bool) or f.name == "workers":
                continue  # workers: "auto", 0 or 1 (below)
            if f.name in MAY_BE_ZERO:
                if value < 0:
                    raise ValueError(f"{f.name} must be >= 0, got {value}")
            elif value <= 0:
                raise ValueError(f"{f.name} must be > 0, got {value}")
        if self.workers != "auto" and (
            isinstance(self.workers, bool) or self.workers not in (0, 1)
        ):
            raise ValueError(f'workers must be "auto", 0 or 1, got {self.workers!r}')
        try:
            parse_feed_url(self.box_feed)
        except ValueError as exc:
            raise ValueError(f"box_feed {exc}") from None
        if self.attitude_wait_max_us < self.attitude_lead_max_us:
            raise ValueError("attitude_wait_max_us must be >= attitude_lead_max_us")

    def feed_problem(self, backend: str, n_cameras: int) -> tuple[str, str] | None:
        """What makes the live box feed this asks for impossible with the ``[detection]
        backend`` ``backend`` and ``n_cameras`` cameras: ``(key, why)``, ``why`` starting
        with the key as config.toml writes it; None when nothing does."""
        for key in ("box_feed", "box_tracking"):
            if getattr(self, key) and backend != "boxes":
                return key, (
                    f'{key} needs [detection] backend = "boxes" (it is {backend!r}): the'
                    " feed's boxes are that backend's input"
                )
        camera = self.box_tracking_camera
        if self.box_tracking and not 0 <= camera < n_cameras:
            runs = (
                "one ([camera], index 0)"
                if n_cameras == 1
                else f"{n_cameras} (indices 0..{n_cameras - 1})"
            )
            return "box_tracking_camera", (
                f"box_tracking_camera = {camera} is not a camera: the daemon runs {runs}"
            )
        return None
