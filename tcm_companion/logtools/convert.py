"""Convert between MCAP flight logs and ``tcm-scenario/1`` directories.

:func:`log_to_scenario` turns a flight log (one ``.mcap`` or a directory of rotated
ones) into a scenario that ``tcm-companion replay`` and ``eval`` read: the frames of
one camera as PNG files with their capture times, the MAVLink the companion received
as a MAVProxy ``.tlog``, and the camera model from the log's metadata.
:func:`scenario_to_log` goes the other way, writing a scenario as a flight log with the
topics the daemon writes (optionally with replayed results, so the log opens in the
Foxglove layout of ``tools/foxglove``).

Time bases. The log stamps every message twice: ``publish_time`` is the companion's
monotonic clock (``t_us * 1000`` of the call that logged it) and ``log_time`` is the
wall clock. A scenario wants one clock for frames and telemetry, microseconds since the
Unix epoch (scenario format: ``frames.csv`` ``t_us`` "on the same clock as the
telemetry timestamps"; ``.tlog`` records carry the receive time, Unix epoch). So frame
capture times and MAVLink receive times are both taken from ``publish_time`` (the exact
values the daemon used) and shifted by one constant wall-minus-monotonic offset: the
median of ``log_time - publish_time`` over the converted records. Capture times and
receive times therefore keep exactly the spacing they had live, and land on the wall
clock. Going back, :func:`scenario_to_log` logs with a zero offset, so the scenario's
times come back unchanged.
"""

from __future__ import annotations

import heapq
import json
import logging
import shutil
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..core.camera import CameraModel, CameraModelError, camera_from_dict
from ..flightlog import reader, topics
from ..flightlog.docs import annotation_circles, result_doc
from ..flightlog.settings import LoggingConfig
from ..flightlog.writer import FlightLogWriter
from ..io.scenario import CAMERA_NAME, RigScenario, Scenario, ScenarioError, load_any
from ..io.scenario_writer import RigWriter, ScenarioWriter, rig_scenario_toml, scenario_toml
from ..io.tlog import TlogError, read_tlog

log = logging.getLogger(__name__)

__all__ = [
    "ExportSummary",
    "ImportSummary",
    "LogConversionError",
    "camera_from_metadata",
    "check_log_path",
    "log_to_scenario",
    "parse_mavlink",
    "replay_result_doc",
    "scenario_to_log",
    "split_mavlink",
]

# Message ids the scenario reader needs from the autopilot (common.xml).
_MSGID_ATTITUDE = (30, 31)  # ATTITUDE, ATTITUDE_QUATERNION


class LogConversionError(ValueError):
    """A log or scenario cannot be converted; the message names the file at fault."""


@dataclass
class ExportSummary:
    """What :func:`log_to_scenario` wrote."""

    scenario_dir: Path
    frames: int
    telemetry_records: int
    wall_minus_mono_us: int
    frames_skipped: int = 0  # capture time not after the previous frame's
    mavlink_bad: int = 0  # bytes of /mavlink/in that did not frame or failed the CRC
    warnings: list[str] = field(default_factory=list)
    cameras: list[str] = field(default_factory=list)  # a rig's camera names ([]: one camera)


@dataclass
class ImportSummary:
    """What :func:`scenario_to_log` wrote."""

    log_path: Path
    frames: int
    mavlink_records: int
    results: int = 0


# --------------------------------------------------------------------------------------
# Shared helpers
# --------------------------------------------------------------------------------------
def camera_from_metadata(
    metadata: dict[str, str], camera_id: int, where: str | Path
) -> CameraModel:
    """The camera model a log's metadata holds under ``camera{id}`` (JSON of ``to_dict()``)."""
    key = f"camera{camera_id}"
    text = metadata.get(key)
    if text is None:
        have = ", ".join(sorted(k for k in metadata if k.startswith("camera"))) or "none"
        raise LogConversionError(
            f"{where}: metadata has no {key!r} camera model (camera keys present: {have})"
        )
    try:
        table = json.loads(text)
    except json.JSONDecodeError as exc:
        raise LogConversionError(f"{where}: metadata {key!r} is not JSON: {exc}") from None
    if not isinstance(table, dict):
        raise LogConversionError(f"{where}: metadata {key!r} is not a JSON object")
    try:
        return camera_from_dict(table, where=f"{where}: metadata {key}")
    except CameraModelError as exc:
        raise LogConversionError(str(exc)) from None


