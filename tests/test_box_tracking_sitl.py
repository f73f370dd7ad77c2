"""A tracking camera's CAMERA_TRACKING_IMAGE_STATUS over the mock autopilot, in SITL
(issue 14 §1, the second live source of boxes; docs/box-feed.md).

Virtual-time SITL on the T90 flight: the simulated camera is also the tracker. After
rendering each frame it measures the ball's true box (the renderer's visible coverage)
and the message, from a MAVLink camera component (1/100), is routed by the mock
autopilot onto the companion's link ``LATENCY_US`` after the frame's instant, as
ArduPilot routes a camera's messages. The companion takes the rectangle as the frame's
box ([daemon] box_tracking, stamped on receipt minus box_tracking_latency_us) and its
decisions are scored against the simulator's truth.
"""

from __future__ import annotations

import asyncio
import heapq
import math
from pathlib import Path
from typing import Any

import pytest

from tcm_companion.config import config_from_dict
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.sim.scene.truth import coverage_box_px, is_full_panorama
from tcm_companion.sim.scene.truth_camera import SimulatedCamera
from tcm_companion.sitl.mock_flight import run_sitl
from tcm_companion.sitl.virtual import VirtualTimeModel

LATENCY_US = 30_000  # the tracker's delay from a frame's instant to its message


def tracking_camera(routed: list[tuple[int, int, bytes]]) -> Any:
    """A ``camera_factory``: the simulated camera, tracking object 0 (module docstring)."""

    def factory(mock: Any, model: Any, **kw: Any) -> SimulatedCamera:
        cam = SimulatedCamera.for_mock(model, mock, **kw)
        encoder = d.MAVLink(None, srcSystem=1, srcComponent=d.MAV_COMP_ID_CAMERA)
        wrap = is_full_panorama(model)
        read = cam.read
        target = mock.plan.objects[0].object_id

        def read_and_track() -> tuple[Any, int | None]:
            image, tick_us = read()
            if tick_us is None or image is None:
                return image, tick_us
            t_s, pos, R = cam.truth_us(tick_us)
            cov = cam.renderer.visible_coverage(float(t_s), pos, R).get(target)
            box = None if cov is None else coverage_box_px(cov, wrap)
            w, h = model.width, model.height
            if box is None:  # not in view: the tracker says it lost it
                msg = d.MAVLink_camera_tracking_image_status_message(
                    d.CAMERA_TRACKING_STATUS_FLAGS_IDLE, d.CAMERA_TRACKING_MODE_NONE, 0,
                    *(math.nan,) * 7,
                )  # fmt: skip
            else:
                x0, y0, x1, y1 = box
                msg = d.MAVLink_camera_tracking_image_status_message(
                    d.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE,
                    d.CAMERA_TRACKING_MODE_RECTANGLE,
                    d.CAMERA_TRACKING_TARGET_DATA_IN_STATUS,
                    math.nan, math.nan, math.nan,
                    x0 / w, y0 / h, x1 / w, y1 / h,
                )  # fmt: skip
            heapq.heappush(routed, (tick_us + LATENCY_US, len(routed), bytes(msg.pack(encoder))))
            return image, tick_us

        cam.read = read_and_track  # type: ignore[method-assign]

        # The mock autopilot routes the camera's messages to the companion when due.
        send, deadline = mock.data_to_send, mock.next_deadline_us

        def data_to_send() -> bytes:
            out = send()
            while routed and routed[0][0] <= mock.now_us:
                out += heapq.heappop(routed)[2]
            return out

        def next_deadline_us() -> int:
            due = deadline()
            return min(due, routed[0][0]) if routed else due

        mock.data_to_send = data_to_send
        mock.next_deadline_us = next_deadline_us
        return cam

    return factory


@pytest.mark.slow  # a SITL run, seconds of CPU
def test_a_tracking_camera_over_the_mock_autopilot_feeds_the_boxes(tmp_path: Path) -> None:
    model = VirtualTimeModel()
    config = config_from_dict(
        {
            "detection": {"backend": "boxes"},
            "daemon": {
                "box_tracking": True,
                # The tracker's delay plus the link's: the message's own time is unknown.
                "box_tracking_latency_us": LATENCY_US + model.link_latency_us,
            },
        }
    )
    routed: list[tuple[int, int, bytes]] = []
    report = asyncio.run(
        run_sitl(
            config,
            duration_s=8.0,
            state_dir=str(tmp_path),
            clock="virtual",
            model=model,
            camera_factory=tracking_camera(routed),
        )
    )
    s = report.summary
    feed = s.box_feed
    assert feed["tracking messages"] >= s.processed - 2
    # Every frame but the first one or two (before the tracker's first message) had its
    # box, matched by time: nothing late, nothing unmatched.
    assert feed["frames with boxes"] >= s.processed - 2
    assert feed.get("late", 0) <= 2 and feed.get("unmatched", 0) == 0
    # ... and each frame waited for its own message: stamped (receipt - latency) at the
    # frame's instant, not ready before it came (a latency set to 0 gives every frame the
    # previous frame's box at once, and none waits).
    assert feed["frames waited"] >= s.processed - 2
    # Dropped: only what still waited for its box when the run stopped.
    assert s.frames_balance and s.dropped <= 2
    assert not [k for k in s.faults if k.startswith("box feed")], s.faults
    # T90: the moving ball is called moving, from the tracker's boxes alone.
    assert report.score.decided >= 100
    assert report.score.accuracy >= 0.9, report.lines()
