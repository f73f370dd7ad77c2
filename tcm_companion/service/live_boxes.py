"""The live box feed's policy, sans-IO: which boxes a frame gets and how long it waits.

:class:`LiveBoxes` is the part of :class:`~tcm_companion.service.companion.Companion` that
deals with another process's detector (docs/box-feed.md): it takes the feed's datagrams
(``tcm-boxes/1``, parsed by :mod:`.box_feed`) and a tracking camera's
CAMERA_TRACKING_IMAGE_STATUS, hands each message's boxes to its camera's
:class:`~tcm_companion.core.detection.BoxesDetector`, says until when a frame waits for
its boxes, and counts and reports what it could not use. Every time is µs on the
companion's monotonic clock, given as an argument; nothing here reads a clock or a socket.

The Companion keeps the frame slots and asks this object three questions about them:
:meth:`LiveBoxes.deadline_us` (does a new frame wait for its boxes, and until when),
:meth:`LiveBoxes.holds` (does a waiting frame stay when a newer one arrives) and
:meth:`LiveBoxes.frame_processed` (count a frame with or without boxes).
"""

from __future__ import annotations

import logging
import math
from collections import Counter
from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

from ..core.camera import CameraModel
from ..core.detection import Box, BoxesDetector
from ..core.pipeline import Pipeline
from ..mavlink import tcm_dialect as d
from ..mavlink.endpoint import CompanionEndpoint, TrackingImageStatus
from .box_feed import INPUT_NAME, BoxFeedError, box_in_image, parse_box_datagram
from .inputs import Inputs

if TYPE_CHECKING:
    from .daemon_config import DaemonConfig

log = logging.getLogger(__name__)

#: Boxes stamped more than this after the time they arrive are for a frame not yet
#: captured: a feeder on another clock (counted ``future``, not used).
BOX_FUTURE_SLACK_US = 20_000
#: At most this many frames of a camera wait for their boxes at once (the oldest is
#: dropped beyond); the wait itself is bounded by ``box_wait_max_us``.
MAX_FRAMES_WAITING_FOR_BOXES = 16
#: The box feed's counters that are messages refused or not used (reported in a
#: STATUSTEXT when they grow; docs/box-feed.md).
BOX_FEED_BAD = ("malformed", "unknown camera", "late", "future", "boxes refused")
#: At most one log record of the feed's problems per this long (the counters and the
#: once-a-second STATUSTEXT carry the rest).
_WARN_INTERVAL_US = 10_000_000


class CameraView(Protocol):
    """What :class:`LiveBoxes` reads of one of the Companion's cameras (its pipeline is
    rebuilt on a parameter change, so the detector is looked up each time)."""

    camera_id: int
    name: str
    model: CameraModel
    pipeline: Pipeline
    last_processed_capture_mono_us: int | None


