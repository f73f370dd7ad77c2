"""The live box feed (issue 14 §1, docs/box-feed.md): the ``tcm-boxes/1`` datagram parser,
and the Companion taking boxes from it — frames waiting (bounded) for their boxes, late,
future and malformed messages counted and never fatal, a feed that stops is a fault that
clears when it resumes.

The Companion is driven as the daemon drives it, on a fake clock, in time order:
telemetry at its receive time, each frame 1 ms after capture, each frame's boxes as a
datagram ``latency`` after capture, and ``process_due`` at every deadline it names. The
boxes are the simulated TS flight's true ones (the detector simulator without noise).
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tcm_companion.config import ConfigError, config_from_dict
from tcm_companion.core.camera import Pinhole
from tcm_companion.core.detection import Box, DetectionConfig
from tcm_companion.core.pipeline import PipelineConfig
from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.endpoint import CompanionEndpoint
from tcm_companion.replay.scenario import boxes_by_frame
from tcm_companion.service.box_feed import (
    MAX_BOXES,
    MAX_DATAGRAM_BYTES,
    BoxFeedError,
    encode_box_message,
    parse_box_datagram,
    parse_feed_url,
)
from tcm_companion.service.companion import Companion
from tcm_companion.service.daemon_config import DaemonConfig
from tcm_companion.sim.scene.detector_sim import DetectorSimConfig, simulate_detections
from tcm_companion.sim.scene.export import SimulatedScenario

from .helpers import CAMERA, FEED, FedDriver, simulated_flight

PINHOLE = Pinhole(640, 480, fx=320.0, fy=320.0, cx=320.0, cy=240.0)


def msg(**over: Any) -> bytes:
    doc: dict[str, Any] = {
        "v": 1,
        "camera": 0,
        "capture_mono_us": 5_000_000,
        "boxes": [{"x_min": 10.0, "y_min": 20.0, "x_max": 30.5, "y_max": 41.0, "score": 0.9}],
    }
    for k, v in over.items():
        if v is None:
            doc.pop(k)
        else:
            doc[k] = v
    return json.dumps(doc).encode()


# -- the datagram ----------------------------------------------------------------------------
def test_a_message_is_parsed_by_camera_index_or_name() -> None:
    m = parse_box_datagram(msg(), [CAMERA], ["front"])
    assert (m.camera_id, m.capture_mono_us, m.refused) == (0, 5_000_000, 0)
    assert m.boxes == (Box(10.0, 20.0, 30.5, 41.0, 0.9, ""),)
    m = parse_box_datagram(msg(camera="back"), [CAMERA, PINHOLE], ["front", "back"])
    assert m.camera_id == 1
    # Score defaults to 1, label optional; unknown keys are ignored (forward compatible).
    box = {"x_min": 1, "y_min": 2, "x_max": 3, "y_max": 4, "label": "car", "track": 7}
    m = parse_box_datagram(msg(boxes=[box], seq=12), [CAMERA], ["front"])
    assert m.boxes == (Box(1.0, 2.0, 3.0, 4.0, 1.0, "car"),)
    # An empty list: nothing in that frame.
    assert parse_box_datagram(msg(boxes=[]), [CAMERA], ["front"]).boxes == ()
    # What encode_box_message writes, parse reads.
    boxes = (Box(1.5, 2.0, 3.0, 4.25, 0.5, "person"), Box(300.0, 0.0, 20.0, 10.0, 0.7))
    m = parse_box_datagram(encode_box_message("front", 123, boxes), [CAMERA], ["front"])
    assert (m.capture_mono_us, m.boxes) == (123, boxes)


BAD_BOX = {"x_min": 1, "y_min": 2, "x_max": 3, "y_max": 4}


@pytest.mark.parametrize(
    ("data", "kind", "says"),
    [
        (b"\xff\xfe", "malformed", "not UTF-8 JSON"),
        (b"hello", "malformed", "not UTF-8 JSON"),
        (b"[1, 2]", "malformed", "not a JSON object"),
        (msg(v=None), "malformed", "v must be 1"),
        (msg(v=2), "malformed", "v must be 1"),
        (msg(v=True), "malformed", "v must be 1"),
        (msg(camera=None), "malformed", "camera must be"),
        (msg(camera=0.0), "malformed", "camera must be"),
        (msg(camera=True), "malformed", "camera must be"),
        (msg(camera=3), "unknown camera", "camera 3 is not in 0..0"),
        (msg(camera=-1), "unknown camera", "camera -1"),
        (msg(camera="back"), "unknown camera", "'back' is not one of ['front']"),
        (msg(capture_mono_us=None), "malformed", "capture_mono_us"),
        (msg(capture_mono_us=5e6), "malformed", "capture_mono_us"),
        (msg(capture_mono_us=-1), "malformed", "capture_mono_us"),
        (msg(capture_mono_us="5000000"), "malformed", "capture_mono_us"),
        (msg(boxes=None), "malformed", "boxes must be a list"),
        (msg(boxes={"x_min": 1}), "malformed", "boxes must be a list"),
        (msg(boxes=[[1, 2, 3, 4]]), "malformed", "boxes[0] must be an object"),
        (msg(boxes=[{"x_min": 1, "y_min": 2, "x_max": 3}]), "malformed", "has no y_max"),
        (msg(boxes=[{**BAD_BOX, "x_max": "3"}]), "malformed", "x_max must be a number"),
        (msg(boxes=[{**BAD_BOX, "y_min": None}]), "malformed", "y_min must be a number"),
        (msg(boxes=[{**BAD_BOX, "score": 1.5}]), "malformed", "score must be in [0, 1]"),
        (msg(boxes=[{**BAD_BOX, "label": 3}]), "malformed", "label must be a string"),
        (msg(boxes=[{**BAD_BOX, "label": "x" * 65}]), "malformed", "label must be a string"),
        (msg(boxes=[BAD_BOX] * (MAX_BOXES + 1)), "malformed", f"more than {MAX_BOXES}"),
        (b" " * (MAX_DATAGRAM_BYTES + 1), "malformed", f"more than {MAX_DATAGRAM_BYTES}"),
        # JSON's non-standard constants, which Python's json would otherwise accept.
        (msg().replace(b"30.5", b"NaN"), "malformed", "NaN is not a number here"),
        (msg().replace(b"30.5", b"Infinity"), "malformed", "Infinity is not a number"),
        (msg().replace(b"30.5", b"1e999"), "malformed", "x_max must be finite"),
        (b"[" * 100_00 + b"]" * 100_00, "malformed", ""),  # deep nesting: no RecursionError
        # Numbers too big for any arithmetic (issue 24 §3: a 4000-digit capture time raised
        # OverflowError in live_boxes.py, a traceback per datagram).
        pytest.param(
            msg(capture_mono_us=int("9" * 4000)),
            "malformed",
            "capture_mono_us must be",
            id="4000-digit capture_mono_us",
        ),
        (msg(capture_mono_us=2**63), "malformed", "below 2^63"),
        pytest.param(
            msg(boxes=[{**BAD_BOX, "x_min": int("9" * 400)}]),
            "malformed",
            "x_min must be finite",
            id="400-digit x_min",
        ),
        pytest.param(
            msg(boxes=[{**BAD_BOX, "score": -int("9" * 400)}]),
            "malformed",
            "score must be finite",
            id="400-digit score",
        ),
        pytest.param(
            msg(camera=int("9" * 4000)), "unknown camera", "camera 999", id="4000-digit camera"
        ),
        pytest.param(
            msg().replace(b"5000000", b"9" * 5000),
            "malformed",
            "Exceeds the limit",
            id="5000-digit capture_mono_us",
        ),
    ],
)
def test_a_malformed_datagram_is_refused_with_its_reason(data: bytes, kind: str, says: str) -> None:
    with pytest.raises(BoxFeedError) as err:
        parse_box_datagram(data, [CAMERA], ["front"])
    assert err.value.kind == kind
    assert says in str(err.value)


def test_boxes_outside_the_image_or_empty_are_refused_one_by_one() -> None:
    boxes = [
        {"x_min": 10, "y_min": 20, "x_max": 30, "y_max": 40},  # kept
        {"x_min": -1, "y_min": 20, "x_max": 30, "y_max": 40},  # left of the image
        {"x_min": 10, "y_min": 20, "x_max": 361, "y_max": 40},  # right of it
        {"x_min": 10, "y_min": 20, "x_max": 30, "y_max": 221},  # below it
        {"x_min": 10, "y_min": 40, "x_max": 30, "y_max": 20},  # upside down
        {"x_min": 10, "y_min": 20, "x_max": 10, "y_max": 40},  # no width
        {"x_min": 350, "y_min": 20, "x_max": 5, "y_max": 40},  # across the panorama's seam
    ]
    m = parse_box_datagram(msg(boxes=boxes), [CAMERA], ["front"])
    assert m.refused == 5
    assert [b.x_min for b in m.boxes] == [10.0, 350.0]
    # On a pinhole there is no seam: x_min > x_max is not a box.
    m = parse_box_datagram(msg(boxes=[boxes[-1]]), [PINHOLE], ["front"])
    assert (m.boxes, m.refused) == ((), 1)


def test_the_feed_address() -> None:
    assert parse_feed_url("") is None
    assert parse_feed_url("udp:127.0.0.1:14660") == ("127.0.0.1", 14660)
    assert parse_feed_url("udp:localhost:1") == ("localhost", 1)
    for bad in ("127.0.0.1:14660", "tcp:127.0.0.1:14660", "udp:127.0.0.1", "udp:h:70000"):
        with pytest.raises(ValueError):
            parse_feed_url(bad)


def test_the_configuration_names_the_bad_key() -> None:
    cfg = config_from_dict({"daemon": {"box_feed": FEED}, "detection": {"backend": "boxes"}})
    assert cfg.daemon.box_feed == FEED
    with pytest.raises(ConfigError, match=r"box_feed needs \[detection\] backend") as err:
        config_from_dict({"daemon": {"box_feed": FEED}}, "c.toml")
    assert err.value.key == "daemon.box_feed"
    with pytest.raises(ConfigError, match=r"c.toml: \[daemon\]: box_feed must be"):
        config_from_dict({"daemon": {"box_feed": "udp:x"}}, "c.toml")
    with pytest.raises(ConfigError, match=r"\[daemon\] box_wait_max_us = 0 is out of range"):
        config_from_dict({"daemon": {"box_wait_max_us": 0}}, "c.toml")
    with pytest.raises(ConfigError, match=r"\[daemon\] box_feed_timeout_us = 5 is out of range"):
        config_from_dict({"daemon": {"box_feed_timeout_us": 5}}, "c.toml")


# -- the Companion fed live -------------------------------------------------------------------
@pytest.fixture(scope="module")
def flight() -> tuple[SimulatedScenario, list[np.ndarray], dict[int, list[Box]]]:
    scenario, frames = simulated_flight(6.0)
    exact = DetectorSimConfig(
        centre_sigma_px=0.0, scale_sigma=0.0, miss_probability=0.0, false_per_frame=0.0
    )
    boxes = boxes_by_frame(simulate_detections(scenario, exact))
    assert len(boxes) > 0.9 * len(frames)  # the ball is boxed in (nearly) every frame
    return scenario, frames, boxes


@pytest.mark.slow  # over a second of CPU
def test_frames_wait_for_boxes_that_come_later_than_the_next_frame(flight: Any) -> None:
    """A detector 60 ms behind a 25-Hz camera: every frame waits for its boxes (a newer
    frame does not push out one still waiting), none is dropped, each is processed with
    its own boxes, and the stationary ball is called stationary."""
    drv = FedDriver(flight, warm=False)
    drv.frames_with_boxes(0, 150, latency_us=60_000)
    drv.run_until(drv.t(149) + 200_000)
    comp = drv.companion
    st = comp.stats.box_feed
    assert comp.stats.frames_processed == 150 and comp.stats.frames_dropped == 0
    # The two frames before the feed's first message did not wait (nothing said a feeder
    # was there): their boxes came late. Every frame after waited for its own.
    assert drv.replies == ["late"] * 2 + ["accepted"] * 148
    assert st["accepted"] == 148 and st["frames with boxes"] == 148
    assert st["frames without boxes"] == 2 and st["late"] == 2
    assert st["boxes"] == sum(len(drv.boxes.get(i, [])) for i in range(2, 150))
    # They waited for their boxes, and no longer: processed when the datagram came.
    waits = [p.process_mono_us - p.capture_mono_us for p in drv.processed]
    assert st["frames waited"] >= 140
    assert max(waits) <= 60_000 + comp.config.attitude_wait_max_us
    assert np.median(waits) == pytest.approx(60_000, abs=1)
    # Boxes of the true ball: TS's ball is stationary, and TCM says so.
    decided = [m for m in drv.statuses()[-40:] if m.state != d.TCM_OBJECT_STATE_UNKNOWN]
    assert len(decided) >= 30
    assert all(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in decided)
    assert comp.stats.faults.get("box feed missing", 0) == 0
    assert [t for t in drv.texts() if "box feed" in t] == ["TCM: box feed: 2 late"]
    assert "boxes 148 frames, 2 bad" in comp.status_line(drv.now)


def test_boxes_later_than_the_wait_are_counted_late_and_the_frames_go_on(flight: Any) -> None:
    """A detector slower than box_wait_max_us: each frame goes on without its boxes at
    the bound, the boxes then come for a frame already processed (late, counted, not
    used), the counter shows in the status line and one STATUSTEXT says so."""
    cfg = DaemonConfig(box_feed=FEED, box_wait_max_us=50_000)
    drv = FedDriver(flight, cfg)
    drv.frames_with_boxes(0, 50, latency_us=80_000)
    drv.run_until(drv.t(49) + 200_000)
    comp = drv.companion
    st = comp.stats.box_feed
    assert comp.stats.frames_processed == 50
    waits = [p.process_mono_us - p.capture_mono_us for p in drv.processed]
    assert max(waits) <= 50_000 + 1_000
    assert st["late"] == 50 and st["accepted"] == 1 and st["frames with boxes"] == 0
    assert drv.replies == ["accepted"] + ["late"] * 50  # (the warm-up message first)
    assert "50 bad" in comp.status_line(drv.now)
    # One STATUSTEXT for the condition (its key), however the count grows meanwhile.
    said = [t for t in drv.texts() if "box feed" in t]
    assert len(said) == 1 and re.fullmatch(r"TCM: box feed: \d+ late", said[0]), said


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_boxes_for_the_future_and_garbage_are_counted_and_harmless(flight: Any) -> None:
    """Every other datagram garbage, boxes stamped a second ahead (another clock), boxes
    outside the image, an unknown camera: all counted by kind, none used, nothing raised;
    the good datagrams between them work as if alone."""
    good = FedDriver(flight)
    good.frames_with_boxes(0, 60)
    good.run_until(good.t(59) + 200_000)

    junk = [
        b"\x00garbage",
        b'{"v": 1}',
        msg(camera=7),
        msg(boxes=[{"x_min": 1, "y_min": 2, "x_max": 3, "y_max": float("nan")}]),
    ]
    drv = FedDriver(flight)
    outside = [Box(-50.0, 10.0, 20.0, 30.0), Box(10.0, 10.0, 20.0, 400.0)]
    drv.frames_with_boxes(
        0, 60, datagram=lambda i, t: encode_box_message(0, t, [*drv.boxes.get(i, []), *outside])
    )
    for i in range(60):
        t = drv.t(i)
        drv._at(t + 20_000, "datagram", junk[i % len(junk)])
        drv._at(t + 30_000, "datagram", encode_box_message(0, t + 1_000_000, []))  # future
    drv.run_until(drv.t(59) + 200_000)
    st = drv.companion.stats.box_feed
    assert st["malformed"] == 45 and st["unknown camera"] == 15
    assert st["future"] == 60 and st["boxes refused"] == 120
    assert st["datagrams"] == 60 * 3 + 1
    assert st["frames with boxes"] == 60 and drv.companion.stats.frames_dropped == 0
    # The same objects and states as without the junk.
    states = [(m.track_id, m.state) for m in drv.statuses()]
    assert states == [(m.track_id, m.state) for m in good.statuses()]
    text = "".join(drv.texts())  # (a long text goes in 50-character chunks)
    assert re.search(r"TCM: box feed: \d+ malformed, \d+ unknown camera, \d+ future", text)


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_a_feed_that_stops_is_a_fault_until_it_resumes(flight: Any) -> None:
    """No message for box_feed_timeout_us: ``box feed stale`` (one fault, one STATUSTEXT),
    the last objects once more as unknown, frames stop waiting for boxes that are not
    coming; when it resumes, ``box feed OK`` and frames with boxes again."""
    drv = FedDriver(flight)
    drv.frames_with_boxes(0, 50)
    drv.frames_with_boxes(50, 100, datagram=lambda i, t: None)  # the feeder stops
    drv.frames_with_boxes(100, 150)  # ... and resumes
    drv.run_until(drv.t(49) + 100_000)
    comp = drv.companion
    assert comp.last_objects(0), "objects were tracked while the feed ran"
    before = len(drv.statuses())
    drv.run_until(drv.t(99) + 40_000)
    assert comp.stats.faults["box feed stale"] == 1
    texts = drv.texts()
    assert texts.count("TCM: box feed stale") == 1
    assert drv.statuses()[:before], "statuses while the feed ran"
    assert "box feed stale" in comp.status_line(drv.now)
    # Frames captured box_feed_timeout_us after the feed's last message do not wait.
    silent_since = drv.t(49) + 60_000
    waits = [
        p.process_mono_us - p.capture_mono_us
        for p in drv.processed
        if p.capture_mono_us > silent_since + comp.config.box_feed_timeout_us
    ]
    assert len(waits) >= 20
    assert waits and max(waits) <= comp.config.attitude_wait_max_us + 1_000
    drv.run_until(drv.t(149) + 100_000)
    assert "TCM: box feed OK" in drv.texts()
    assert comp.stats.faults["box feed stale"] == 1
    # The first two frames after it resumed did not wait (the feed was silent until their
    # boxes came, 60 ms after each): their boxes were late; every later frame had its own.
    assert comp.stats.box_feed["frames with boxes"] == 98
    assert comp.stats.box_feed["late"] == 2
    assert comp.stats.frames_processed == 150
    # Between the fault and the recovery, no object was reported decided.
    kinds = [
        "stale"
        if m.get_type() == "STATUSTEXT" and m.text == "TCM: box feed stale"
        else "ok"
        if m.get_type() == "STATUSTEXT" and m.text == "TCM: box feed OK"
        else "decided"
        if m.get_type() == "TCM_OBJECT_STATUS" and m.state != d.TCM_OBJECT_STATE_UNKNOWN
        else ""
        for m in drv.sent
    ]
    stale, ok = kinds.index("stale"), kinds.index("ok")
    assert "decided" in kinds[:stale] and "decided" not in kinds[stale:ok]
    assert "decided" in kinds[ok:], "decisions again after the feed resumed"


def test_no_feeder_at_all_is_a_fault_and_frames_do_not_wait(flight: Any) -> None:
    drv = FedDriver(flight, warm=False)
    drv.frames_with_boxes(0, 60, datagram=lambda i, t: None)
    drv.run_until(drv.t(59) + 100_000)
    comp = drv.companion
    assert comp.stats.faults["box feed missing"] == 1
    assert "TCM: box feed missing" in drv.texts()
    assert comp.stats.frames_processed == 60
    assert comp.stats.box_feed["frames without boxes"] == 60
    assert comp.stats.box_feed["frames waited"] == 0


def test_without_a_feed_nothing_changes(flight: Any) -> None:
    """No box_feed: no feed input, no waiting, boxes offered are not used."""
    drv = FedDriver(flight, DaemonConfig())
    drv.frames_with_boxes(0, 20)
    drv.run_until(drv.t(19) + 100_000)
    comp = drv.companion
    assert "box feed" not in comp.inputs.monitors
    assert comp.stats.box_feed["unused"] == 21  # (with the warm-up message)
    assert "boxes" not in comp.status_line(drv.now)


# -- a tracking camera's CAMERA_TRACKING_IMAGE_STATUS -------------------------------------------
def tracking_bytes(
    box: Box | None,
    status: int = d.CAMERA_TRACKING_STATUS_FLAGS_ACTIVE,
    mode: int = d.CAMERA_TRACKING_MODE_RECTANGLE,
) -> bytes:
    """The message as a MAVLink camera (system 1, component 100) sends it: the rectangle
    normalised to 0..1."""
    mav = d.MAVLink(None, srcSystem=1, srcComponent=d.MAV_COMP_ID_CAMERA)
    w, h = CAMERA.width, CAMERA.height
    rect = (
        (box.x_min / w, box.y_min / h, box.x_max / w, box.y_max / h)
        if box is not None
        else (math.nan,) * 4
    )
    msg = d.MAVLink_camera_tracking_image_status_message(
        status, mode, d.CAMERA_TRACKING_TARGET_DATA_IN_STATUS, math.nan, math.nan, math.nan, *rect
    )
    return bytes(msg.pack(mav))


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_a_tracking_cameras_rectangle_is_the_frames_box(flight: Any) -> None:
    """CAMERA_TRACKING_IMAGE_STATUS through the endpoint: the rectangle, scaled to the
    image, is the box of the frame captured box_tracking_latency_us before it arrived;
    every frame gets its box and the stationary ball is called stationary. A rectangle
    with NaN corners is malformed, "not tracking" is a frame without boxes."""
    cfg = DaemonConfig(box_tracking=True, box_tracking_latency_us=60_000)
    drv = FedDriver(flight, cfg, warm=False)
    boxes = drv.boxes
    for i in range(100):
        t = drv.t(i)
        drv._at(t + 1_000, "frame", (i, t))
        found = boxes.get(i, [])
        data = tracking_bytes(found[0]) if found else tracking_bytes(None, status=0)
        drv._at(t + 60_000, "mavlink", data)
    drv._at(drv.t(99) + 70_000, "mavlink", tracking_bytes(None))  # NaN corners
    drv.run_until(drv.t(99) + 200_000)
    comp = drv.companion
    st = comp.stats.box_feed
    assert st["tracking messages"] == 101
    assert st["malformed"] == 1
    # The first two frames went before the first message (60 ms after the first frame,
    # 20 ms after the second): their boxes were late; every later frame had its own.
    assert st["accepted"] == 98 and st["late"] == 2
    assert st["frames with boxes"] == 98 and comp.stats.frames_dropped == 0
    assert st["boxes"] == sum(1 for i in range(2, 100) if boxes.get(i))
    labels = {o.label for o in comp.last_objects(0)}
    assert labels == {"tracked"}
    decided = [m for m in drv.statuses()[-30:] if m.state != d.TCM_OBJECT_STATE_UNKNOWN]
    assert len(decided) >= 20
    assert all(m.state == d.TCM_OBJECT_STATE_STATIONARY for m in decided)


def test_tracking_messages_are_ignored_unless_configured(flight: Any) -> None:
    drv = FedDriver(flight, DaemonConfig(), warm=False)
    drv._at(drv.t(0), "mavlink", tracking_bytes(drv.boxes[0][0]))
    drv.run_until(drv.t(0) + 10_000)
    assert drv.companion.stats.box_feed["tracking ignored"] == 1
    assert drv.companion.stats.box_feed["accepted"] == 0


# -- anything at all ------------------------------------------------------------------------
_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8),
    lambda inner: (
        st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4)
    ),
    max_leaves=12,
)
_box_like = st.fixed_dictionaries(
    {
        k: st.one_of(st.floats(), st.integers(), st.none(), st.text(max_size=3))
        for k in ("x_min", "y_min", "x_max", "y_max")
    },
    optional={"score": _json, "label": _json},
)
_message_like = st.fixed_dictionaries(
    {},
    optional={
        "v": st.one_of(st.just(1), _json),
        "camera": st.one_of(st.sampled_from([0, 1, "front", "x"]), _json),
        "capture_mono_us": st.one_of(st.integers(-(2**70), 2**70), _json),
        "boxes": st.one_of(st.lists(st.one_of(_box_like, _json), max_size=5), _json),
    },
)


@pytest.mark.slow  # over a second of CPU
@settings(max_examples=300, deadline=None)
@given(
    st.one_of(
        st.binary(max_size=200),
        _json.map(lambda x: json.dumps(x).encode()),
        _message_like.map(lambda x: json.dumps(x).encode()),
    )
)
def test_no_datagram_raises_anything_but_a_refusal(data: bytes) -> None:
    """Random bytes, random JSON, random near-messages: parsed, or refused with a kind."""
    try:
        m = parse_box_datagram(data, [CAMERA], ["front"])
    except BoxFeedError as exc:
        assert exc.kind in ("malformed", "unknown camera")
    else:
        for b in m.boxes:
            assert all(math.isfinite(v) for v in (b.x_min, b.y_min, b.x_max, b.y_max, b.score))


#: Values a hostile feeder sends: integers of up to 4200 digits (Python's json reads up
#: to 4300), every float (NaN and infinities as JSON's non-standard constants), strings,
#: and nested containers.
_huge = st.builds(
    lambda digits, sign: sign * int("9" * digits), st.integers(300, 4200), st.sampled_from([1, -1])
)
_hostile_scalar = st.one_of(
    _huge, st.integers(), st.floats(), st.none(), st.booleans(), st.text(max_size=5)
)
_hostile = st.recursive(
    _hostile_scalar,
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner, max_size=3)
    ),
    max_leaves=8,
)


def _spoil(doc: dict[str, Any], where: list[str], value: Any) -> dict[str, Any]:
    """``doc`` with the field at path ``where`` replaced by ``value`` (None: removed);
    unchanged when an earlier change took the path away."""
    out = json.loads(json.dumps(doc))
    parent: Any = out
    for key in where[:-1]:
        try:
            parent = parent[key] if isinstance(parent, dict) else parent[int(key)]
        except (KeyError, IndexError, TypeError, ValueError):
            return out
    if not isinstance(parent, dict):
        return out
    if value is None:
        parent.pop(where[-1], None)
    else:
        parent[where[-1]] = value
    return out


_GOOD = json.loads(msg())
#: A good message with one or two of its fields hostile.
_hostile_message = st.builds(
    lambda first, second: _spoil(_spoil(_GOOD, *first), *second),
    *[
        st.tuples(
            st.sampled_from(
                [["v"], ["camera"], ["capture_mono_us"], ["boxes"]]
                + [
                    ["boxes", "0", k]
                    for k in ("x_min", "y_min", "x_max", "y_max", "score", "label")
                ]
            ).map(list),
            st.one_of(st.none(), _huge, _hostile_scalar, _hostile),
        )
    ]
    * 2,
)

_hostile_datagram = st.one_of(
    _hostile_message.map(lambda x: json.dumps(x).encode()),
    _hostile_message.map(lambda x: json.dumps(x).encode()[:-3]),  # cut short
    st.binary(max_size=64).map(lambda b: b"\xff" + b),  # not UTF-8
    st.integers(1, 3000).map(lambda n: b"[" * n + b"]" * n),  # deep nesting
    st.integers(0, 100).map(lambda n: b" " * (MAX_DATAGRAM_BYTES - 50 + n) + b"{}"),  # huge
)


@pytest.mark.slow  # over a second of CPU
@settings(max_examples=300, deadline=None)
@given(st.lists(_hostile_datagram, min_size=1, max_size=6))
def test_hostile_datagrams_are_refused_and_counted_never_raised(datagrams: list[bytes]) -> None:
    """Huge numbers, NaN and infinities, negatives, wrong types, deep nesting, huge and
    non-UTF-8 datagrams: each is used or refused with a counted kind; nothing raises
    (before issue 24 a 4000-digit number raised OverflowError), and a good datagram
    after them is still used."""
    pipeline = dataclasses.replace(PipelineConfig(), detection=DetectionConfig(backend="boxes"))
    comp = Companion(
        [CAMERA], pipeline, CompanionEndpoint(now_us=0), 0, DaemonConfig(box_feed=FEED), ["front"]
    )
    kinds = [comp.on_box_datagram(data, 1_000_000 + 1000 * i) for i, data in enumerate(datagrams)]
    assert set(kinds) <= {"accepted", "malformed", "unknown camera", "late", "future"}, kinds
    counts = comp.stats.box_feed
    assert counts["datagrams"] == len(datagrams)
    for kind in set(kinds):
        assert counts[kind] == kinds.count(kind)
    good = encode_box_message(0, 1_900_000, [Box(10.0, 20.0, 30.0, 40.0, 0.9, "")])
    assert comp.on_box_datagram(good, 2_000_000) == "accepted"


@pytest.mark.slow  # over a second of CPU
@settings(max_examples=200, deadline=None)
@given(st.lists(_message_like.map(lambda x: json.dumps(x).encode()), max_size=8))
def test_the_companion_takes_any_datagrams_and_counts_each(datagrams: list[bytes]) -> None:
    pipeline = dataclasses.replace(PipelineConfig(), detection=DetectionConfig(backend="boxes"))
    comp = Companion(
        [CAMERA], pipeline, CompanionEndpoint(now_us=0), 0, DaemonConfig(box_feed=FEED), ["front"]
    )
    kinds = [comp.on_box_datagram(data, 1_000_000 + 1000 * i) for i, data in enumerate(datagrams)]
    st_ = comp.stats.box_feed
    assert st_["datagrams"] == len(datagrams)
    for kind in set(kinds):
        assert st_[kind] == kinds.count(kind)
    comp.process_due(5_000_000)  # and the health check after them
