"""Flight log tools: log <-> scenario conversion, analysis plots, the Foxglove layout.

One module-scoped flight log is written with the real :class:`FlightLogWriter` the way
the daemon writes it (frames, annotations, MAVLink as received, ``/tcm/result`` per frame,
``/tcm/health`` once a second, events and parameters) from 3 s of the simulated T90
flight, with a wall-minus-monotonic offset, then converted and plotted.
"""

from __future__ import annotations

import json
import re
import struct
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from tcm_companion.config import AppConfig
from tcm_companion.flightlog import reader
from tcm_companion.flightlog.docs import annotation_circles
from tcm_companion.flightlog.settings import LoggingConfig
from tcm_companion.flightlog.writer import FlightLogWriter
from tcm_companion.io.scenario import load_scenario
from tcm_companion.io.tlog import read_tlog
from tcm_companion.logtools import (
    LogConversionError,
    log_to_scenario,
    plot_log,
    plot_scenario,
    scenario_to_log,
)
from tcm_companion.logtools.convert import replay_result_doc, split_mavlink
from tcm_companion.logtools.plot import PLOT_NAMES
from tcm_companion.mavlink import tcm_dialect
from tcm_companion.replay.scenario import run_replay
from tcm_companion.sim import make_scenario
from tcm_companion.sim.scene.export import export_scenario

LAYOUT = Path(__file__).resolve().parents[1] / "tools" / "foxglove" / "tcm_layout.json"
OFFSET_NS = 1_700_000_123_456_000  # wall minus monotonic of the test "daemon"
OFFSET_US = OFFSET_NS // 1000
# The sim's clock is used as the companion's monotonic clock: shift it to ~0.
MONO_SHIFT_US = 1_718_000_000_000_000
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@dataclass
class Flight:
    sim: Any
    frames: list[tuple[int, int, np.ndarray]]  # (index, t_us on the sim's clock, image)
    log_dir: Path
    log_file: Path
    tmp: Path


def _companion_heartbeat() -> bytes:
    mav = tcm_dialect.MAVLink(None, srcSystem=1, srcComponent=191)
    msg = mav.heartbeat_encode(
        tcm_dialect.MAV_TYPE_ONBOARD_CONTROLLER, tcm_dialect.MAV_AUTOPILOT_INVALID, 0, 0, 4
    )
    return bytes(msg.pack(mav))


def _writer(directory: Path, **cfg: Any) -> FlightLogWriter:
    config = LoggingConfig(queue_items=100_000, min_free_mb=0.0, **cfg)
    return FlightLogWriter(config, directory, wall_minus_mono_ns=OFFSET_NS)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    tmp = tmp_path_factory.mktemp("logtools")
    sim = make_scenario("T90", duration_s=3)
    frames = list(sim.iter_frames())
    cached = SimpleNamespace(
        name=sim.name,
        camera=sim.camera,
        frame_times_us=sim.frame_times_us,
        telemetry=sim.telemetry,
        n_frames=sim.n_frames,
        iter_frames=lambda: iter(frames),
    )
    results = list(run_replay(cached, AppConfig()))
    threshold = AppConfig().pipeline.classifier.tcm_threshold

    log_dir = tmp / "log"
    w = _writer(log_dir, image_format="png")
    w.start({"camera0": json.dumps(sim.camera.to_dict()), "cameras": '["sim"]'})
    mono = lambda t: int(t) - MONO_SHIFT_US  # noqa: E731
    tlog = sim.tlog_records
    j = 0
    heartbeat = _companion_heartbeat()
    for (i, t_us, image), res in zip(frames, results):
        while j < len(tlog) and tlog[j][0] <= t_us:  # one datagram per message
            assert w.log_mavlink("in", mono(tlog[j][0]), tlog[j][1])
            j += 1
        assert w.log_frame(0, mono(t_us), image)
        doc = replay_result_doc(res, threshold)
        doc["t_capture_us"] = mono(t_us)
        doc["latency_ms"] = 6.0 + 0.1 * (i % 30)
        t_done = mono(t_us) + 7000
        assert w.log_json("/tcm/result", t_done, doc)
        assert w.log_annotations(0, mono(t_us), annotation_circles(res, sim.camera))
        assert w.log_mavlink("out", t_done, heartbeat)
        if i % 25 == 0:
            health = {"frame_rate_hz": 25.0, "latency_ms": 7.1, "frames_dropped": 0}
            assert w.log_json("/tcm/health", t_done, {**health, "inputs": {"camera0": ""}})
        if i == 10:
            assert w.log_json("/tcm/event", t_done, {"severity": "info", "text": "camera0 OK"})
            assert w.log_json("/tcm/param", t_done, {"name": "TCM_THRESH", "value": threshold})
    for t, frame in tlog[j:]:
        assert w.log_mavlink("in", mono(t), frame)
    w.stop(timeout_s=30.0)
    st = w.stats
    assert st.frames_logged == len(frames) and st.write_errors == 0
    (log_file,) = reader.log_files(log_dir)
    return Flight(sim=sim, frames=frames, log_dir=log_dir, log_file=log_file, tmp=tmp)


