"""The MCAP flight log: round trip, Foxglove-readable files, a never-blocking producer,
crash safety under SIGKILL, rotation, the free-space floor and write faults."""

from __future__ import annotations

import errno
import itertools
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from tcm_companion.flightlog import encoding as log_encoding
from tcm_companion.flightlog import reader as log_reader
from tcm_companion.flightlog import topics
from tcm_companion.flightlog import writer as fl
from tcm_companion.flightlog.reader import (
    LogReport,
    check_log,
    decode_image,
    decode_json,
    log_files,
    read_log,
    read_metadata,
)
from tcm_companion.flightlog.settings import LoggingConfig
from tcm_companion.flightlog.stats import FlightLogStats
from tcm_companion.flightlog.writer import FlightLogWriter
from tcm_companion.io.aio import monotonic_us

REPO = Path(__file__).resolve().parents[1]
WALL = 1_790_000_000_000_000_000 - 5_000_000_000  # a fixed wall-minus-monotonic offset (ns)
T0 = 12_000_000_000  # µs, a monotonic time stamp


@pytest.fixture(scope="module")
def sim_frames() -> list[np.ndarray]:
    """50 frames (2 s at 25 Hz) of the simulated T90 flight at 360×220."""
    from tcm_companion.sim import make_scenario

    return [img for _, _, img in make_scenario("T90", duration_s=2).iter_frames()]


def wait_for(pred: Callable[[], bool], timeout: float = 5.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.005)
    return pred()


def noise_image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (220, 360, 3), dtype=np.uint8)


def seeking_messages(path: Path) -> int:
    """Messages mcap's seeking reader returns, or -1 if it raises."""
    try:
        with open(path, "rb") as f:
            return sum(1 for _ in make_reader(f).iter_messages())
    except Exception:
        return -1


def writer_with_events(
    directory: Path, **kwargs: Any
) -> tuple[FlightLogWriter, list[tuple[str, str]]]:
    """A started writer flushing every 50 ms, and the list its events go to."""
    events: list[tuple[str, str]] = []
    w = FlightLogWriter(
        LoggingConfig(flush_interval_s=0.05),
        directory,
        wall_minus_mono_ns=WALL,
        on_event=lambda sev, text: events.append((sev, text)),
        **kwargs,
    )
    w.start({})
    return w, events


def frames_account(s: FlightLogStats, calls: int) -> None:
    assert (
        s.frames_logged + s.frames_dropped_queue + s.frames_dropped_disk + s.frames_dropped_error
        == calls
    ), s


# ---------------------------------------------------------------------------------------
# Config


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("image_format", "webp"),
        ("jpeg_quality", 0),
        ("jpeg_quality", 101),
        ("queue_items", 0),
        ("chunk_size_bytes", 10),
        ("flush_interval_s", 0.0),
        ("rotate_size_mb", 0),
        ("rotate_interval_s", -1.0),
        ("min_free_mb", -1.0),
        ("enabled", "yes"),
    ],
)
def test_config_range_checks_name_the_field(field: str, value: Any) -> None:
    with pytest.raises(ValueError, match=field):
        LoggingConfig(**{field: value})


def test_defaults_and_state_codes_match_the_dialect(tmp_path: Path) -> None:
    from tcm_companion.mavlink import tcm_dialect as d

    c = LoggingConfig()
    assert (c.queue_items, c.chunk_size_bytes, c.flush_interval_s) == (256, 262_144, 0.5)
    assert FlightLogStats(state="off").log_state_code == d.TCM_LOG_STATE_OFF
    assert FlightLogStats(state="recording").log_state_code == d.TCM_LOG_STATE_RECORDING
    assert FlightLogStats(state="frames paused (disk)").log_state_code == 1
    assert FlightLogStats(state="fault").log_state_code == d.TCM_LOG_STATE_FAULT

    # disabled: nothing written, calls refused and counted, stop idempotent
    w = FlightLogWriter(LoggingConfig(enabled=False), tmp_path / "off")
    w.start({})
    assert w.log_frame(0, T0, noise_image(0)) is False
    assert w.log_mavlink("in", T0, b"x") is False
    w.stop()
    w.stop()
    s = w.stats
    assert (s.state, s.log_state_code, s.files) == ("off", 0, [])
    assert (s.frames_dropped_queue, s.messages_dropped_queue) == (1, 1)
    assert not (tmp_path / "off").exists()
    FlightLogWriter(LoggingConfig(), tmp_path / "never").stop()  # stop without start


# ---------------------------------------------------------------------------------------
# The topic table, the counts, the reader on its own


def test_the_topic_table_is_the_one_the_docs_list() -> None:
    """flightlog/topics.py and the table of docs/logging.md name the same topics and encodings."""
    doc = (REPO / "docs" / "logging.md").read_text(encoding="utf-8")
    rows = [ln for ln in doc.splitlines() if ln.startswith("| `/")]
    documented: dict[str, str] = {}
    for row in rows:
        names, encoding = row.split("|")[1:3]
        for name in re.findall(r"`(/[^`]+)`", names):
            documented[name] = encoding.strip()
    table = {t.name.replace("{camera}", "{N}"): t for t in topics.TOPICS}
    assert set(documented) == set(table)
    for name, t in table.items():
        assert documented[name] == t.encoding, (name, documented[name])
    assert topics.camera_image(3) == "/camera3/image"
    assert topics.camera_of("/camera12/image") == 12
    assert topics.camera_of("/camera1/annotations", topics.CAMERA_ANNOTATIONS) == 1
    assert topics.camera_of("/tcm/result") is None
    assert topics.spec("/camera7/annotations").schema == topics.ANNOTATIONS_SCHEMA
    assert fl.MAVLINK_TOPICS == {"in": topics.MAVLINK_IN, "out": topics.MAVLINK_OUT}