def parse_mavlink(
    chunks: Iterator[tuple[int, bytes]],
    on_bad: Callable[[int], None] | None = None,
) -> Iterator[tuple[int, Any]]:
    """Decode ``(t, bytes)`` chunks of a MAVLink byte stream into ``(t, message)``.

    One parser (the project's dialect) runs over the whole stream, so a frame split
    across two chunks (a serial read that ended mid-frame) is rebuilt and stamped with
    the time of the chunk that completed it, i.e. when it was received. Bytes that are
    no frame or fail the CRC are dropped (``on_bad`` gets their count); messages of ids
    the dialect does not know come out as ``MAVLink_unknown`` with their raw frame.
    """
    from ..mavlink import tcm_dialect

    mav = tcm_dialect.MAVLink(None)
    mav.robust_parsing = True
    for t, data in chunks:
        for msg in mav.parse_buffer(data) or ():
            if isinstance(msg, tcm_dialect.MAVLink_bad_data):
                if on_bad is not None:
                    on_bad(len(msg.get_msgbuf()))
                continue
            yield t, msg


def split_mavlink(
    chunks: Iterator[tuple[int, bytes]],
    on_bad: Callable[[int], None] | None = None,
) -> Iterator[tuple[int, bytes]]:
    """Split ``(t, bytes)`` chunks of a MAVLink stream into ``(t, raw frame)``; see
    :func:`parse_mavlink` (frames of unknown message ids are kept as they are)."""
    for t, msg in parse_mavlink(chunks, on_bad):
        yield t, bytes(msg.get_msgbuf())


def check_log_path(log_path: Path, flight: str | None = None) -> dict[str, str]:
    """A log file, or a directory holding rotated parts, with a readable metadata record
    (of the flight ``flight`` picks: :func:`~tcm_companion.flightlog.reader.select_flight`);
    else an error naming it. Returns the metadata."""
    if not log_path.exists():
        raise LogConversionError(f"{log_path}: no such log file or directory")
    if log_path.is_dir() and not reader.log_files(log_path):
        raise LogConversionError(f"{log_path}: directory holds no flight log (tcm-*.mcap)")
    metadata = reader.read_metadata(log_path, flight)
    if not metadata:
        damaged = reader.check_log(log_path, flight).problems()
        why = "; ".join(damaged) if damaged else "not a flight log?"
        raise LogConversionError(f"{log_path}: no tcm-companion metadata record readable: {why}")
    return metadata


def _wall_minus_mono_us(metadata: dict[str, str], offsets_ns: list[int]) -> int:
    """The writer's wall-minus-monotonic offset: from the metadata record when it is
    there (the writer stamps ``log_time = publish_time + offset``), else the median of
    the records' ``log_time - publish_time``."""
    text = metadata.get("wall_minus_mono_ns")
    if text is not None:
        try:
            return round(int(text) / 1000)
        except ValueError:
            pass
    return round(statistics.median(offsets_ns) / 1000) if offsets_ns else 0


def _msgid(frame: bytes) -> int:
    if frame[0] == 0xFD:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    return frame[5]