@pytest.fixture(scope="module")
def exported(flight: Flight) -> Path:
    out = flight.tmp / "exported"
    summary = log_to_scenario(flight.log_dir, out)
    assert summary.frames == len(flight.frames)
    assert summary.telemetry_records == len(flight.sim.tlog_records)
    assert summary.frames_skipped == 0 and summary.mavlink_bad == 0 and not summary.warnings
    return out


# --------------------------------------------------------------------------------------
# log -> scenario
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over a second of CPU
def test_log_to_scenario_keeps_frames_times_and_telemetry(flight: Flight, exported: Path) -> None:
    sc = load_scenario(exported)
    sim = flight.sim
    shift = OFFSET_US - MONO_SHIFT_US  # sim clock -> monotonic -> wall clock
    assert sc.n_frames == sim.n_frames
    assert sc.camera.to_dict() == sim.camera.to_dict()
    # Frame capture times and telemetry receive times: the same wall clock, spacing kept.
    np.testing.assert_array_equal(sc.frame_times_us, sim.frame_times_us + shift)
    assert [s.recv_us for s in sc.telemetry] == [s.recv_us + shift for s in sim.telemetry]
    assert len(sc.attitude_samples()) == len(sim.attitude_samples()) > 50
    assert len(sc.position_samples()) == len(sim.position_samples()) > 20
    assert not sc.warnings
    # PNG frames are lossless.
    for i in (0, sim.n_frames - 1):
        np.testing.assert_array_equal(sc.read_frame(i), flight.frames[i][2])
    # The .tlog is the sim's, byte for byte, with receive times on the wall clock; the
    # companion's own /mavlink/out is not in it.
    expected = b"".join(struct.pack(">Q", t + shift) + f for t, f in sim.tlog_records)
    assert (exported / "telemetry.tlog").read_bytes() == expected
    records, stats = read_tlog(exported / "telemetry.tlog")
    assert stats.decoded == len(sim.tlog_records) and not stats.skipped
    assert {r.msg.get_type() for r in records} >= {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED"}
    assert all(r.msg.get_srcComponent() == 1 for r in records)
    # frames.csv: header, 0-based index, strictly increasing times
    lines = (exported / "frames.csv").read_text().splitlines()
    assert lines[0] == "frame,t_us" and lines[1] == f"0,{sim.frame_times_us[0] + shift}"


@pytest.mark.slow  # over a second of CPU
def test_exported_scenario_replays_like_the_flight(flight: Flight, exported: Path) -> None:
    sc = load_scenario(exported)
    frames = flight.frames[:40]
    cached = SimpleNamespace(
        name="sim",
        camera=flight.sim.camera,
        frame_times_us=flight.sim.frame_times_us[:40],
        telemetry=flight.sim.telemetry,
        n_frames=40,
        iter_frames=lambda: iter(frames),
    )
    sc.frame_times_us = sc.frame_times_us[:40]
    live = list(run_replay(cached, AppConfig()))
    again = list(run_replay(sc, AppConfig()))
    assert [[o.state for o in r.objects] for r in again] == [
        [o.state for o in r.objects] for r in live
    ]
    d_live = [o.disparity for r in live for o in r.objects]
    d_again = [o.disparity for r in again for o in r.objects]
    np.testing.assert_allclose(d_again, d_live, rtol=1e-6, atol=1e-9)
    assert any(o.state == "moving" for r in again for o in r.objects)


def test_mavlink_chunks_split_mid_frame_are_rebuilt() -> None:
    """The link logs every chunk it read: frames split across chunks (serial) are
    rebuilt, stamped with the chunk that completed them; garbage is dropped."""
    frames = [f for _, f in make_scenario("T90", duration_s=1).tlog_records[:40]]
    garbage = b"\x00\x13garbage"
    stream = b"".join(frames[:3]) + garbage + b"".join(frames[3:])
    frame_ends = np.cumsum([len(f) for f in frames]) + np.where(np.arange(40) >= 3, len(garbage), 0)
    chunks, chunk_ends = [], []
    pos, t = 0, 1000
    sizes = iter([7, 1, 50, 13, 200, 3] * 1000)
    while pos < len(stream):
        size = next(sizes)
        chunks.append((t, stream[pos : pos + size]))
        pos += size
        chunk_ends.append((pos, t))
        t += 10
    bad: list[int] = []
    out = list(split_mavlink(iter(chunks), on_bad=bad.append))
    assert [f for _, f in out] == frames
    assert sum(bad) == len(garbage)
    for (t_out, _), end in zip(out, frame_ends):  # stamped by the chunk with the last byte
        assert t_out == next(tc for p, tc in chunk_ends if p >= end)


def test_log_to_scenario_errors_name_the_log(flight: Flight, tmp_path: Path) -> None:
    with pytest.raises(LogConversionError, match=re.escape(str(tmp_path / "nope.mcap"))):
        log_to_scenario(tmp_path / "nope.mcap", tmp_path / "s0")
    (tmp_path / "empty").mkdir()
    with pytest.raises(LogConversionError, match="holds no flight log"):
        log_to_scenario(tmp_path / "empty", tmp_path / "s1")
    with pytest.raises(LogConversionError, match=r"metadata has no 'camera1'.*camera0"):
        log_to_scenario(flight.log_file, tmp_path / "s2", camera_id=1)

    def first(msgid: int) -> bytes:  # a MAVLink 2 frame of the sim's telemetry by id
        return next(f for _, f in flight.sim.tlog_records if f[7:10] == bytes([msgid, 0, 0]))

    hb, att = first(0), first(30)  # HEARTBEAT, ATTITUDE
    image = flight.frames[0][2]
    cam = json.dumps(flight.sim.camera.to_dict())

    def small_log(name: str, meta: dict[str, str], *, frame: bool, mav: list[bytes]) -> Path:
        w = _writer(tmp_path / name)
        w.start(meta)
        for k, data in enumerate(mav):
            w.log_mavlink("in", 1000 + k, data)
        if frame:
            w.log_frame(0, 2000, image)
        w.stop()
        return reader.log_files(tmp_path / name)[0]

    no_meta = small_log("a", {}, frame=True, mav=[hb, att])
    with pytest.raises(LogConversionError, match=rf"{re.escape(str(no_meta))}: metadata has no"):
        log_to_scenario(no_meta, tmp_path / "s3")
    no_images = small_log("b", {"camera0": cam}, frame=False, mav=[hb, att])
    with pytest.raises(
        LogConversionError, match=rf"{re.escape(str(no_images))}: no messages on /camera0/image"
    ):
        log_to_scenario(no_images, tmp_path / "s4")
    no_mav = small_log("c", {"camera0": cam}, frame=True, mav=[])
    with pytest.raises(LogConversionError, match="no messages on /mavlink/in"):
        log_to_scenario(no_mav, tmp_path / "s5")
    no_att = small_log("d", {"camera0": cam}, frame=True, mav=[hb])
    with pytest.raises(LogConversionError, match="no ATTITUDE"):
        log_to_scenario(no_att, tmp_path / "s6")
    w = _writer(tmp_path / "f")
    w.start({"camera0": cam})
    w.log_mavlink("in", 1000, att)
    w.log_frame(0, 2000, image[:100])
    w.stop()
    with pytest.raises(LogConversionError, match=r"is 360x100 but metadata camera0 says 360x220"):
        log_to_scenario(tmp_path / "f", tmp_path / "s7")


# --------------------------------------------------------------------------------------
# scenario -> log
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over half a second of CPU
def test_scenario_to_log_and_back(flight: Flight, exported: Path, tmp_path: Path) -> None:
    log_path = tmp_path / "sub" / "imported.mcap"
    summary = scenario_to_log(exported, log_path, results=True)
    assert summary.frames == flight.sim.n_frames == summary.results
    assert summary.mavlink_records == len(flight.sim.tlog_records)
    assert log_path.is_file() and sorted(p.name for p in log_path.parent.iterdir()) == [
        "imported.mcap"
    ]
    counts: dict[str, int] = {}
    for rec in reader.read_log(log_path):
        counts[rec.topic] = counts.get(rec.topic, 0) + 1
        assert rec.log_time_ns == rec.publish_time_ns  # logged on the scenario's clock
    n = flight.sim.n_frames
    assert counts == {
        "/camera0/image": n,
        "/camera0/annotations": n,
        "/tcm/result": n,
        "/mavlink/in": len(flight.sim.tlog_records),
    }
    meta = reader.read_metadata(log_path)
    assert json.loads(meta["camera0"]) == flight.sim.camera.to_dict()
    first = next(reader.read_log(log_path, topics={"/tcm/result"}))
    doc = reader.decode_json(first)
    assert doc["t_capture_us"] == load_scenario(exported).frame_times_us[0]

    # ... and back: the same scenario, times and telemetry bytes unchanged.
    back = tmp_path / "back"
    log_to_scenario(log_path, back)
    assert (back / "frames.csv").read_text() == (exported / "frames.csv").read_text()
    assert (back / "telemetry.tlog").read_bytes() == (exported / "telemetry.tlog").read_bytes()
    sc = load_scenario(back)
    np.testing.assert_array_equal(sc.read_frame(5), flight.frames[5][2])


@pytest.mark.slow  # over a second of CPU
def test_a_log_imported_with_results_replays_to_its_results(exported: Path, tmp_path: Path) -> None:
    """Issue 24 §4: a log written by ``import --results`` failed ``replay --check`` (150
    frames differ, 2.3e-04). Its results were computed with the telemetry received up to
    ``attitude_wait_max_us`` after each frame, which the log held after the frame's
    result, so replay processed each frame with less telemetry; and neither the clock
    offset nor the configuration was recorded. Now process replay reproduces them, also
    for a configuration other than the defaults, and they are the scenario's replay."""
    from dataclasses import replace

    from tcm_companion.replay.log import compare, replay_log

    base = AppConfig()
    other = replace(
        base,
        pipeline=replace(
            base.pipeline, classifier=replace(base.pipeline.classifier, tcm_threshold=0.05)
        ),
    )
    scenario = load_scenario(exported)
    for name, config in (("default", None), ("other", other)):
        log_path = tmp_path / f"{name}.mcap"
        scenario_to_log(exported, log_path, results=True, config=config)
        frames = list(replay_log(log_path))
        assert len(frames) == scenario.n_frames
        assert [d for f in frames for d in compare(f)] == [], name
        assert any(o["disparity"] is not None for f in frames for o in f.logged["objects"])
        # ... and the logged results are those of the scenario's replay
        want = list(run_replay(scenario, config or base))
        assert [[o.state for o in r.objects] for r in want] == [
            [o["state"] for o in f.logged["objects"]] for f in frames
        ]
    meta = reader.read_metadata(tmp_path / "other.mcap")
    assert "tcm_threshold = 0.05" in meta["config"]
    assert json.loads(meta["params"])["TCM_THRESH"] == 0.05


def test_scenario_to_log_refuses_bad_input(exported: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="image_format"):
        scenario_to_log(exported, tmp_path / "x.mcap", image_format="bmp")
    with pytest.raises(ValueError, match=re.escape(str(tmp_path / "missing"))):
        scenario_to_log(tmp_path / "missing", tmp_path / "y.mcap")
    with pytest.raises(LogConversionError, match="is a directory"):
        scenario_to_log(exported, tmp_path)


# --------------------------------------------------------------------------------------
# plots
# --------------------------------------------------------------------------------------
def _check_pngs(paths: list[Path], names: set[str]) -> None:
    assert {p.stem for p in paths} == names
    for p in paths:
        data = p.read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000, p


@pytest.mark.slow  # over a second of CPU
def test_plot_log_draws_every_plot(flight: Flight, tmp_path: Path) -> None:
    from tcm_companion.logtools.plot import build_figures, load_log_data

    from .plot_checks import assert_legends_clear

    files = plot_log(flight.log_dir, tmp_path / "plots")  # the rotated-directory form
    _check_pngs(files, set(PLOT_NAMES))
    assert files.skipped == {}
    assert plot_log(flight.log_file, tmp_path / "again") == [
        tmp_path / "again" / p.name for p in files
    ]
    figures, _ = build_figures(load_log_data(flight.log_dir))
    assert sum(assert_legends_clear(fig) for fig in figures.values()) == 5


def test_plot_log_health_latency_blank_before_the_first_result(
    flight: Flight, tmp_path: Path
) -> None:
    """The daemon reports latency 0 ms until it has processed a frame: not plotted."""
    from tcm_companion.logtools.plot import build_figures, load_log_data

    w = _writer(tmp_path / "log")
    w.start({"camera0": json.dumps(flight.sim.camera.to_dict())})
    for k in range(4):  # health at 1, 2, 3, 4 s; the first frame captured at 2.5 s
        t_us = (k + 1) * 1_000_000
        health = {"frame_rate_hz": 0.0 if k < 2 else 25.0, "latency_ms": 0.0 if k < 2 else 6.5}
        w.log_json("/tcm/health", t_us, {**health, "frames_dropped": 0})
        if k == 1:
            doc = {"camera_id": 0, "t_capture_us": 2_500_000, "objects": [], "latency_ms": 6.5}
            w.log_json("/tcm/result", 2_506_500, doc)
    w.stop()
    data = load_log_data(tmp_path / "log")
    assert data.first_result_us == 2_506_500
    fig = build_figures(data)[0]["health"]
    (ax,) = [a for a in fig.axes if a.get_ylabel().startswith("latency")]
    latency = np.asarray(ax.get_lines()[0].get_ydata(), dtype=np.float64)
    assert np.isnan(latency[:2]).all()
    np.testing.assert_array_equal(latency[2:], 6.5)


@pytest.mark.slow  # over a second of CPU
def test_plot_scenario_with_truth(flight: Flight, tmp_path: Path) -> None:
    from tcm_companion.logtools.plot import load_scenario_data

    sim = make_scenario("T90", duration_s=2)
    scen = export_scenario(sim, tmp_path / "scen")
    data = load_scenario_data(scen)
    assert len(data.results) == sim.n_frames and data.latency_is_processing_time
    assert [t.object_id for t in data.truth] == [1] and data.truth[0].moving.all()
    files = plot_scenario(scen, tmp_path / "plots")
    _check_pngs(files, set(PLOT_NAMES) - {"health"})
    assert set(files.skipped) == {"health"}


def test_plots_without_data_are_skipped_not_drawn(flight: Flight, tmp_path: Path) -> None:
    w = _writer(tmp_path / "log")
    w.start({"camera0": json.dumps(flight.sim.camera.to_dict())})
    for t, frame in flight.sim.tlog_records[:200]:
        w.log_mavlink("in", t - MONO_SHIFT_US, frame)
    # one result with an unknown object: no disparity, TTC or egomotion to draw
    w.log_json(
        "/tcm/result",
        flight.sim.tlog_records[100][0] - MONO_SHIFT_US,
        {
            "camera_id": 0,
            "t_capture_us": flight.sim.tlog_records[100][0] - MONO_SHIFT_US,
            "threshold": 0.09,
            "objects": [{"track_id": 1, "state": "unknown", "disparity": None, "ttc_s": None}],
            "egomotion": None,
            "timings_ms": {},
            "latency_ms": None,
        },
    )
    w.stop()
    files = plot_log(tmp_path / "log", tmp_path / "plots")
    _check_pngs(files, {"attitude"})
    assert set(files.skipped) == set(PLOT_NAMES) - {"attitude"}
    assert all(files.skipped.values())
    assert not (tmp_path / "plots" / "disparity.png").exists()


def test_plot_log_draws_only_the_followed_autopilots_attitude(
    flight: Flight, tmp_path: Path
) -> None:
    """Issue 24 §3: `plot LOG` drew ATTITUDE from any system as the vehicle's (a second
    system's -172° pitch). Now only what the companion used: the first autopilot
    heartbeat's system, one sender under its id."""
    from tcm_companion.logtools.plot import build_figures, load_log_data

    hb = tcm_dialect.MAVLink_heartbeat_message(
        tcm_dialect.MAV_TYPE_QUADROTOR, tcm_dialect.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4, 3
    )
    other = tcm_dialect.MAVLink(None, srcSystem=2, srcComponent=1)  # another vehicle
    spoof = tcm_dialect.MAVLink(None, srcSystem=1, srcComponent=1)  # a second sender as 1/1
    spoof.seq = 90
    parsed = tcm_dialect.MAVLink(None)
    kinds = [
        (m.get_type(), m.get_srcSystem())
        for _, f in flight.sim.tlog_records
        for m in parsed.parse_buffer(f) or []
    ]
    first_hb = kinds.index(("HEARTBEAT", 1))  # the companion follows 1/1 from here
    real = sum(1 for kind, _ in kinds[first_hb:] if kind == "ATTITUDE")
    w = _writer(tmp_path / "log")
    w.start({"camera0": json.dumps(flight.sim.camera.to_dict())})
    for k, (t, frame) in enumerate(flight.sim.tlog_records):
        t -= MONO_SHIFT_US
        w.log_mavlink("in", t, frame)
        if k > first_hb and k % 4 == 0:
            for mav, pitch, boot in ((other, -3.0, 777_000), (spoof, 1.4, 999_000 + k)):
                for msg in ([hb] if k % 40 == 0 else []) + [
                    tcm_dialect.MAVLink_attitude_message(boot, 0.0, pitch, 0.0, 0, 0, 0)
                ]:
                    w.log_mavlink("in", t + 100, bytes(msg.pack(mav)))
                    mav.seq = (mav.seq + 1) % 256
    w.stop()
    data = load_log_data(tmp_path / "log")
    pitch = np.degrees([a[2] for a in data.attitude])
    assert np.all(np.abs(pitch) < 30.0), pitch.min()  # neither -172° nor the spoofer's 80°
    assert len(pitch) == real, (len(pitch), real)
    assert data.autopilot == "1/1"
    fig = build_figures(data)[0]["attitude"]
    assert "Autopilot 1/1 attitude" in fig.axes[0].get_title()


# --------------------------------------------------------------------------------------
# Foxglove layout
# --------------------------------------------------------------------------------------
def _leaves(node: Any) -> list[str]:
    if isinstance(node, str):
        return [node]
    if "tabs" in node:
        return [leaf for tab in node["tabs"] for leaf in _leaves(tab["layout"])]
    return _leaves(node["first"]) + _leaves(node["second"])


def _resolve(doc: Any, path: str) -> list[Any]:
    """Values of a Foxglove message path like ``objects[:].disparity`` in a document."""
    values = [doc]
    for part in path.split("."):
        m = re.fullmatch(r"(\w+)(\[:\])?", part)
        assert m, part
        values = [v[m.group(1)] for v in values if isinstance(v, dict) and m.group(1) in v]
        if m.group(2):
            values = [x for v in values for x in v]
    return values


def test_foxglove_layout_references_what_the_daemon_logs(flight: Flight) -> None:
    layout = json.loads(LAYOUT.read_text(encoding="utf-8"))
    panels = layout["configById"]
    assert set(_leaves(layout["layout"])) == set(panels)
    assert {pid.split("!")[0] for pid in panels} >= {"Image", "Plot", "RawMessages"}

    docs: dict[str, list[dict[str, Any]]] = {}
    topics = set()
    for rec in reader.read_log(flight.log_file):
        topics.add(rec.topic)
        if rec.message_encoding == "json":
            docs.setdefault(rec.topic, []).append(reader.decode_json(rec))

    image = next(c for pid, c in panels.items() if pid.startswith("Image!"))["imageMode"]
    assert image["imageTopic"] == "/camera0/image"
    assert image["annotations"] == {"/camera0/annotations": {"visible": True}}
    referenced = {image["imageTopic"], *image["annotations"]}
    plotted = []
    for pid, cfg in panels.items():
        if pid.startswith("Plot!"):
            for p in cfg["paths"]:
                assert p["enabled"] is True
                topic, _, field = p["value"].partition(".")
                referenced.add(topic)
                plotted.append((topic, field))
        elif pid.startswith("RawMessages!"):
            referenced.add(cfg["topicPath"])
    assert referenced <= topics
    values = {f"{t}.{f}" for t, f in plotted}
    assert {
        "/tcm/result.objects[:].disparity",
        "/tcm/result.threshold",
        "/tcm/result.objects[:].ttc_s",
    } <= values
    assert "/tcm/health" in referenced
    for topic, fieldpath in plotted:  # every plotted field exists in the logged documents
        found = [v for d in docs[topic] for v in _resolve(d, fieldpath)]
        assert any(isinstance(v, int | float) for v in found), (topic, fieldpath)