def test_one_counts_object_and_its_snapshots(tmp_path: Path) -> None:
    w = FlightLogWriter(LoggingConfig(), tmp_path, wall_minus_mono_ns=WALL)
    before = w.stats
    assert not w.log_frame(0, T0, noise_image(0))  # not started: dropped, counted
    assert not w.log_json(topics.RESULT, T0, {})
    s = w.stats
    assert (s.frames_dropped_queue, s.messages_dropped_queue) == (1, 1)
    assert (s.frames_queued, s.messages_queued, s.state) == (0, 0, "off")
    assert before.frames_dropped_queue == 0  # a snapshot does not move
    s.frames_dropped_queue = 99  # nor does changing one touch the writer's counts
    s.files.append(tmp_path)
    assert w.stats.frames_dropped_queue == 1 and w.stats.files == []


def test_the_reader_module_is_the_log_readerers(tmp_path: Path) -> None:
    assert fl.read_log is log_reader.read_log and fl.LogRecord is log_reader.LogRecord
    assert log_reader.part_name("20260101-000000", 7) == "tcm-20260101-000000-007.mcap"
    with pytest.raises(FileNotFoundError):
        log_reader.log_files(tmp_path / "none")


# ---------------------------------------------------------------------------------------
# Round trip


def write_everything(directory: Path, fmt: str, frames: list[np.ndarray]) -> list[tuple]:
    """Log frames of two cameras, annotations, MAVLink both ways and JSON; return the calls
    in order as (topic, t_us, payload)."""
    w = FlightLogWriter(
        LoggingConfig(image_format=fmt),  # type: ignore[arg-type]
        directory,
        wall_minus_mono_ns=WALL,
    )
    w.start({"version": "9.9.9", "config": "[logging]\nenabled = true\n", "camera0": {"w": 360}})
    calls: list[tuple] = []
    rng = np.random.default_rng(7)
    for i, img in enumerate(frames):
        t = T0 + 40_000 * i
        cam = i % 2
        assert w.log_frame(cam, t, img)
        calls.append((f"/camera{cam}/image", t, img))
        circles = [(100.5 + i, 50.25, 7.5, "moving ttc 2.1 s"), (200.0, 80.0, 4.0, "stationary")]
        circles.append((300.0, 100.0, 3.0, "unknown"))
        assert w.log_annotations(cam, t, circles)
        calls.append((f"/camera{cam}/annotations", t, circles))
        for direction in ("in", "out"):
            data = bytes(rng.integers(0, 256, int(rng.integers(12, 280)), dtype=np.uint8))
            assert w.log_mavlink(direction, t + 1_000, data)
            calls.append((f"/mavlink/{direction}", t + 1_000, data))
        for topic in ("/tcm/result", "/tcm/health", "/tcm/event", "/tcm/param"):
            doc = {"i": i, "x": np.float32(0.5) * i, "bad": float("nan"), "tags": ("a", "b")}
            assert w.log_json(topic, t + 2_000, doc)
            calls.append(
                (topic, t + 2_000, {"i": i, "x": 0.5 * i, "bad": None, "tags": ["a", "b"]})
            )
    w.stop()
    s = w.stats
    assert s.frames_logged == len(frames) and s.frames_dropped_queue == 0
    assert s.messages_logged == len(calls) - len(frames)
    assert s.write_errors == 0 and s.encode_errors == 0 and s.state == "off"
    assert len(s.files) == 1 and s.bytes_written == s.files[0].stat().st_size
    return calls


