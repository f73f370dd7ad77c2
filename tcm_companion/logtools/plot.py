"""Analysis plots (PNG) of a flight log or of a scenario's replay.

:func:`plot_log` reads a flight log (one ``.mcap`` or a directory of rotated ones):
``/tcm/result`` per frame, ``/tcm/health`` once a second and the autopilot's attitude
from ``/mavlink/in`` — the attitude the companion used: the logged bytes go through a
fresh MAVLink endpoint, the daemon's own rule (the first autopilot heartbeat picks the
autopilot; another system's ATTITUDE, or a second sender under the autopilot's id, is
not its attitude; issue 24 drew a second system's −172° pitch as the vehicle's). :func:`plot_scenario` replays a ``tcm-scenario/1`` directory (or a
simulated scenario in memory) through the pipeline and plots the same documents, with
the scenario's ``truth.csv`` overlaid where it has one. Both write:

=================  ===============================================================
``disparity.png``  TCM disparity δ per track over time, coloured by state, with the
                   threshold; truth "object moving" as background bands
``bearings.png``   azimuth and elevation (local-level NED) per track; truth bearings
``ttc.png``        time to contact per track; frames flagged collision course marked;
                   the true time to contact (range over closing speed) per truth object
``egomotion.png``  translation-direction uncertainty σ and inlier ratio over time
``latency.png``    histogram of capture → MAVLink latency (replay: processing time)
``attitude.png``   roll, pitch, yaw of the attitude the companion used
``health.png``     frame rate, latency and dropped frames from ``/tcm/health`` (logs)
=================  ===============================================================

Legends sit outside the axes (right of them) so that they never hide data. A health
document's latency counts only once a ``/tcm/result`` has been published: before that the
daemon reports 0 ms for "no frames yet", which is drawn as a gap, not as 0 ms.
:func:`build_figures` returns the matplotlib figures without writing them.

A plot without data is skipped, not drawn empty: the returned :class:`PlotFiles` (a list
of the written paths) says in ``skipped`` which plots were left out and why, and the
reason is logged. Times are seconds from the first frame (logs: the companion's
monotonic clock, on which capture and receive times are stamped).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from ..flightlog import topics
from ..io.outputs import PNG_FILE, atomic_path

log = logging.getLogger(__name__)

__all__ = [
    "PLOT_NAMES",
    "PlotData",
    "PlotFiles",
    "build_figures",
    "load_log_data",
    "load_scenario_data",
    "plot_data",
    "plot_log",
    "plot_scenario",
]

PLOT_NAMES = ("disparity", "bearings", "ttc", "egomotion", "latency", "attitude", "health")
STATE_COLOURS = {"moving": "tab:red", "stationary": "tab:green", "unknown": "0.6"}
TRUTH_COLOURS = ("tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
DPI = 110
TTC_AXIS_MAX_S = 30.0


class PlotFiles(list[Path]):
    """The PNG files written, plus ``skipped``: plot name -> why it was not drawn."""

    def __init__(self, paths: Iterable[Path] = (), skipped: dict[str, str] | None = None):
        super().__init__(paths)
        self.skipped: dict[str, str] = dict(skipped or {})


@dataclass
class TruthSeries:
    """Ground truth of one object at the frame times."""

    object_id: int
    t_s: np.ndarray
    moving: np.ndarray  # bool
    azimuth_deg: np.ndarray  # local-level NED, clockwise from north
    elevation_deg: np.ndarray
    ttc_s: np.ndarray | None = None  # true time to contact; NaN where not closing


@dataclass
class PlotData:
    """Everything the plots draw, already on one time axis (µs, same clock)."""

    source: str  # shown in titles
    results: list[dict[str, Any]] = field(default_factory=list)  # /tcm/result documents
    health: list[tuple[int, dict[str, Any]]] = field(default_factory=list)  # (t_us, doc)
    attitude: list[tuple[int, float, float, float]] = field(default_factory=list)  # rad
    autopilot: str = ""  # "1/1": whose attitude (logs: the autopilot the companion followed)
    truth: list[TruthSeries] = field(default_factory=list)
    latency_is_processing_time: bool = False  # replay: no live latency
    t0_us: int | None = None
    # When the first /tcm/result was published (logs): health latency counts from then on.
    first_result_us: int | None = None


# --------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------
def load_log_data(path: str | Path, flight: str | None = None) -> PlotData:
    """Read what the plots need from a flight log (file or rotated directory; ``flight``
    picks one of a directory's flights)."""
    from ..flightlog import reader
    from .convert import check_log_path

    path = Path(path)
    check_log_path(path, flight)
    data = PlotData(source=path.name)
    chunks: list[tuple[int, bytes]] = []
    wanted = [topics.RESULT, topics.HEALTH, topics.MAVLINK_IN]
    for rec in reader.read_log(path, topics=wanted, flight=flight):
        t_us = rec.publish_time_ns // 1000
        if rec.topic == topics.MAVLINK_IN:
            chunks.append((t_us, bytes(rec.data)))
            continue
        try:
            doc = reader.decode_json(rec)
        except ValueError as exc:
            log.warning("%s: %s message at %d us is not JSON (%s)", path, rec.topic, t_us, exc)
            continue
        if rec.topic == topics.RESULT:
            if isinstance(doc.get("t_capture_us"), int):
                data.results.append(doc)
                if data.first_result_us is None or t_us < data.first_result_us:
                    data.first_result_us = t_us
            else:
                log.warning("%s: %s at %d us has no t_capture_us (skipped)", path, rec.topic, t_us)
        else:
            data.health.append((t_us, doc))
    data.attitude, data.autopilot = followed_attitude(chunks)
    data.results.sort(key=lambda d: (d.get("t_capture_us", 0), d.get("camera_id", 0)))
    return data


def followed_attitude(
    chunks: Sequence[tuple[int, bytes]],
) -> tuple[list[tuple[int, float, float, float]], str]:
    """The attitude samples ``(receive µs, roll, pitch, yaw rad)`` the companion used, of
    the logged received bytes ``chunks``, and whose they were (``"1/1"``, "" when no
    autopilot was found): the bytes through a fresh
    :class:`~tcm_companion.mavlink.endpoint.CompanionEndpoint` at their receive times,
    as process replay does."""
    from ..core.frames import euler_zyx_from_rot
    from ..core.telemetry import AttitudeSample
    from ..mavlink.endpoint import CompanionEndpoint, TelemetryReceived

    out: list[tuple[int, float, float, float]] = []
    if not chunks:
        return out, ""
    ep = CompanionEndpoint(now_us=chunks[0][0])
    for t_us, data in chunks:
        ep.poll(t_us)  # its timers: an autopilot lost and found again starts anew
        for ev in ep.receive_data(data, t_us):
            if isinstance(ev, TelemetryReceived) and isinstance(ev.sample, AttitudeSample):
                roll, pitch, yaw = euler_zyx_from_rot(ev.sample.R_ned_from_body)
                out.append((t_us, roll, pitch, yaw))
        ep.data_to_send()
    ap = ep.autopilot
    return out, f"{ap.system_id}/{ap.component_id}" if ap is not None else ""


def load_scenario_data(scenario: Any, config: Any | None = None) -> PlotData:
    """Replay ``scenario`` (a directory or a loaded/simulated scenario) for the plots."""
    from ..config import AppConfig
    from ..io.scenario import load_scenario
    from ..replay.scenario import run_replay
    from .convert import replay_result_doc

    if isinstance(scenario, str | Path):
        scenario = load_scenario(scenario)
    cfg = config if config is not None else AppConfig()
    threshold = float(cfg.pipeline.classifier.tcm_threshold)
    data = PlotData(source=str(scenario.name), latency_is_processing_time=True)
    data.results = [replay_result_doc(r, threshold) for r in run_replay(scenario, cfg)]
    times = np.asarray(scenario.frame_times_us, dtype=np.int64)
    data.t0_us = int(times[0]) if len(times) else None
    for s in scenario.attitude_samples():
        R = np.asarray(s.R_ned_from_body, dtype=np.float64)
        roll = math.atan2(R[2, 1], R[2, 2])
        pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
        yaw = math.atan2(R[1, 0], R[0, 0])
        data.attitude.append((int(s.recv_us), roll, pitch, yaw))
    truth = getattr(scenario, "truth", None)
    if truth is not None and len(truth.frame):
        t_s = (times - times[0]) / 1e6
        ttc_s = truth.ttc_s(times)
        for oid in truth.object_ids:
            rows = truth.rows_for_object(oid)
            rel = truth.obj_ned_m[rows] - truth.veh_ned_m[rows]
            az = np.degrees(np.arctan2(rel[:, 1], rel[:, 0]))
            el = np.degrees(np.arctan2(-rel[:, 2], np.hypot(rel[:, 0], rel[:, 1])))
            data.truth.append(
                TruthSeries(
                    object_id=int(oid),
                    t_s=t_s[truth.frame[rows]],
                    moving=np.asarray(truth.moving[rows], dtype=bool),
                    azimuth_deg=az,
                    elevation_deg=el,
                    ttc_s=ttc_s[rows],
                )
            )
    return data


# --------------------------------------------------------------------------------------
# Entry points
# --------------------------------------------------------------------------------------
def plot_log(path: str | Path, out_dir: str | Path, flight: str | None = None) -> PlotFiles:
    """Plot a flight log (``.mcap`` file or directory of rotated files; ``flight`` picks
    one of a directory's flights) into ``out_dir``."""
    return plot_data(load_log_data(path, flight), out_dir)


def plot_scenario(scenario: Any, out_dir: str | Path, config: Any | None = None) -> PlotFiles:
    """Replay a scenario (directory or scenario object) and plot it with its truth."""
    return plot_data(load_scenario_data(scenario, config), out_dir)


def plot_data(data: PlotData, out_dir: str | Path) -> PlotFiles:
    """Draw every plot that has data; see the module docstring for the list."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures, skipped = build_figures(data)
    files = PlotFiles(skipped=skipped)
    for name, fig in figures.items():
        path = out / f"{name}.png"
        # whole or not at all; an earlier PNG of that name is replaced, nothing else is
        with atomic_path(path, kind=PNG_FILE, force=True) as tmp:
            fig.savefig(tmp)
        files.append(path)
    return files


def build_figures(data: PlotData) -> tuple[dict[str, Figure], dict[str, str]]:
    """The figures of every plot that has data (by name, in :data:`PLOT_NAMES` order),
    and for the others why they were skipped (also logged)."""
    figures: dict[str, Figure] = {}
    skipped: dict[str, str] = {}
    t0 = _t0_us(data)
    drawers = {
        "disparity": _plot_disparity,
        "bearings": _plot_bearings,
        "ttc": _plot_ttc,
        "egomotion": _plot_egomotion,
        "latency": _plot_latency,
        "attitude": _plot_attitude,
        "health": _plot_health,
    }
    for name, draw in drawers.items():
        fig = Figure(figsize=(10, 5.5), dpi=DPI, layout="constrained")
        reason = draw(fig, data, t0)
        if reason:
            skipped[name] = reason
            log.info("%s: %s plot skipped: %s", data.source, name, reason)
            continue
        figures[name] = fig
    return figures, skipped


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------
def _t0_us(data: PlotData) -> int:
    """Time zero: the first frame (telemetry before it plots at negative times)."""
    if data.t0_us is not None:
        return data.t0_us
    frames = [int(d["t_capture_us"]) for d in data.results if "t_capture_us" in d]
    if frames:
        return min(frames)
    starts = [t for t, *_ in data.attitude[:1]] + [t for t, _ in data.health[:1]]
    return min(starts) if starts else 0


def _frame_span(ax: Axes, data: PlotData, t0: int) -> None:
    """Give every per-frame plot the same time axis: the span of the frames."""
    t = _result_times(data, t0)
    if t.size > 1:
        pad = 0.01 * float(t[-1] - t[0])
        ax.set_xlim(float(t[0]) - pad, float(t[-1]) + pad)


def _f(x: Any) -> float:
    """A JSON number or null as float (NaN for null/missing)."""
    try:
        return float(x) if x is not None else math.nan
    except (TypeError, ValueError):
        return math.nan


@dataclass
class _Track:
    label: str
    t_s: list[float] = field(default_factory=list)
    objs: list[dict[str, Any]] = field(default_factory=list)

    def values(self, key: str) -> np.ndarray:
        return np.array([_f(o.get(key)) for o in self.objs], dtype=np.float64)

    def states(self) -> list[str]:
        return [str(o.get("state", "unknown")) for o in self.objs]


def _tracks(data: PlotData, t0: int) -> list[_Track]:
    cams = {int(d.get("camera_id", 0)) for d in data.results}
    tracks: dict[tuple[int, int], _Track] = {}
    for d in data.results:
        cam = int(d.get("camera_id", 0))
        t_s = (int(d["t_capture_us"]) - t0) / 1e6
        for o in d.get("objects") or ():
            key = (cam, int(o.get("track_id", -1)))
            if key not in tracks:
                label = f"track {key[1]}" if len(cams) == 1 else f"cam{cam} track {key[1]}"
                tracks[key] = _Track(label)
            tracks[key].t_s.append(t_s)
            tracks[key].objs.append(o)
    return [tracks[k] for k in sorted(tracks)]


def _result_times(data: PlotData, t0: int) -> np.ndarray:
    return np.array([(int(d["t_capture_us"]) - t0) / 1e6 for d in data.results])


def _truth_bands(ax: Axes, data: PlotData) -> list[Any]:
    """Shade the spans where each truth object moves; legend handles."""
    handles: list[Any] = []
    for k, tr in enumerate(data.truth):
        colour = TRUTH_COLOURS[k % len(TRUTH_COLOURS)]
        drawn = False
        for a, b in _runs(tr.t_s, tr.moving):
            ax.axvspan(a, b, color=colour, alpha=0.12, lw=0)
            drawn = True
        if drawn:
            handles.append(
                Patch(color=colour, alpha=0.25, label=f"truth: object {tr.object_id} moving")
            )
    return handles


def _runs(t: np.ndarray, flag: np.ndarray) -> Iterator[tuple[float, float]]:
    """(start, end) times of the runs where ``flag`` is true (ends half a step on)."""
    if len(t) == 0:
        return
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.04
    start: float | None = None
    for i, f in enumerate(flag):
        if f and start is None:
            start = float(t[i]) - step / 2
        if not f and start is not None:
            yield start, float(t[i]) - step / 2
            start = None
    if start is not None:
        yield start, float(t[-1]) + step / 2


def _state_legend() -> list[Any]:
    return [
        Line2D([], [], ls="", marker="o", color=c, label=f"state: {s}")
        for s, c in STATE_COLOURS.items()
    ]


def _legend(fig: Figure, handles: Sequence[Any] | None = None) -> None:
    """The figure's legend outside the axes, right of them (constrained layout makes room),
    so that it never hides data; ``handles`` default to the labelled artists of all axes."""
    if handles is None:
        seen: dict[str, Any] = {}
        for ax in fig.axes:
            for h, label in zip(*ax.get_legend_handles_labels()):
                seen.setdefault(label, h)
        handles = list(seen.values())
    if handles:
        fig.legend(handles=handles, loc="outside right upper", fontsize=8)


def _integer_ticks(ax: Axes, bars: bool = False) -> None:
    """Counts (frames) on the y axis: integer ticks only, the axis from 0 to at least 1
    (points: a little below 0, so that zero counts do not hide in the axis line)."""
    ax.yaxis.set_major_locator(MaxNLocator(integer=True, min_n_ticks=1))
    top = max(1.0, ax.get_ylim()[1])
    ax.set_ylim(0.0 if bars else -0.03 * top, top)


def _title(data: PlotData, what: str) -> str:
    return f"{what} — {data.source}"


def _time_label(data: PlotData) -> str:
    return "time since first frame (s)"


# --------------------------------------------------------------------------------------
# The plots: each returns "" when drawn, else why it was skipped
# --------------------------------------------------------------------------------------
def _plot_disparity(fig: Figure, data: PlotData, t0: int) -> str:
    if not data.results:
        return f"no {topics.RESULT} documents"
    tracks = _tracks(data, t0)
    if not any(np.isfinite(tr.values("disparity")).any() for tr in tracks):
        return "no disparity values (no object was ever decided)"
    ax = fig.add_subplot()
    handles = _truth_bands(ax, data)
    for tr in tracks:
        t = np.asarray(tr.t_s)
        d = tr.values("disparity")
        ax.plot(t, d, "-", color="0.75", lw=0.8, zorder=1)
        colours = [STATE_COLOURS.get(s, "k") for s in tr.states()]
        ax.scatter(t, d, c=colours, s=9, zorder=2)
        ok = np.isfinite(d)
        if ok.any():
            i = int(np.nonzero(ok)[0][-1])
            ax.annotate(
                tr.label, (t[i], d[i]), fontsize=7, xytext=(3, 0), textcoords="offset points"
            )
    th_t = _result_times(data, t0)
    th = np.array([_f(d.get("threshold")) for d in data.results])
    if np.isfinite(th).any():
        ax.step(th_t, th, where="post", color="k", ls="--", lw=1.2)
        handles.append(Line2D([], [], color="k", ls="--", label="threshold"))
    ax.set_xlabel(_time_label(data))
    _frame_span(ax, data, t0)
    ax.set_ylabel("TCM disparity δ (dimensionless)")
    ax.set_ylim(bottom=0)
    ax.set_title(_title(data, "TCM disparity per track (dots: state)"))
    ax.grid(alpha=0.3)
    _legend(fig, _state_legend() + handles)
    return ""


def _plot_bearings(fig: Figure, data: PlotData, t0: int) -> str:
    tracks = _tracks(data, t0)
    if not tracks:
        return f"no tracked objects in {topics.RESULT}"
    if not any(np.isfinite(tr.values("azimuth_ned_deg")).any() for tr in tracks):
        return f"no object bearings (azimuth_ned_deg) in {topics.RESULT}"
    axes = fig.subplots(2, 1, sharex=True)
    for ax, key, truth_key, label in (
        (axes[0], "azimuth_ned_deg", "azimuth_deg", "azimuth, clockwise from north (°)"),
        (axes[1], "elevation_ned_deg", "elevation_deg", "elevation, up (°)"),
    ):
        for truth in data.truth:
            ax.plot(truth.t_s, getattr(truth, truth_key), "k--", lw=1.0, alpha=0.7)
        for tr in tracks:
            ax.plot(tr.t_s, tr.values(key), ".-", ms=3, lw=0.6, label=tr.label)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    handles, _ = axes[0].get_legend_handles_labels()
    if data.truth:
        handles.append(Line2D([], [], color="k", ls="--", label="truth (per object)"))
    if len(handles) <= 12:
        _legend(fig, handles)
    _frame_span(axes[1], data, t0)
    axes[1].set_xlabel(_time_label(data))
    axes[0].set_title(_title(data, "Object bearings (local-level NED)"))
    return ""


def _plot_ttc(fig: Figure, data: PlotData, t0: int) -> str:
    tracks = _tracks(data, t0)
    has_ttc = any(np.isfinite(tr.values("ttc_s")).any() for tr in tracks)
    has_cc = any(bool(o.get("collision_course")) for tr in tracks for o in tr.objs)
    truths = [t for t in data.truth if t.ttc_s is not None and np.isfinite(t.ttc_s).any()]
    if not (has_ttc or has_cc or truths):
        return "no time to contact (no object approaching) and no collision-course frame"
    ax = fig.add_subplot()
    finite: list[float] = []  # the estimates: they set the scale
    truth_finite: list[float] = []
    dashes = ("--", "-.", ":")
    for k, truth in enumerate(truths):
        assert truth.ttc_s is not None
        ax.plot(
            truth.t_s,
            truth.ttc_s,
            color="k",
            ls=dashes[k % len(dashes)],
            lw=1.2,
            alpha=0.8,
            zorder=1,
            label=f"truth: object {truth.object_id} (range / closing speed)",
        )
        truth_finite += [float(v) for v in truth.ttc_s if math.isfinite(v)]
    for tr in tracks:
        ttc = tr.values("ttc_s")
        ax.plot(tr.t_s, ttc, ".-", ms=3, lw=0.8, label=tr.label, zorder=2)
        finite += [float(v) for v in ttc if math.isfinite(v)]
    cc_t: list[float] = []
    cc_v: list[float] = []
    for tr in tracks:
        ttc = tr.values("ttc_s")
        for t, o, v in zip(tr.t_s, tr.objs, ttc):
            if o.get("collision_course"):
                cc_t.append(t)
                cc_v.append(v if math.isfinite(v) else 0.0)
    if cc_t:
        ax.scatter(
            cc_t, cc_v, marker="x", color="tab:red", s=30, zorder=3, label="collision course"
        )
    ax.set_xlabel(_time_label(data))
    _frame_span(ax, data, t0)
    ax.set_ylabel("time to contact (s)")
    # The estimates set the scale (truth only when there are none): the true TTC runs off
    # to infinity where the range stops closing. Receding or barely closing objects: keep
    # the near ones legible.
    top = min(max(finite or truth_finite or [1.0]), TTC_AXIS_MAX_S)
    if max(finite + truth_finite, default=0.0) > top:
        ax.text(
            0.01,
            0.98,
            f"values above {top:.0f} s are off the scale",
            transform=ax.transAxes,
            fontsize=7,
            va="top",
        )
    ax.set_ylim(0, top * 1.05)
    ax.set_title(_title(data, "Time to contact per track"))
    ax.grid(alpha=0.3)
    _legend(fig)
    return ""


def _plot_egomotion(fig: Figure, data: PlotData, t0: int) -> str:
    rows = [(d, d["egomotion"]) for d in data.results if d.get("egomotion")]
    if not rows:
        return f"no egomotion estimates in {topics.RESULT}"
    t = np.array([(int(d["t_capture_us"]) - t0) / 1e6 for d, _ in rows])
    sigma = np.degrees([_f(e.get("sigma_rad")) for _, e in rows])
    inl = np.array([_f(e.get("inlier_ratio")) for _, e in rows])
    valid = np.array([bool(e.get("valid")) for _, e in rows])
    sources = sorted({str(e.get("source", "?")) for _, e in rows})
    axes = fig.subplots(2, 1, sharex=True)
    for ax, y, label in (
        (axes[0], sigma, "direction uncertainty σ (°)"),
        (axes[1], inl, "inlier ratio (0–1)"),
    ):
        ax.plot(t[valid], y[valid], ".", ms=3, color="tab:blue", label="valid")
        if (~valid).any():
            ax.plot(t[~valid], y[~valid], "x", ms=4, color="tab:red", label="invalid")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[1].set_ylim(0, 1.05)
    _frame_span(axes[1], data, t0)
    _legend(fig)
    axes[1].set_xlabel(_time_label(data))
    axes[0].set_title(_title(data, f"Egomotion quality (source: {', '.join(sources)})"))
    return ""


def _percentiles(x: np.ndarray) -> Sequence[tuple[str, float]]:
    from ..service.health import latency_percentile_ms

    return [(f"p{p}", latency_percentile_ms(x, p)) for p in (50, 90, 99)]


def _plot_latency(fig: Figure, data: PlotData, t0: int) -> str:
    lat = np.array([_f(d.get("latency_ms")) for d in data.results])
    lat = lat[np.isfinite(lat)]
    what = "capture → MAVLink latency (ms)"
    if not lat.size:
        lat = np.array([_f((d.get("timings_ms") or {}).get("total")) for d in data.results])
        lat = lat[np.isfinite(lat)]
        what = "pipeline processing time per frame (ms)"
        if not lat.size:
            return f"no latency_ms or timings_ms.total in {topics.RESULT}"
        if not data.latency_is_processing_time:
            what += " — the log has no latency_ms"
    ax = fig.add_subplot()
    if np.ptp(lat) > 0:
        ax.hist(lat, bins=min(60, max(10, lat.size // 10)), color="tab:blue", alpha=0.8)
    else:  # all equal: one bar centred on the value
        ax.hist(lat, bins=11, range=(lat[0] - 0.5, lat[0] + 0.5), color="tab:blue", alpha=0.8)
    for (name, v), ls in zip(_percentiles(lat), ("-", "--", ":")):
        ax.axvline(v, color="k", ls=ls, lw=1, label=f"{name} = {v:.2f} ms")
    ax.set_xlabel(what)
    ax.set_ylabel("frames")
    _integer_ticks(ax, bars=True)
    title = (
        "Processing time (replay, not live latency)"
        if data.latency_is_processing_time
        else "Latency"
    )
    ax.set_title(_title(data, f"{title}, {lat.size} frames, max {lat.max():.2f} ms"))
    ax.grid(alpha=0.3)
    _legend(fig)
    return ""


def _plot_attitude(fig: Figure, data: PlotData, t0: int) -> str:
    if not data.attitude:
        return "no attitude from the autopilot"
    a = np.array(data.attitude, dtype=np.float64)
    t = (a[:, 0] - t0) / 1e6
    axes = fig.subplots(3, 1, sharex=True)
    for ax, col, name in zip(axes, (1, 2, 3), ("roll (°)", "pitch (°)", "yaw (°)")):
        ax.plot(t, np.degrees(a[:, col]), lw=0.8)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(f"{_time_label(data)}, receive time")
    who = f"Autopilot {data.autopilot} attitude" if data.autopilot else "Autopilot attitude"
    axes[0].set_title(_title(data, f"{who} ({len(a)} samples)"))
    return ""


def _health_series(data: PlotData, key: str) -> np.ndarray:
    """One field of the health documents; latency is NaN (no data, drawn as a gap) until
    the first /tcm/result was published: before any frame the daemon reports 0 ms."""
    values = np.array([_f(d.get(key)) for _, d in data.health], dtype=np.float64)
    if key == "latency_ms":
        first = data.first_result_us
        if first is None and data.results:
            first = min(int(d["t_capture_us"]) for d in data.results)
        if first is None:  # no frame at all
            values[:] = np.nan
        else:
            values[np.array([tu for tu, _ in data.health]) < first] = np.nan
    return values


def _plot_health(fig: Figure, data: PlotData, t0: int) -> str:
    if not data.health:
        return f"no {topics.HEALTH} documents"
    t = np.array([(tu - t0) / 1e6 for tu, _ in data.health])
    series = [
        ("frame_rate_hz", "frame rate (Hz)"),
        ("latency_ms", "latency p50 (ms)"),
        ("frames_dropped", "frames dropped (total)"),
    ]
    present = [(k, lbl) for k, lbl in series if any(k in d for _, d in data.health)]
    if not present:
        return f"{topics.HEALTH} has none of frame_rate_hz, latency_ms, frames_dropped"
    axes = np.atleast_1d(fig.subplots(len(present), 1, sharex=True))
    for ax, (key, label) in zip(axes, present):
        y = _health_series(data, key)
        ax.plot(t, y, ".-", ms=3, lw=0.8)
        if key == "latency_ms" and not np.isfinite(y).any():
            ax.text(0.5, 0.5, "no frame processed", transform=ax.transAxes, ha="center")
        if key == "frames_dropped":
            _integer_ticks(ax)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel(_time_label(data))
    axes[0].set_title(_title(data, "Daemon health (once a second)"))
    return ""