class LiveBoxes:
    """The live box feed of one Companion (``[daemon] box_feed`` and/or
    ``box_tracking``); ``enabled`` is False without either, and then no frame waits.

    ``counts`` is the Companion's ``stats.box_feed`` (updated here), ``inputs`` its input
    health (the feed is the input :data:`~.box_feed.INPUT_NAME`, whose spec the Companion
    adds when :attr:`enabled`), ``endpoint`` where STATUSTEXTs go."""

    def __init__(
        self,
        config: DaemonConfig,
        cameras: Sequence[CameraView],
        counts: Counter[str],
        inputs: Inputs,
        endpoint: CompanionEndpoint,
    ) -> None:
        self.config = config
        self.cameras = cameras
        self.counts = counts
        self.inputs = inputs
        self.endpoint = endpoint
        self.enabled = self.configured(config)
        self._last_mono_us: int | None = None  # the newest well-formed message
        self._newest_capture_mono_us: int | None = None  # of any frame delivered
        self._bad_reported = 0
        self._logged_mono_us: int | None = None

    @staticmethod
    def configured(config: DaemonConfig) -> bool:
        """Whether ``config`` asks for a live feed (``box_feed`` or ``box_tracking``)."""
        return bool(config.box_feed) or config.box_tracking

    @staticmethod
    def check(config: DaemonConfig, cameras: Sequence[CameraView]) -> None:
        """Raise ValueError when ``config`` asks for a feed these cameras cannot take
        (:meth:`~.daemon_config.DaemonConfig.feed_problem`)."""
        backends = [c.pipeline.config.detection.backend for c in cameras]
        backend = next((b for b in backends if b != "boxes"), "boxes")
        problem = config.feed_problem(backend, len(cameras))
        if problem is not None:
            raise ValueError(problem[1])

    # -- messages ---------------------------------------------------------------------------
    def on_datagram(self, data: bytes, now_mono_us: int) -> str:
        """A datagram of the feed arrived at ``now_mono_us``. Returns what became of it:
        ``"accepted"``, or the counter it went to (``"malformed"``, ``"unknown camera"``,
        ``"late"``, ``"future"``)."""
        st = self.counts
        st["datagrams"] += 1
        try:
            msg = parse_box_datagram(
                data, [c.model for c in self.cameras], [c.name for c in self.cameras]
            )
        except BoxFeedError as exc:
            st[exc.kind] += 1
            self._warn(f"{exc.kind} datagram ({exc})", now_mono_us)
            return exc.kind
        if msg.refused:
            st["boxes refused"] += msg.refused
            self._warn(f"{msg.refused} box(es) outside the image or empty, refused", now_mono_us)
        return self.on_boxes(msg.camera_id, msg.capture_mono_us, msg.boxes, now_mono_us)

    def on_tracking_image(self, ev: TrackingImageStatus, now_mono_us: int) -> str:
        """A tracking camera's CAMERA_TRACKING_IMAGE_STATUS as the boxes of camera
        ``box_tracking_camera``: its rectangle (normalised 0..1, scaled to the image),
        labelled ``tracked``, for the frame captured ``box_tracking_latency_us`` before it
        arrived (the message has no time of its own). Not tracking, or tracking a point (no
        size): no boxes in that frame. What became of it, as :meth:`on_boxes` says, or
        ``"malformed"`` (a rectangle with NaN corners)."""
        st = self.counts
        st["tracking messages"] += 1
        camera_id = self.config.box_tracking_camera
        model = self.cameras[camera_id].model
        boxes: list[Box] = []
        active = ev.tracking_status & d.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE
        if active and ev.tracking_mode == d.CAMERA_TRACKING_MODE_RECTANGLE:
            corners = (ev.rec_top_x, ev.rec_top_y, ev.rec_bottom_x, ev.rec_bottom_y)
            if not all(math.isfinite(c) for c in corners):
                st["malformed"] += 1
                self._warn("tracking rectangle with NaN corners", now_mono_us)
                return "malformed"
            w, h = model.width, model.height
            box = Box(
                corners[0] * w, corners[1] * h, corners[2] * w, corners[3] * h, 1.0, "tracked"
            )
            if box_in_image(box, model) is None:
                st["boxes refused"] += 1
                self._warn("tracking rectangle outside the image or empty", now_mono_us)
            else:
                boxes.append(box)
        elif active:
            st["tracking without rectangle"] += 1
        capture = ev.recv_us - self.config.box_tracking_latency_us
        return self.on_boxes(camera_id, capture, boxes, now_mono_us)

    def on_boxes(
        self, camera_id: int, capture_mono_us: int, boxes: Sequence[Box], now_mono_us: int
    ) -> str:
        """Camera ``camera_id``'s frame captured at ``capture_mono_us`` shows ``boxes``
        (all of them; none: nothing in it), said at ``now_mono_us``. A frame waiting for
        them is processed at the Companion's next ``process_due``. Boxes for a frame
        already processed (``"late"``) or not yet captured (``"future"``) are counted,
        not used; otherwise ``"accepted"``. Every such message keeps the feed alive."""
        st = self.counts
        cam = self.cameras[camera_id]
        detector = cam.pipeline.detector
        if not self.enabled or not isinstance(detector, BoxesDetector):
            st["unused"] += 1  # no feed configured: nobody expects them
            return "unused"
        self.inputs.update(INPUT_NAME, now_mono_us, True)
        self._last_mono_us = now_mono_us
        t = int(capture_mono_us)
        if t > now_mono_us + BOX_FUTURE_SLACK_US:
            st["future"] += 1
            self._warn(
                f"boxes for a frame {(t - now_mono_us) / 1e3:.0f} ms in the future (clock?)",
                now_mono_us,
            )
            return "future"
        # Late: for the frame processed last or an older one (that frame went on without
        # them). Boxes stamped a little after it may be the next frame's: they are
        # pushed, and if no frame takes them the detector counts them (``unmatched``).
        last = cam.last_processed_capture_mono_us
        if last is not None and t <= last:
            st["late"] += 1
            self._warn(
                f"boxes {(now_mono_us - t) / 1e3:.0f} ms after capture came for a frame"
                " already processed (late)",
                now_mono_us,
            )
            return "late"
        detector.push(t, boxes)
        st["accepted"] += 1
        st["boxes"] += len(boxes)
        return "accepted"

    def _warn(self, text: str, now_mono_us: int) -> None:
        """Log a problem of the feed (at most one record per 10 s)."""
        last = self._logged_mono_us
        if last is None or now_mono_us - last >= _WARN_INTERVAL_US:
            self._logged_mono_us = now_mono_us
            log.warning("box feed: %s", text)

    # -- frames -----------------------------------------------------------------------------
    def frame_delivered(self, capture_mono_us: int) -> None:
        """A camera delivered a frame captured at ``capture_mono_us``."""
        newest = self._newest_capture_mono_us
        t = int(capture_mono_us)
        self._newest_capture_mono_us = t if newest is None else max(newest, t)

    def deadline_us(self, camera_id: int, capture_mono_us: int) -> int | None:
        """Until when a frame of ``camera_id`` captured at ``capture_mono_us`` waits for
        its boxes: ``None`` (it does not) without a live feed, when boxes for it or a
        later frame have arrived (waiting cannot change them), or when the feed had sent
        nothing for ``box_feed_timeout_us`` before the newest frame delivered (of any
        camera: so that an older frame never waits when a newer one would not);
        otherwise until ``box_wait_max_us`` after its capture."""
        if not self.enabled:
            return None
        detector = self.cameras[camera_id].pipeline.detector
        if not isinstance(detector, BoxesDetector) or detector.ready(capture_mono_us):
            return None
        last = self._last_mono_us
        newest = max(capture_mono_us, self._newest_capture_mono_us or capture_mono_us)
        if last is None or newest - last > self.config.box_feed_timeout_us:
            return None  # nobody is feeding: waiting would only add latency
        return capture_mono_us + self.config.box_wait_max_us

    def holds(self, waited_for_boxes: bool, capture_mono_us: int, now_mono_us: int) -> bool:
        """Whether a newer frame leaves a waiting one in place: it arrived waiting for its
        boxes (``waited_for_boxes``) and its bounded wait is not over (its boxes may have
        come meanwhile, and it is processed next)."""
        return waited_for_boxes and capture_mono_us + self.config.box_wait_max_us > now_mono_us

    def boxes_used(self, camera_id: int) -> int:
        """Camera ``camera_id``'s detector's count of frames that took boxes so far (read
        before a frame's step, given to :meth:`frame_processed` after it)."""
        detector = self.cameras[camera_id].pipeline.detector
        return detector.stats["used"] if isinstance(detector, BoxesDetector) else 0

    def frame_processed(self, camera_id: int, waited_for_boxes: bool, used_before: int) -> None:
        """Count a processed frame: with or without boxes, and whether it waited."""
        if not self.enabled:
            return
        if waited_for_boxes:
            self.counts["frames waited"] += 1
        with_boxes = self.boxes_used(camera_id) > used_before
        self.counts["frames with boxes" if with_boxes else "frames without boxes"] += 1

    # -- once a second ----------------------------------------------------------------------
    def all_counts(self) -> dict[str, int]:
        """The counters with the boxes detectors' own: pushes no frame took
        (``unmatched``) or dropped for room (``overflow``), over the current pipelines."""
        out = dict(self.counts)
        for key, name in (("stale", "unmatched"), ("overflow", "overflow")):
            n = sum(
                c.pipeline.detector.stats[key]
                for c in self.cameras
                if isinstance(c.pipeline.detector, BoxesDetector)
            )
            if n:
                out[name] = n
        return out

    def report(self, now_mono_us: int) -> None:
        """A STATUSTEXT when messages were refused or not used since the last one (one
        condition: the repeat interval of the endpoint paces it)."""
        st = self.counts
        bad = sum(st[k] for k in BOX_FEED_BAD)
        if bad <= self._bad_reported:
            return
        self._bad_reported = bad
        parts = ", ".join(f"{st[k]} {k}" for k in BOX_FEED_BAD if st[k])
        self.endpoint.statustext(
            d.MAV_SEVERITY_WARNING, f"TCM: box feed: {parts}", now_mono_us, key="box feed bad"
        )

    def status(self) -> str:
        """The status line's part: `` | boxes 98 frames, 2 bad`` ("" without a feed)."""
        if not self.enabled:
            return ""
        bad = sum(self.counts[k] for k in BOX_FEED_BAD)
        return f" | boxes {self.counts['frames with boxes']} frames, {bad} bad"