@pytest.mark.slow  # over a second of CPU
def test_round_trip_png_is_bit_exact(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    frames = sim_frames[:6]
    calls = write_everything(tmp_path, "png", frames)
    records = list(read_log(tmp_path))
    # every message, in write order, on its topic
    assert [(r.topic, r.publish_time_ns // 1000) for r in records] == [(c[0], c[1]) for c in calls]
    assert {r.topic for r in records} == {
        "/camera0/image",
        "/camera1/image",
        "/camera0/annotations",
        "/camera1/annotations",
        "/mavlink/in",
        "/mavlink/out",
        "/tcm/result",
        "/tcm/health",
        "/tcm/event",
        "/tcm/param",
    }
    for rec, (topic, t, payload) in zip(records, calls, strict=True):
        assert rec.publish_time_ns == t * 1000
        assert rec.log_time_ns == t * 1000 + WALL
        if topic.endswith("/image"):
            cam, t_us, img = decode_image(rec)
            assert (cam, t_us) == (int(topic[7]), t)
            assert img.dtype == np.uint8 and np.array_equal(img, payload)  # lossless
            msg = CompressedImage.FromString(rec.data)
            assert msg.format == "png" and msg.frame_id == f"camera{cam}"
            assert msg.timestamp.ToNanoseconds() == rec.log_time_ns
        elif topic.startswith("/mavlink"):
            assert (rec.data, rec.message_encoding, rec.schema_name) == (payload, "mavlink", "")
        elif topic.endswith("/annotations"):
            ann = ImageAnnotations.FromString(rec.data)
            assert rec.schema_name == "foxglove.ImageAnnotations"
            assert [(c.position.x, c.position.y, c.diameter) for c in ann.circles] == [
                (u, v, 2 * r) for u, v, r, _ in payload
            ]
            assert [t.text for t in ann.texts] == [label for *_, label in payload]
            colours = [(c.outline_color.r, c.outline_color.g) for c in ann.circles]
            assert colours[0][0] > 0.9 > colours[0][1]  # moving: red
            assert colours[1][1] > 0.8 > colours[1][0]  # stationary: green
            assert colours[2][0] == colours[2][1]  # else grey
            assert all(c.timestamp.ToNanoseconds() == rec.log_time_ns for c in ann.circles)
        else:
            assert rec.message_encoding == "json" and rec.schema_name == topic
            assert decode_json(rec) == payload
    meta = read_metadata(tmp_path)
    assert meta["version"] == "9.9.9" and meta["config"] == "[logging]\nenabled = true\n"
    assert json.loads(meta["camera0"]) == {"w": 360}
    assert meta["wall_minus_mono_ns"] == str(WALL) and meta["image_format"] == "png"
    # a topic filter
    only = list(read_log(tmp_path, topics={"/mavlink/out"}))
    assert [r.data for r in only] == [c[2] for c in calls if c[0] == "/mavlink/out"]


def test_jpeg_round_trip_is_close(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    frames = sim_frames[10:14]
    write_everything(tmp_path, "jpeg", frames)
    images = [decode_image(r) for r in read_log(tmp_path) if r.topic.endswith("/image")]
    assert len(images) == len(frames)
    for (_, _, img), ref in zip(images, frames, strict=True):
        err = img.astype(float) - ref.astype(float)
        psnr = 10 * np.log10(255**2 / np.mean(err**2))
        assert img.shape == ref.shape and psnr > 30, psnr
    assert read_metadata(tmp_path)["jpeg_quality"] == str(LoggingConfig().jpeg_quality)


@pytest.mark.slow  # over a second of CPU
def test_file_is_foxglove_readable_with_a_summary(
    tmp_path: Path, sim_frames: list[np.ndarray]
) -> None:
    calls = write_everything(tmp_path, "jpeg", sim_frames[:4])
    (path,) = log_files(tmp_path)
    assert path.name.startswith("tcm-") and path.name.endswith("-000.mcap")
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(calls)
        assert len(summary.chunk_indexes) >= 1
        schemas = {s.name: s for s in summary.schemas.values()}
        assert {"foxglove.CompressedImage", "foxglove.ImageAnnotations"} <= set(schemas)
        assert schemas["foxglove.CompressedImage"].encoding == "protobuf"
        assert json.loads(schemas["/tcm/result"].data) == {"title": "/tcm/result", "type": "object"}
        assert schemas["/tcm/result"].encoding == "jsonschema"
        channels = {c.topic: c for c in summary.channels.values()}
        assert channels["/mavlink/in"].schema_id == 0
        assert channels["/mavlink/in"].message_encoding == "mavlink"
        assert channels["/tcm/health"].message_encoding == "json"
        # the seeking (indexed) reader gets every message, and the protobuf schemas decode
        assert sum(1 for _ in reader.iter_messages()) == len(calls)
        decoded = list(reader.iter_decoded_messages(topics=["/camera0/image"]))
        assert len(decoded) == 2 and decoded[0].decoded_message.format == "jpeg"
        (meta,) = [m for m in reader.iter_metadata() if m.name == "tcm-companion"]
        assert meta.metadata["version"] == "9.9.9"


def test_log_files_order_and_damaged_tails(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    names = [
        "tcm-20260101-120000-1000.mcap",
        "tcm-20260101-120000-002.mcap",
        "tcm-20251231-235959-000.mcap",
        "tcm-20260101-120000-999.mcap",
    ]
    for n in names:
        (tmp_path / n).write_bytes(b"")
    (tmp_path / "other.mcap").write_bytes(b"")
    assert [p.name for p in log_files(tmp_path)] == [names[2], names[1], names[3], names[0]]
    assert log_files(tmp_path / names[0]) == [tmp_path / names[0]]
    with pytest.raises(FileNotFoundError):
        log_files(tmp_path / "missing")
    assert list(read_log(tmp_path)) == [] and read_metadata(tmp_path) == {}  # empty parts

    good = tmp_path / "good"
    write_everything(good, "jpeg", sim_frames[:3])
    (path,) = log_files(good)
    full = [(r.topic, r.publish_time_ns, r.data) for r in read_log(path)]
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    for size in (0, 5, 8, 40, len(data) // 3, len(data) // 2, len(data) - 100, len(data) - 1):
        cut.write_bytes(data[:size])
        got = [(r.topic, r.publish_time_ns, r.data) for r in read_log(cut)]  # never raises
        assert got == full[: len(got)], size  # a prefix of the full log
    assert got == full  # a missing footer only: everything


def test_the_reader_says_how_much_of_a_truncated_or_damaged_file_it_read(
    tmp_path: Path, sim_frames: list[np.ndarray]
) -> None:
    """It stops at a damaged tail, as before, but not silently (issue 13): the report says
    the part is truncated or damaged, where, how much of the file was readable and the
    time of the last message read."""
    good = tmp_path / "good"
    write_everything(good, "png", sim_frames[:6])  # several 256 KiB chunks
    (path,) = log_files(good)
    data = path.read_bytes()
    report = LogReport()
    full = list(read_log(path, report=report))
    (part,) = report.parts
    assert (part.complete, part.kind, part.read_bytes, part.messages) == (
        True, "complete", len(data), len(full)
    )  # fmt: skip
    assert report.problems() == [] and check_log(path).problems() == []
    t0 = full[0].publish_time_ns
    cut = tmp_path / "cut.mcap"
    for size in (0, 5, 40, len(data) // 3, len(data) // 2, len(data) - 100, len(data) - 1):
        cut.write_bytes(data[:size])
        report = LogReport()
        got = list(read_log(cut, {"/camera0/image"}, report))  # a topic filter changes nothing
        (part,) = report.parts
        assert (part.kind, part.damaged, part.size_bytes) == ("truncated", True, size), size
        assert part.read_bytes <= size
        (line,) = report.problems()
        assert line.startswith(f"{cut}: truncated: "), line
        if 0 < part.read_bytes < size:
            assert f"{part.read_bytes} of {size} bytes" in line
        every = list(read_log(cut))
        assert part.messages == len(every)
        assert len(got) == sum(1 for r in every if r.topic == "/camera0/image")
        if every:
            last = (every[-1].publish_time_ns - t0) / 1e9
            assert f"{len(every)} messages readable, the last {last:.2f} s into the log" in line
        else:
            assert "no message readable" in line
        assert check_log(cut).problems() == report.problems()
    assert part.messages == len(full)  # a cut footer only: every message, still reported

    broken = bytearray(data)
    broken[len(data) // 2] ^= 0xFF  # inside a chunk: its CRC fails, the rest is unread
    cut.write_bytes(bytes(broken))
    report = check_log(cut)
    (part,) = report.parts
    assert part.kind == "damaged" and 0 < part.read_bytes < len(data) // 2
    (line,) = report.problems()
    assert f"damaged at byte {part.read_bytes} of {len(data)} (CRCValidationError" in line


def test_a_damaged_part_of_several_is_named(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    # Three parts of one flight, as the writer's rotation leaves them (a part per frame:
    # rotated by the records' time). Three copies of one part were used before: since
    # flights have ids (issue 24), those are one part three times, not three parts.
    log = tmp_path / "log"
    w = FlightLogWriter(
        LoggingConfig(image_format="jpeg", rotate_interval_s=0.04),
        log,
        wall_minus_mono_ns=WALL,
        deterministic=True,
        session="20260101-120000",
    )
    w.start({"camera0": {"w": 360}})
    for i, img in enumerate(sim_frames[:3]):
        assert w.log_frame(0, T0 + 40_000 * i, img)
        assert w.log_json("/tcm/result", T0 + 40_000 * i + 2_000, {"i": i})
    w.stop()
    parts = w.stats.files
    assert parts == log_files(log) and len(parts) == 3
    data = parts[1].read_bytes()
    parts[1].write_bytes(data[: len(data) - 200])  # the middle part lost its end
    report = LogReport()
    n = sum(1 for _ in read_log(log, report=report))
    assert [p.kind for p in report.parts] == ["complete", "truncated", "complete"]
    assert n == sum(p.messages for p in report.parts) and report.parts[0].messages > 0
    (line,) = report.problems()
    assert line.startswith(f"part 2 of 3: {parts[1]}: truncated: ")
    assert report.damaged == [report.parts[1]]


# ---------------------------------------------------------------------------------------
# The producer never blocks


def test_full_queue_drops_and_counts_but_never_blocks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The writer is stuck (its image encoder waits until released): a producer that
    # blocked on the full queue would never get through its calls. No wall-clock bound
    # on each call (a loaded machine would fail that): the calls must simply all return.
    real_encode = log_encoding.encode_image
    release = threading.Event()

    def stuck_encode(image: np.ndarray, config: LoggingConfig) -> bytes:
        release.wait(30.0)
        return real_encode(image, config)

    monkeypatch.setattr(log_encoding, "encode_image", stuck_encode)
    w = FlightLogWriter(LoggingConfig(queue_items=8), tmp_path, wall_minus_mono_ns=WALL)
    w.start({})
    img = noise_image(1)
    accepted: list[int] = []
    mav_ok: list[bytes] = []
    n = 150

    def produce() -> None:
        for i in range(n):
            t = T0 + 10_000 * i
            if w.log_frame(0, t, img):
                accepted.append(t)
            if w.log_mavlink("out", t, i.to_bytes(2, "little")):
                mav_ok.append(i.to_bytes(2, "little"))
            assert isinstance(w.log_json("/tcm/result", t, {"i": i}), bool)

    producer = threading.Thread(target=produce, daemon=True)
    producer.start()
    producer.join(20.0)
    stuck_while_writer_stuck = producer.is_alive()
    release.set()
    producer.join(20.0)
    assert not stuck_while_writer_stuck, "a log_* call blocked on the full queue"
    w.stop(timeout_s=10)
    s = w.stats
    assert s.frames_dropped_queue > 0 and s.messages_dropped_queue > 0
    assert s.frames_queued == len(accepted) and s.frames_logged == len(accepted)
    frames_account(s, n)
    assert s.frames_dropped_error == 0 and s.frames_dropped_disk == 0
    assert s.messages_logged + s.messages_dropped_queue == 2 * n
    images = [r.publish_time_ns // 1000 for r in read_log(tmp_path, {"/camera0/image"})]
    assert images == accepted  # exactly the accepted frames, in order
    assert [r.data for r in read_log(tmp_path, {"/mavlink/out"})] == mav_ok


# ---------------------------------------------------------------------------------------
# Crash safety

CRASH_WRITER = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from tcm_companion.flightlog.settings import LoggingConfig
    from tcm_companion.flightlog.writer import FlightLogWriter

    w = FlightLogWriter(LoggingConfig(), sys.argv[1])  # default flush interval and chunks
    w.start({"test": "crash"})
    # a smooth image, ~9 kB as JPEG: a 256 KiB chunk takes > 1 s to fill, so what bounds
    # the loss is the flush timer, not the chunk size
    y, x = np.mgrid[0:220, 0:360]
    base = np.dstack([(x * 0.7) % 256, (y * 1.1) % 256, ((x + y) * 0.3) % 256]).astype(np.uint8)
    base += np.random.default_rng(1).integers(0, 6, base.shape, dtype=np.uint8)
    print("started", flush=True)
    t_next = time.monotonic()
    for i in range(25 * 20):  # killed long before: 20 s at most
        t_us = time.monotonic_ns() // 1000
        w.log_frame(0, t_us, np.roll(base, 3 * i, axis=1))
        w.log_mavlink("in", t_us, i.to_bytes(4, "little") * 8)
        # One write per line: with PYTHONUNBUFFERED print() writes each piece on its own,
        # and the kill could land between "t_us" and "i".
        sys.stdout.write(f"{t_us} {i}\\n")
        sys.stdout.flush()
        t_next += 0.04
        time.sleep(max(0.0, t_next - time.monotonic()))
    """
)


@pytest.mark.slow  # a subprocess
def test_sigkill_loses_at_most_the_flush_interval(tmp_path: Path) -> None:
    script = tmp_path / "crash_writer.py"
    script.write_text(CRASH_WRITER)
    logdir = tmp_path / "log"
    proc = subprocess.Popen(
        [sys.executable, str(script), str(logdir)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert proc.stdout is not None
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout))  # type: ignore[arg-type]
    reader.start()
    try:
        assert wait_for(lambda: len(lines) >= 2, timeout=30), "writer did not start"
        kill_after = random.uniform(1.2, 3.0)
        time.sleep(kill_after)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        reader.join(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    # Whole lines only: the kill may cut the last one short.
    logged = [tuple(map(int, ln.split())) for ln in lines if ln[:1].isdigit() and ln.endswith("\n")]
    last_t, last_i = logged[-1]

    (path,) = log_files(logdir)
    frames = [r.publish_time_ns // 1000 for r in read_log(path, {"/camera0/image"})]
    mav = [int.from_bytes(r.data[:4], "little") for r in read_log(path, {"/mavlink/in"})]
    t_of = dict((i, t) for t, i in logged)
    assert mav == list(range(len(mav))), "recovered MAVLink is not a gap-free prefix"
    assert frames == [t_of[i] for i in range(len(frames))], "frames not a gap-free prefix"
    lost_s = (last_t - max(frames)) / 1e6
    window = LoggingConfig().flush_interval_s + 0.5
    print(
        f"\nSIGKILL after {kill_after:.2f} s: {last_i + 1} frames logged, "
        f"{len(frames)} frames / {len(mav)} MAVLink recovered, lost the last {lost_s:.3f} s"
    )
    assert lost_s <= window, f"lost {lost_s:.2f} s > {window} s (killed after {kill_after:.2f} s)"
    assert (last_t - t_of[mav[-1]]) / 1e6 <= window
    assert read_metadata(path)["test"] == "crash"
    assert seeking_messages(path) <= 0  # no footer: mcap's seeking reader gets nothing


DEFAULT_MCAP_WRITER = textwrap.dedent(
    """
    import os, random, signal, sys
    from mcap.writer import Writer

    w = Writer(open(sys.argv[1], "wb"))  # mcap's defaults: 1 MiB chunks, no flushing
    w.start()
    ch = w.register_channel("/mavlink/in", "mavlink", 0)
    for i in range(int(sys.argv[2])):
        w.add_message(ch, log_time=1 + i, data=random.Random(i).randbytes(20_000), publish_time=i)
    os.kill(os.getpid(), signal.SIGKILL)
    """
)


@pytest.mark.slow  # a subprocess
def test_mcap_defaults_lose_everything_on_sigkill(tmp_path: Path) -> None:
    """Why the writer flushes: with mcap's defaults a killed process leaves nothing for the
    seeking reader and, below one chunk (1 MiB, ~50 s of telemetry), nothing at all."""
    script = tmp_path / "default_writer.py"
    script.write_text(DEFAULT_MCAP_WRITER)
    got = {}
    for n in (40, 150):  # 0.8 MB (under one chunk), 3 MB (two complete chunks)
        path = tmp_path / f"default-{n}.mcap"
        rc = subprocess.run([sys.executable, str(script), str(path), str(n)], check=False)
        assert rc.returncode == -signal.SIGKILL
        got[n] = (seeking_messages(path), sum(1 for _ in read_log(path)))
    assert got[40][0] <= 0 and got[40][1] == 0  # everything lost
    assert got[150][0] <= 0  # the seeking reader: nothing
    assert 100 <= got[150][1] < 150  # the stream reader: the complete chunks only


# ---------------------------------------------------------------------------------------
# Rotation


def check_parts(directory: Path, files: list[Path]) -> None:
    assert log_files(directory) == files
    for k, f in enumerate(files):
        with open(f, "rb") as fh:
            reader = make_reader(fh)
            assert reader.get_summary() is not None  # each part closed properly
            (meta,) = [m for m in reader.iter_metadata() if m.name == "tcm-companion"]
        assert meta.metadata["log_part"] == str(k) and meta.metadata["run"] == "rot"
        assert f.name.endswith(f"-{k:03d}.mcap")


def test_rotation_by_size(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    # JPEG q90 (~21 kB a frame) so that 40 frames make several 0.1 MB parts.
    cfg = LoggingConfig(rotate_size_mb=0.1, chunk_size_bytes=16_384, jpeg_quality=90)
    w = FlightLogWriter(cfg, tmp_path, wall_minus_mono_ns=WALL)
    w.start({"run": "rot"})
    ts = [T0 + 40_000 * i for i in range(40)]
    for i, t in enumerate(ts):
        assert w.log_frame(0, t, sim_frames[i % len(sim_frames)])
        assert w.log_mavlink("in", t, i.to_bytes(2, "little"))
        time.sleep(0.001)
    w.stop()
    s = w.stats
    assert len(s.files) >= 5, s.files
    check_parts(tmp_path, s.files)
    assert all(f.stat().st_size >= 100_000 for f in s.files[:-1])
    assert sum(f.stat().st_size for f in s.files) == s.bytes_written
    frames = [r.publish_time_ns // 1000 for r in read_log(tmp_path, {"/camera0/image"})]
    assert frames == ts  # across the parts, in order, nothing lost
    mav = [r.data for r in read_log(tmp_path, {"/mavlink/in"})]
    assert mav == [i.to_bytes(2, "little") for i in range(40)]


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_rotation_by_time(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    cfg = LoggingConfig(rotate_interval_s=0.25, flush_interval_s=0.05)
    w = FlightLogWriter(cfg, tmp_path, wall_minus_mono_ns=WALL)
    w.start({"run": "rot"})
    ts = []
    end = time.monotonic() + 1.3
    i = 0
    while time.monotonic() < end:
        t = monotonic_us()
        assert w.log_frame(0, t, sim_frames[i % 5]) and w.log_json("/tcm/health", t, {"i": i})
        ts.append(t)
        i += 1
        time.sleep(0.03)
    w.stop()
    files = w.stats.files
    assert 4 <= len(files) <= 7, files
    check_parts(tmp_path, files)
    assert [r.publish_time_ns // 1000 for r in read_log(tmp_path, {"/camera0/image"})] == ts
    assert [decode_json(r)["i"] for r in read_log(tmp_path, {"/tcm/health"})] == list(range(i))
    spans = [[r.publish_time_ns for r in read_log(f)] for f in files]
    for a, b in itertools.pairwise(spans):
        if a and b:
            assert max(a) <= min(b)  # each part is its own stretch of time


# ---------------------------------------------------------------------------------------
# Disk space and write errors


def test_free_space_floor_pauses_frames_only(tmp_path: Path) -> None:
    free = {"bytes": 10_000_000_000}
    w, events = writer_with_events(
        tmp_path, free_bytes=lambda p: free["bytes"], free_check_interval_s=0.01
    )
    img = noise_image(3)
    t = T0

    def burst(n: int) -> None:
        nonlocal t
        for _ in range(n):
            t += 40_000
            assert w.log_frame(0, t, img)
            assert w.log_annotations(0, t, [(1.0, 2.0, 3.0, "moving")])
            assert w.log_mavlink("in", t, b"\xfd" + t.to_bytes(8, "little"))
            assert w.log_json("/tcm/result", t, {"t": t})
        assert wait_for(lambda: w.stats.queue_depth == 0)

    burst(5)
    assert w.state == "recording" and w.log_state_code == 1
    free["bytes"] = 499_000_000
    assert wait_for(lambda: w.state == "frames paused (disk)")
    assert w.log_state_code == 1
    burst(6)
    free["bytes"] = 2_000_000_000
    assert wait_for(lambda: w.state == "recording")
    burst(4)
    w.stop()
    s = w.stats
    assert (s.frames_logged, s.frames_dropped_disk, s.messages_dropped_disk) == (9, 6, 6)
    frames_account(s, 15)
    assert s.messages_logged == 9 + 15 + 15  # annotations 9, MAVLink and JSON all 15
    assert len(list(read_log(tmp_path, {"/mavlink/in"}))) == 15
    assert len(list(read_log(tmp_path, {"/tcm/result"}))) == 15
    assert len(list(read_log(tmp_path, {"/camera0/image"}))) == 9
    assert events == [
        ("warning", "log: disk below 500 MB, frames not logged"),
        ("info", "log: disk above 500 MB, frames logged again"),
    ]


class FailingFile:
    """A real file whose writes fail with ENOSPC while ``broken['on']`` is set."""

    def __init__(self, fh: Any, broken: dict[str, bool]) -> None:
        self._fh, self._broken = fh, broken

    def write(self, data: bytes) -> int:
        if self._broken["on"]:
            raise OSError(errno.ENOSPC, "No space left on device")
        return self._fh.write(data)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


def failing_disk(monkeypatch: pytest.MonkeyPatch) -> dict[str, bool]:
    """Every part the writer opens fails its writes with ENOSPC while ``["on"]`` is set."""
    broken = {"on": False}
    real_open = FlightLogWriter._open_stream
    monkeypatch.setattr(
        FlightLogWriter,
        "_open_stream",
        lambda self, path: FailingFile(real_open(self, path), broken),
    )
    return broken


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_write_error_faults_then_recovers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    broken = failing_disk(monkeypatch)
    w, events = writer_with_events(tmp_path, retry_interval_s=0.1)
    img = noise_image(4)
    calls = 0

    def log_some(n: int) -> None:
        nonlocal calls
        for _ in range(n):
            calls += 1
            t = T0 + 40_000 * calls
            assert w.log_frame(0, t, img)  # queued: never an exception to the caller
            assert w.log_mavlink("out", t, b"m")
            time.sleep(0.01)

    log_some(5)
    broken["on"] = True
    log_some(10)
    assert wait_for(lambda: w.state == "fault")
    assert w.log_state_code == 2 and w.stats.write_errors >= 1
    log_some(5)
    assert w.alive
    time.sleep(0.3)  # a few failed retries
    assert w.state == "fault" and len(events) == 1 and events[0][0] == "error"
    assert "No space left" in events[0][1]
    broken["on"] = False
    assert wait_for(lambda: w.state == "recording")
    log_some(5)
    w.stop()
    s = w.stats
    frames_account(s, calls)
    # ENOSPC: frames lost to the full disk count as dropped (disk), not (error), since
    # issue 24 §2 (this asserted frames_dropped_error > 0 before)
    assert s.frames_dropped_disk > 0 and s.frames_dropped_error == 0 and s.write_errors >= 2
    assert len(s.files) >= 2
    assert [sev for sev, _ in events] == ["error", "info"]
    got = [r.publish_time_ns // 1000 for r in read_log(tmp_path, {"/camera0/image"})]
    assert T0 + 40_000 * calls in got  # logged after the recovery
    assert s.frames_logged >= len(got) >= 5


def test_directory_removed_faults_then_recovers(tmp_path: Path) -> None:
    logdir = tmp_path / "logs"
    w, events = writer_with_events(logdir, free_check_interval_s=0.02, retry_interval_s=0.1)
    img = noise_image(5)
    t = T0

    def log_some(n: int) -> None:
        nonlocal t
        for _ in range(n):
            t += 40_000
            w.log_frame(0, t, img)
            w.log_json("/tcm/event", t, {"t": t})
            time.sleep(0.01)

    log_some(3)
    shutil.rmtree(logdir)  # the log directory goes away, a file takes its place
    logdir.write_text("not a directory")
    assert wait_for(lambda: w.state == "fault")
    log_some(3)
    time.sleep(0.3)
    assert w.state == "fault" and w.alive
    logdir.unlink()  # the directory can be created again
    assert wait_for(lambda: w.state == "recording")
    log_some(3)
    w.stop()
    assert [sev for sev, _ in events] == ["error", "info"]
    s = w.stats
    assert s.write_errors >= 2
    frames_account(s, 9)
    got = [r.publish_time_ns // 1000 for r in read_log(logdir, {"/camera0/image"})]
    assert got and got[-1] == t


# ---------------------------------------------------------------------------------------
# Every frame of a run in each format (size and CPU are measured by `tcm-companion bench
# --daemon`, flight log writer lines, not by the unit tests)


def test_every_frame_is_logged_in_each_format(tmp_path: Path, sim_frames: list[np.ndarray]) -> None:
    for fmt in ("jpeg", "png"):
        w = FlightLogWriter(
            LoggingConfig(image_format=fmt, queue_items=1024),
            tmp_path / fmt,
            wall_minus_mono_ns=WALL,
        )
        w.start({})
        for i, img in enumerate(sim_frames):
            t = T0 + 40_000 * i
            w.log_frame(0, t, img)
            w.log_annotations(0, t, [(100.0, 50.0, 6.0, "moving ttc 3.0 s")])
            w.log_json("/tcm/result", t, {"track": 1, "state": "moving", "ttc_s": 3.0})
        w.stop(timeout_s=30)
        s = w.stats
        assert s.frames_logged == len(sim_frames)
        counts = Counter(r.topic for r in read_log(tmp_path / fmt))
        assert counts["/camera0/image"] == len(sim_frames)


def test_a_deterministic_writer_sleeps_while_its_queue_is_empty(tmp_path: Path) -> None:
    """The deterministic writer (``sitl --clock virtual``) flushes by the records' time, so
    its thread has no flush deadline of its own to wake for: once one interval had passed
    it polled the empty queue with a zero timeout, holding the GIL, and a 60 s virtual SITL
    ran 4-15x slower with ``--log`` than without. CPU time of an idle thread does not
    depend on the machine's load, so the bound is safe on a busy machine."""
    w, _ = writer_with_events(tmp_path, deterministic=True)
    try:
        w.log_json(topics.HEALTH, 1_000_000, {"ok": True})
        assert w.wait_drained(timeout_s=10.0)
        time.sleep(0.6)  # twelve flush intervals with nothing to write
    finally:
        w.stop()
    assert w.stats.writer_cpu_s < 0.2, w.stats.writer_cpu_s


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_a_live_writer_is_woken_by_frames_not_by_every_item(tmp_path: Path) -> None:
    """Live, the writer thread wakes for a frame (25 Hz), a half-full queue, its own
    timers or stop, and writes what came in meanwhile with it: a wake-up per MAVLink
    datagram or result cost the loop a futex call and a GIL hand-over each (issue 15,
    docs/decisions.md §8.3). Before, every item woke it."""
    w = FlightLogWriter(
        LoggingConfig(flush_interval_s=5.0, queue_items=64),
        tmp_path,
        wall_minus_mono_ns=WALL,
        free_check_interval_s=5.0,
    )
    w.start({})
    try:
        time.sleep(0.1)  # past the first free-space check
        for i in range(10):
            assert w.log_mavlink("in", T0 + i, b"\xfd" + bytes(20))
        time.sleep(0.3)
        assert w.stats.messages_logged == 0 and w.stats.queue_depth == 10  # not woken
        assert w.log_frame(0, T0 + 20, np.zeros((4, 6, 3), np.uint8))  # a frame wakes it
        assert wait_for(lambda: w.stats.frames_logged == 1)
        assert w.stats.messages_logged == 10  # the items before it went with it
        for i in range(31):
            assert w.log_json(topics.HEALTH, T0 + 100 + i, {"i": i})
        time.sleep(0.3)
        assert w.stats.messages_logged == 10  # 31 of 64 queued: still asleep
        assert w.log_json(topics.HEALTH, T0 + 200, {"i": 31})  # the 32nd: half full
        assert wait_for(lambda: w.stats.messages_logged == 42)
    finally:
        w.stop()
    s = w.stats
    assert (s.messages_logged, s.frames_logged, s.messages_dropped_queue) == (42, 1, 0)


def test_a_full_disk_is_counted_as_dropped_disk_and_leaves_no_empty_parts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 24 §2: ENOSPC during a write. What the writer had counted as logged but not
    yet written out (the open chunk) is lost with the failed write: it is counted as
    dropped (disk), so that ``frames_logged`` is what the file holds; while the disk is
    full, frames are dropped (disk), not (error); the retries leave no empty parts behind
    (each used to leave one, ``-001``, ``-002`` ...); once there is room again the log
    goes on in a new part."""
    broken = failing_disk(monkeypatch)
    free = {"bytes": 10**12}
    w, events = writer_with_events(
        tmp_path, retry_interval_s=0.05, free_bytes=lambda p: free["bytes"]
    )
    img = noise_image(6)
    calls = 0

    def log_some(n: int) -> None:
        nonlocal calls
        for _ in range(n):
            calls += 1
            t = T0 + 40_000 * calls
            assert w.log_frame(0, t, img)
            assert w.log_json("/tcm/result", t, {"t": t})
        assert wait_for(lambda: w.stats.queue_depth == 0)

    log_some(3)
    assert wait_for(lambda: w.stats.bytes_written > 0)
    time.sleep(0.1)  # flushed: those three are in the file
    broken["on"] = True
    log_some(4)  # into the open chunk, then the flush fails
    assert wait_for(lambda: w.state == "fault")
    log_some(3)  # while the disk is full
    time.sleep(0.4)  # several failed retries
    assert w.state == "fault"
    broken["on"] = False
    assert wait_for(lambda: w.state == "recording")
    log_some(2)
    w.stop()
    s = w.stats
    frames_account(s, calls)
    got = [r.publish_time_ns // 1000 for r in read_log(tmp_path, {"/camera0/image"})]
    assert s.frames_logged == len(got) == 5, (s, got)  # 3 before, 2 after
    assert s.frames_dropped_disk == 7 and s.frames_dropped_error == 0
    assert s.messages_logged == 5 and s.messages_dropped_disk == 7
    assert s.write_errors >= 2  # the failed write and at least one failed retry
    on_disk = sorted(p.name for p in tmp_path.glob("*.mcap"))
    assert on_disk == sorted(p.name for p in s.files) and len(on_disk) == 2, on_disk
    assert all(read_metadata(p) for p in tmp_path.glob("*.mcap"))  # no empty part
    assert [sev for sev, _ in events] == ["error", "info"]


def test_a_write_that_fails_inside_a_chunk_counts_every_item(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The disk fills while mcap writes a chunk it ended itself (inside ``add_message``):
    the item being written and those pending in the chunk are each counted once, as
    dropped (disk). (An item was left uncounted, and a deterministic run, which waits for
    the counts to add up, hung in ``wait_drained``.)"""
    broken = failing_disk(monkeypatch)
    w = FlightLogWriter(
        LoggingConfig(chunk_size_bytes=1024, flush_interval_s=60.0),
        tmp_path,
        wall_minus_mono_ns=WALL,
        deterministic=True,
        retry_interval_s=60.0,
    )
    w.start({})
    tiny = np.zeros((4, 4, 3), np.uint8)
    for k in range(2):  # small: they stay in the open chunk
        assert w.log_frame(0, T0 + k, tiny)
        assert w.log_json("/tcm/result", T0 + k, {"k": k})
    assert w.wait_drained(10.0)
    broken["on"] = True
    assert w.log_frame(0, T0 + 10, noise_image(7))  # ends the chunk: the write fails
    assert w.wait_drained(10.0)  # it did not: an item was never counted
    w.stop()
    s = w.stats
    frames_account(s, 3)
    frames = sum(1 for _ in read_log(tmp_path, {"/camera0/image"}))
    messages = sum(1 for _ in read_log(tmp_path, {"/tcm/result"}))
    assert (s.frames_logged, s.messages_logged) == (frames, messages), s  # what the file holds
    assert s.frames_dropped_disk == 3 - frames >= 2 and s.frames_dropped_error == 0, s
    assert s.messages_dropped_disk == 2 - messages, s
    assert s.state == "off" and s.write_errors >= 1