# --------------------------------------------------------------------------------------
# Log -> scenario
# --------------------------------------------------------------------------------------
def log_to_scenario(
    log_path: str | Path,
    out_dir: str | Path,
    camera_id: int | None = 0,
    *,
    name: str | None = None,
    flight: str | None = None,
) -> ExportSummary:
    """Write the flight log ``log_path`` (file or rotated directory) as a scenario.

    ``out_dir`` gets ``scenario.toml`` (camera model from the log's metadata
    ``camera{camera_id}``), ``frames/NNNNNN.png`` with ``frames.csv`` (capture times) from
    ``/camera{camera_id}/image``, and ``telemetry.tlog`` from ``/mavlink/in`` (each MAVLink
    frame with its receive time). Raises :class:`LogConversionError` naming the log when
    it lacks the camera model, the camera's images or the autopilot's attitude. A
    directory of several flights exports the one ``flight`` picks (else
    :class:`~tcm_companion.flightlog.reader.FlightSelectionError`, listing them).

    ``camera_id`` None: every camera of the log; a log of two cameras or more (a rig)
    becomes a rig scenario (``[[cameras]]`` named as the log's ``cameras`` metadata, each
    camera's frames and ``frames.csv`` in ``cameras/NAME``, one ``telemetry.tlog``).
    """
    log_path = Path(log_path)
    out = Path(out_dir)
    metadata = check_log_path(log_path, flight)
    if out.resolve() == log_path.resolve():
        raise LogConversionError(f"{out}: the scenario directory cannot be the log itself")
    if camera_id is None:
        n = 0
        while f"camera{n}" in metadata:
            n += 1
        ids = list(range(n)) if n else [0]  # none: camera0's error below
    else:
        ids = [camera_id]
    rig = len(ids) >= 2
    cameras = [camera_from_metadata(metadata, k, log_path) for k in ids]
    names = _camera_names(metadata, len(ids)) if rig else [f"camera{ids[0]}"]

    image_topics = [topics.camera_image(k) for k in ids]
    rig_writer = RigWriter(out) if rig else None
    writers = (
        [rig_writer.camera(n) for n in names] if rig_writer is not None else [ScenarioWriter(out)]
    )

    capture_mono_us: list[list[int]] = [[] for _ in ids]
    skipped = [0] * len(ids)
    chunks: list[tuple[int, bytes]] = []
    offsets_ns: list[int] = []
    log_report = reader.LogReport()
    for rec in reader.read_log(log_path, [*image_topics, topics.MAVLINK_IN], log_report, flight):
        if rec.topic == topics.MAVLINK_IN:
            chunks.append((rec.publish_time_ns // 1000, bytes(rec.data)))
            offsets_ns.append(rec.log_time_ns - rec.publish_time_ns)
            continue
        c = image_topics.index(rec.topic)
        image_topic, camera, times = image_topics[c], cameras[c], capture_mono_us[c]
        try:
            _cam, t_us, image = reader.decode_image(rec)
        except Exception as exc:  # name the file and the message at fault
            raise LogConversionError(
                f"{log_path}: {image_topic} message at log time {rec.log_time_ns} ns "
                f"cannot be decoded: {exc}"
            ) from None
        if image is None or image.ndim != 3:
            raise LogConversionError(
                f"{log_path}: {image_topic} message at log time {rec.log_time_ns} ns "
                "holds no colour image"
            )
        h, w = image.shape[:2]
        if (w, h) != (camera.width, camera.height):
            raise LogConversionError(
                f"{log_path}: {image_topic} frame at t={t_us} us is {w}x{h} but metadata "
                f"camera{ids[c]} says {camera.width}x{camera.height}"
            )
        if times and t_us <= times[-1]:
            skipped[c] += 1  # scenario frame times must strictly increase
            continue
        writers[c].write_frame(len(times), image)
        times.append(int(t_us))
        offsets_ns.append(rec.log_time_ns - rec.publish_time_ns)

    for image_topic, times in zip(image_topics, capture_mono_us):
        if not times:
            raise LogConversionError(f"{log_path}: no messages on {image_topic}")
    if not chunks:
        raise LogConversionError(
            f"{log_path}: no messages on {topics.MAVLINK_IN} (a scenario needs the autopilot "
            "telemetry)"
        )
    offset_us = _wall_minus_mono_us(metadata, offsets_ns)

    bad = 0

    def count_bad(n: int) -> None:
        nonlocal bad
        bad += n

    frames_out = list(split_mavlink(iter(chunks), on_bad=count_bad))
    if not any(_msgid(f) in _MSGID_ATTITUDE for _, f in frames_out):
        raise LogConversionError(
            f"{log_path}: {topics.MAVLINK_IN} holds no ATTITUDE or ATTITUDE_QUATERNION "
            "(the scenario format requires the autopilot's attitude)"
        )

    records = ((t_mono + offset_us, frame) for t_mono, frame in frames_out)
    (rig_writer or writers[0]).write_telemetry_records(records)
    for writer, times in zip(writers, capture_mono_us):
        writer.write_frames_csv(t_mono + offset_us for t_mono in times)
        writer.remove_stale_frames(len(times))
    if rig_writer is not None:
        description = (
            f"converted from flight log {log_path.name} (rig of {len(ids)} cameras:"
            f" {', '.join(names)})"
        )
    else:
        description = f"converted from flight log {log_path.name} (camera{ids[0]})"
    if metadata.get("description"):
        description += f": {metadata['description']}"
    if rig_writer is not None:
        toml = rig_scenario_toml(name or log_path.stem, description, list(zip(names, cameras)))
        rig_writer.write_toml(toml)
    else:
        toml = scenario_toml(name or log_path.stem, description, cameras[0], layout="tomli_w")
        writers[0].write_toml(toml)

    summary = ExportSummary(
        scenario_dir=out,
        frames=sum(len(t) for t in capture_mono_us),
        telemetry_records=len(frames_out),
        wall_minus_mono_us=offset_us,
        frames_skipped=sum(skipped),
        mavlink_bad=bad,
        cameras=names if rig else [],
    )
    for image_topic, n_skipped in zip(image_topics, skipped):
        if n_skipped:
            summary.warnings.append(
                f"{log_path}: {n_skipped} frames on {image_topic} skipped (capture time not"
                " after the previous frame's)"
            )
    if bad:
        summary.warnings.append(
            f"{log_path}: {bad} bytes on {topics.MAVLINK_IN} were not valid MAVLink frames "
            "(dropped)"
        )
    # a truncated or damaged log: the scenario holds only what was readable; say so
    summary.warnings += [f"{p} (exported what was readable)" for p in log_report.problems()]
    summary.warnings += log_report.notes
    for w in summary.warnings:
        log.warning("%s", w)
    return summary


def _camera_names(metadata: dict[str, str], n: int) -> list[str]:
    """A rig log's camera names (its ``cameras`` metadata, as the daemon's config names
    them), usable as a rig scenario's (``[A-Za-z0-9_-]+``, unique), else ``camera{i}``."""
    try:
        names = [str(x) for x in json.loads(metadata.get("cameras", "[]"))]
    except ValueError:
        names = []
    if len(names) != n or len(set(names)) != n or not all(CAMERA_NAME.match(x) for x in names):
        names = [f"camera{i}" for i in range(n)]
    return names


# --------------------------------------------------------------------------------------
# Scenario -> log
# --------------------------------------------------------------------------------------
def _retry(what: str, call: Callable[..., bool], *args: Any, timeout_s: float = 10.0) -> None:
    """The writer refuses (returns False) while its queue is full: wait, never drop."""
    deadline = time.monotonic() + timeout_s
    while not call(*args):
        if time.monotonic() > deadline:
            raise LogConversionError(
                f"the flight log writer refused {what} for {timeout_s:.0f} s "
                "(logging stopped: disk full or writer failed?)"
            )
        time.sleep(0.002)


def scenario_to_log(
    scenario_dir: str | Path,
    log_path: str | Path,
    image_format: str = "png",
    *,
    results: bool = False,
    config: Any | None = None,
) -> ImportSummary:
    """Write the scenario at ``scenario_dir`` as the flight log file ``log_path``.

    Frames go to ``/camera0/image`` at their capture times (``image_format`` ``"png"``,
    lossless, or ``"jpeg"``), the ``.tlog``'s MAVLink frames to ``/mavlink/in`` at their
    receive times, and the camera model to the metadata (``camera0``). With ``results``
    the scenario is also replayed (``config``: an ``AppConfig``, default settings if
    None) and each frame's ``/tcm/result`` and ``/camera0/annotations`` are logged too.
    Times are logged as they are (wall minus monotonic = 0), so converting the log back
    gives the same times.

    The results are logged so that process replay (``replay LOG --check``) reproduces
    them, as it does a flight's: the configuration and the parameters they were computed
    with go to the metadata (the pipeline runs on the configuration with the parameters
    applied, as the daemon does); a frame sees the telemetry received up to ``[daemon]
    attitude_wait_max_us`` after its capture (:func:`~tcm_companion.replay.scenario.run_replay`),
    so that telemetry is logged before the frame's result, which is logged when the frame
    was processed (capture + the wait); and the result records the clock offset the
    pipeline used.
    """
    scenario_dir = Path(scenario_dir)
    log_path = Path(log_path)
    if image_format not in ("png", "jpeg"):
        raise ValueError(f"image_format must be 'png' or 'jpeg', got {image_format!r}")
    if log_path.is_dir():
        raise LogConversionError(f"{log_path}: is a directory; give the .mcap file to write")
    loaded = load_any(scenario_dir)  # ScenarioError names file and line
    frames: Iterator[tuple[int, int, int, Any]]  # (capture time, camera id, frame, image)
    if isinstance(loaded, RigScenario):
        if results:
            raise LogConversionError(
                f"{scenario_dir}: a camera rig is imported without --results (its results"
                " come from every camera through the rig tracker: replay DIR --results FILE)"
            )
        scenario_name, description = loaded.name, loaded.description
        n_frames = loaded.n_frames
        camera_meta = {
            f"camera{k}": json.dumps(c.camera.to_dict()) for k, c in enumerate(loaded.cameras)
        }
        camera_meta["cameras"] = json.dumps(loaded.camera_names)

        def tagged(k: int, cam: Scenario) -> Iterator[tuple[int, int, int, Any]]:
            for i, t, img in cam.iter_frames():
                yield t, k, i, img

        frames = heapq.merge(
            *(tagged(k, c) for k, c in enumerate(loaded.cameras)), key=lambda x: x[:2]
        )
    else:
        scenario = loaded
        scenario_name, description = scenario.name, scenario.description
        n_frames = scenario.n_frames
        camera_meta = {"camera0": json.dumps(scenario.camera.to_dict())}
        frames = ((t, 0, i, img) for i, t, img in scenario.iter_frames())
    tlog_path = scenario_dir / "telemetry.tlog"
    try:
        records, _stats = read_tlog(tlog_path)
    except TlogError as exc:
        raise ScenarioError(str(exc)) from None
    mavlink = [(r.recv_us, bytes(r.msg.get_msgbuf())) for r in records]
    mavlink.sort(key=lambda x: x[0])

    pipeline = None
    threshold = 0.0
    wait_us = 0
    recorded: dict[str, str] = {}
    if results:
        from ..config import AppConfig, config_to_toml
        from ..core.pipeline import Pipeline
        from ..core.telemetry import TelemetryBuffer
        from ..io.detector_model import read_detector_model
        from ..mavlink.params import ParamTable, config_with_params, params_from_config
        from ..replay.scenario import telemetry_wait_us

        cfg = config if config is not None else AppConfig()
        # the daemon's start: the parameters from the configuration, applied to it
        params = ParamTable(defaults=params_from_config(cfg.pipeline)).values
        pipe_cfg = config_with_params(cfg.pipeline, params)
        recorded = {"config": config_to_toml(cfg), "params": json.dumps(params, sort_keys=True)}
        buffer = TelemetryBuffer()
        pipeline = Pipeline(
            scenario.camera,
            pipe_cfg,
            telemetry=buffer,
            detector_model=read_detector_model(pipe_cfg.detection),
        )
        threshold = float(pipe_cfg.classifier.tcm_threshold)
        wait_us = telemetry_wait_us(cfg)
        telemetry = sorted(scenario.telemetry, key=lambda s: s.recv_us)

    log_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{log_path.stem}-", dir=log_path.parent))
    n_results = 0
    try:
        lcfg = LoggingConfig(
            enabled=True,
            directory=str(tmp),
            image_format=image_format,  # type: ignore[arg-type]
            rotate_size_mb=1e9,
            rotate_interval_s=1e12,
            min_free_mb=0.0,
            queue_items=64,  # bounded memory; the producer waits (see _retry)
        )
        writer = FlightLogWriter(lcfg, tmp, wall_minus_mono_ns=0)
        writer.start(
            {
                **camera_meta,
                "source": f"tcm-scenario {scenario_dir}",
                "scenario_name": scenario_name,
                "description": description,
                **recorded,
            }
        )
        try:
            j = 0  # next MAVLink record
            k = 0  # next telemetry sample for the pipeline
            for t_us, cam_k, i, image in frames:
                while j < len(mavlink) and mavlink[j][0] <= t_us:
                    t_m, frame = mavlink[j]
                    _retry("a MAVLink message", writer.log_mavlink, "in", t_m, frame)
                    j += 1
                _retry(f"frame {i}", writer.log_frame, cam_k, t_us, image)
                if pipeline is not None:
                    t_done = t_us + wait_us  # processed with what had arrived by then
                    while j < len(mavlink) and mavlink[j][0] <= t_done:
                        t_m, frame = mavlink[j]
                        _retry("a MAVLink message", writer.log_mavlink, "in", t_m, frame)
                        j += 1
                    start = k
                    while k < len(telemetry) and telemetry[k].recv_us <= t_done:
                        k += 1
                    buffer.extend(telemetry[start:k])
                    offset = buffer.clock.offset_us  # what the step places attitude with
                    res = pipeline.step(image, t_us)
                    doc = replay_result_doc(
                        res, threshold, clock_offset_us=offset, t_process_us=t_done
                    )
                    circles = annotation_circles(res, scenario.camera)
                    _retry(f"result {i}", writer.log_json, topics.RESULT, t_done, doc)
                    _retry(f"annotations {i}", writer.log_annotations, 0, t_us, circles)
                    n_results += 1
            for t_m, frame in mavlink[j:]:
                _retry("a MAVLink message", writer.log_mavlink, "in", t_m, frame)
        finally:
            writer.stop(timeout_s=60.0)
        st = writer.stats
        want_messages = len(mavlink) + 2 * n_results
        if st.frames_logged != n_frames or st.messages_logged != want_messages:
            raise LogConversionError(
                f"{log_path}: the flight log writer logged {st.frames_logged}/"
                f"{n_frames} frames and {st.messages_logged}/{want_messages} "
                f"messages (state {st.state}, {st.write_errors} write errors, "
                f"{st.encode_errors} encode errors)"
            )
        files = reader.log_files(tmp)
        if len(files) != 1:
            raise LogConversionError(
                f"{tmp}: the flight log writer produced {len(files)} files, expected one"
            )
        shutil.move(str(files[0]), str(log_path))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return ImportSummary(
        log_path=log_path, frames=n_frames, mavlink_records=len(mavlink), results=n_results
    )


def replay_result_doc(
    result: Any,
    threshold: float,
    camera_id: int = 0,
    *,
    clock_offset_us: float = float("nan"),
    t_process_us: int | None = None,
) -> dict[str, Any]:
    """The ``/tcm/result`` document of a replayed :class:`FrameResult` (no latency: the
    frame was not captured live; processing time: ``t_process_us``, default the capture
    time; ``clock_offset_us``: the boot-to-companion offset the pipeline used, NaN for
    unknown)."""
    return result_doc(
        camera_id,
        result,
        threshold=threshold,
        t_process_us=int(result.t_us) if t_process_us is None else int(t_process_us),
        override="",
        clock_offset_us=clock_offset_us,
        latency_ms=None,
    )
