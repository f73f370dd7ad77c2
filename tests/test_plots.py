"""The analysis plots (``tcm-companion plot``) and the evaluation's plots, checked on the
matplotlib figures they build: legends never over data, coinciding ROC curves all
visible, health latency blank before the first frame, integer frame counts, the true
time to contact drawn when the scenario has truth.

Each check has a counterpart showing that it fails on the figure it guards against.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from tcm_companion.core.classify import ClassifierConfig
from tcm_companion.eval.evaluate import ObjectFrame, ScenarioEval
from tcm_companion.eval.metrics import roc
from tcm_companion.eval.report import (
    ROC_STYLES,
    disparity_over_time_figure,
    roc_figure,
    same_curve,
    separation_figure,
)
from tcm_companion.logtools.plot import (
    PLOT_NAMES,
    PlotData,
    build_figures,
    load_scenario_data,
)
from tcm_companion.sim import make_scenario

from .plot_checks import assert_legends_clear, colour_pixels, figure_legends

#: The plots that always label something (so must have a legend) when drawn.
WITH_LEGEND = {"disparity", "bearings", "ttc", "egomotion", "latency"}


def _axes(fig: Figure, ylabel: str) -> Axes:
    (ax,) = [a for a in fig.axes if a.get_ylabel().startswith(ylabel)]
    return ax


def _ydata(ax: Axes) -> np.ndarray:
    """The y values of the first line of ``ax``."""
    return np.asarray(ax.get_lines()[0].get_ydata(), dtype=np.float64)


def _label(artist: Any) -> str:
    return str(artist.get_label())


def _ticks_in_view(ax: Axes) -> np.ndarray:
    lo, hi = ax.get_ylim()
    ticks = np.asarray(ax.get_yticks())
    return ticks[(ticks >= lo - 1e-9) & (ticks <= hi + 1e-9)]


# --------------------------------------------------------------------------------------
# Data: a simulated scenario with truth, and the same documents as a flight log has them
# --------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def scenario() -> Any:
    return make_scenario("T90", duration_s=2)


@pytest.fixture(scope="module")
def scenario_data(scenario: Any) -> PlotData:
    data = load_scenario_data(scenario)
    assert data.truth and data.results
    return data


def _log_like(data: PlotData, health_before_first_frame: int = 2) -> PlotData:
    """The scenario's documents as a live log has them: latency per frame, no truth, and a
    health document once a second, the first ones before the first frame (0 ms latency,
    the daemon's "no frames yet")."""
    results = [{**d, "latency_ms": 6.0 + (i % 7) * 0.5} for i, d in enumerate(data.results)]
    t_first = int(results[0]["t_capture_us"])
    t_last = int(results[-1]["t_capture_us"])
    health: list[tuple[int, dict[str, Any]]] = []
    t = t_first - health_before_first_frame * 1_000_000 + 300_000
    while t <= t_last:
        started = t > t_first
        health.append(
            (
                t,
                {
                    "frame_rate_hz": 25.0 if started else 0.0,
                    "latency_ms": 7.5 if started else 0.0,
                    "frames_dropped": 0,
                },
            )
        )
        t += 1_000_000
    return PlotData(
        source="log",
        results=results,
        health=health,
        attitude=data.attitude,
        first_result_us=t_first + 7000,
    )


# --------------------------------------------------------------------------------------
# Legends
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over a second of CPU
def test_scenario_plot_legends_do_not_hide_data(scenario_data: PlotData) -> None:
    figures, skipped = build_figures(scenario_data)
    assert set(figures) == set(PLOT_NAMES) - {"health"} and set(skipped) == {"health"}
    for name, fig in figures.items():
        n = assert_legends_clear(fig)
        assert n == (1 if name in WITH_LEGEND else 0), name


@pytest.mark.slow  # over a second of CPU
def test_log_plot_legends_do_not_hide_data(scenario_data: PlotData) -> None:
    figures, skipped = build_figures(_log_like(scenario_data))
    assert set(figures) == set(PLOT_NAMES) and not skipped
    for name, fig in figures.items():
        assert assert_legends_clear(fig) == (1 if name in WITH_LEGEND else 0), name


def test_legend_check_fails_on_a_legend_over_the_data() -> None:
    fig = Figure(figsize=(6, 4), layout="constrained")
    ax = fig.add_subplot()
    x = np.linspace(0, 1, 50)
    ax.plot(x, np.ones_like(x), label="data along the top")
    ax.legend(loc="upper right")  # the old placement
    with pytest.raises(AssertionError, match="over axes"):
        assert_legends_clear(fig)


@pytest.mark.slow  # over half a second of CPU
def test_eval_plot_legends_do_not_hide_data() -> None:
    cls = ClassifierConfig()
    evals = [_eval("static", moving=False, level=0.02), _eval("moving", moving=True, level=0.7)]
    fig = disparity_over_time_figure(evals, cls)
    assert assert_legends_clear(fig) == 2
    # the δ axis shows every value (it used to stop at 0.6)
    assert fig.axes[1].get_ylim()[1] >= 0.7 + 0.01
    sep = {k: 0.15 - 0.0002 * (k - 25) ** 2 for k in range(1, 41)}
    assert assert_legends_clear(separation_figure(sep)) == 1
    assert assert_legends_clear(roc_figure(_roc_records(), cls, "ROC")) == 1


def _eval(name: str, moving: bool, level: float) -> ScenarioEval:
    recs = [
        ObjectFrame(
            frame=i,
            t_us=i * 40_000,
            object_id=1,
            truth_moving=moving,
            matched=True,
            state="moving" if moving else "stationary",
            disparity=level * (0.9 + 0.1 * math.sin(i / 5)),
            time_s=i * 0.04,
        )
        for i in range(100)
    ]
    return ScenarioEval(name, (360, 220), recs)


# --------------------------------------------------------------------------------------
# ROC
# --------------------------------------------------------------------------------------
def _roc_records() -> list[ObjectFrame]:
    """TCM and ECM separate perfectly (so does fused): three curves at AUC 1 on top of
    each other; BSM does not."""
    rng = np.random.default_rng(1)
    out = []
    for i in range(200):
        m = i % 2 == 0
        out.append(
            ObjectFrame(
                frame=i,
                t_us=i,
                object_id=1,
                truth_moving=m,
                matched=True,
                state="moving" if m else "stationary",
                disparity=(0.3 if m else 0.02) + 0.01 * rng.random(),
                omega_rad=(0.2 if m else 0.01) + 0.01 * rng.random(),
                bsm_score=100 * rng.random() + (60 if m else 0),
                time_s=5.0,
            )
        )
    return out


def _method_lines(fig: Figure) -> dict[str, Any]:
    ax = fig.axes[0]
    return {
        _label(ln).split(" ")[0].lower(): ln
        for ln in ax.get_lines()
        if _label(ln).split(" ")[0].lower() in ROC_STYLES
    }


@pytest.mark.slow  # over half a second of CPU
def test_roc_curves_that_coincide_all_stay_visible() -> None:
    cls = ClassifierConfig()
    records = _roc_records()
    fig = roc_figure(records, cls, "ROC")
    lines = _method_lines(fig)
    assert set(lines) == {"tcm", "ecm", "bsm", "fused"}
    # The data drawn as they are (no offsets): each line is its ROC curve.
    for method, ln in lines.items():
        curve = roc(
            np.array([r.truth_moving for r in records]),
            np.array([r.score(method, cls) for r in records]),  # type: ignore[arg-type]
        )
        np.testing.assert_array_equal(ln.get_xdata(), curve.fpr)
        np.testing.assert_array_equal(ln.get_ydata(), curve.tpr)
    # Each drawn differently: line style, marker, and width all distinct.
    for attr in ("get_linestyle", "get_marker", "get_linewidth"):
        values = [str(getattr(ln, attr)()) for ln in lines.values()]
        assert len(set(values)) == len(values), (attr, values)
    assert all(ln.get_marker() not in (None, "None", "", " ") for ln in lines.values())
    # Stacked wide under narrow: a line drawn above another is narrower than it.
    by_z = sorted(lines.values(), key=lambda ln: ln.get_zorder())
    assert [ln.get_linewidth() for ln in by_z] == sorted(
        (ln.get_linewidth() for ln in by_z), reverse=True
    )
    assert len({ln.get_zorder() for ln in by_z}) == 4
    # Every curve shows in the rendered image (inside the axes, not only in the legend).
    ax = fig.axes[0]
    for method in ("tcm", "ecm", "fused"):
        assert colour_pixels(fig, ax, lines[method].get_markeredgecolor()) > 150, method
    # The legend says which curves coincide; the lines along the axes' edges are inside.
    labels = {m: _label(ln) for m, ln in lines.items()}
    assert labels["tcm"].endswith("same curve as ECM and FUSED")
    assert labels["ecm"].endswith("same curve as TCM and FUSED")
    assert labels["fused"].endswith("same curve as TCM and ECM")
    assert "same curve" not in labels["bsm"]
    legend_text = [t.get_text() for leg in figure_legends(fig) for t in leg.get_texts()]
    assert set(labels.values()) <= set(legend_text)
    assert ax.get_xlim()[0] < 0 and ax.get_ylim()[1] > 1


def test_roc_visibility_check_fails_when_the_fused_curve_hides_the_others() -> None:
    """The old drawing: equal solid lines, fused last: TCM and ECM cannot be seen."""
    fig = Figure(figsize=(5, 5))
    ax = fig.add_subplot()
    fpr, tpr = np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 1.0])
    for colour in ("tab:green", "tab:blue", "tab:purple"):
        ax.plot(fpr, tpr, color=colour)
    ax.set_xlim(-0.02, 1.02)
    ax.set_ylim(-0.02, 1.02)
    assert colour_pixels(fig, ax, "tab:purple") > 150
    assert colour_pixels(fig, ax, "tab:green") == colour_pixels(fig, ax, "tab:blue") == 0


def test_same_curve() -> None:
    a = (np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 1.0]))
    # the same path with extra (collinear or repeated) vertices
    b = (np.array([0.0, 0.0, 0.0, 0.0, 0.5, 1.0]), np.array([0.0, 0.5, 1.0, 1.0, 1.0, 1.0]))
    assert same_curve(a, b) and same_curve(b, a)
    c = (np.array([0.0, 0.1, 1.0]), np.array([0.0, 1.0, 1.0]))
    assert not same_curve(a, c)
    d = (np.array([0.0, 0.5, 1.0]), np.array([0.0, 0.5, 1.0]))  # the diagonal
    assert not same_curve(a, d)
    assert not same_curve(a, (np.array([]), np.array([])))


# --------------------------------------------------------------------------------------
# Health, latency histogram
# --------------------------------------------------------------------------------------
@pytest.mark.slow  # over half a second of CPU
def test_health_latency_blank_until_the_first_frame(scenario_data: PlotData) -> None:
    data = _log_like(scenario_data, health_before_first_frame=2)
    fig = build_figures(data)[0]["health"]
    latency = _ydata(_axes(fig, "latency"))
    rate = _ydata(_axes(fig, "frame rate"))
    t_first = data.first_result_us
    assert t_first is not None
    before = np.array([t < t_first for t, _ in data.health])
    assert before[:2].all() and not before[2:].any()
    assert np.isnan(latency[:2]).all()  # not 0 ms
    np.testing.assert_array_equal(latency[2:], 7.5)
    np.testing.assert_array_equal(rate[:2], 0.0)  # 0 Hz before the first frame is true
    # Without the publish time of the first result, the first frame's capture time counts.
    data.first_result_us = None
    latency = _ydata(_axes(build_figures(data)[0]["health"], "latency"))
    assert np.isnan(latency[:2]).all() and np.isfinite(latency[2:]).all()
    # No frame at all: no latency at all.
    data.results = []
    latency = _ydata(_axes(build_figures(data)[0]["health"], "latency"))
    assert np.isnan(latency).all()


@pytest.mark.slow  # over half a second of CPU
def test_frame_counts_have_integer_ticks(scenario_data: PlotData) -> None:
    few = PlotData(source="few", results=scenario_data.results[:12])  # counts of 1..3
    for data in (scenario_data, few, _log_like(scenario_data)):
        figures, _ = build_figures(data)
        ticks = _ticks_in_view(_axes(figures["latency"], "frames"))
        assert len(ticks) >= 2 and np.all(ticks == np.round(ticks)), ticks
    health = build_figures(_log_like(scenario_data))[0]["health"]
    ticks = _ticks_in_view(_axes(health, "frames dropped"))
    assert len(ticks) >= 1 and np.all(ticks == np.round(ticks)), ticks


# --------------------------------------------------------------------------------------
# Time to contact
# --------------------------------------------------------------------------------------
def test_ttc_plot_draws_the_true_time_to_contact(scenario: Any, scenario_data: PlotData) -> None:
    (truth,) = scenario_data.truth
    assert truth.ttc_s is not None
    # The truth TTC the evaluation scores with (one rule: Truth.ttc_s), row for row.
    expected = scenario.truth.ttc_s(scenario.frame_times_us)
    rows = np.nonzero(scenario.truth.object_id == truth.object_id)[0]
    rows = rows[np.argsort(scenario.truth.frame[rows])]
    np.testing.assert_allclose(truth.ttc_s, expected[rows], rtol=1e-4, equal_nan=True)
    np.testing.assert_array_equal(truth.ttc_s, expected[rows])
    assert np.isfinite(truth.ttc_s).sum() > 10

    fig = build_figures(scenario_data)[0]["ttc"]
    (line,) = [ln for ln in fig.axes[0].get_lines() if _label(ln).startswith("truth")]
    assert _label(line).startswith(f"truth: object {truth.object_id}")
    np.testing.assert_array_equal(line.get_ydata(), truth.ttc_s)
    np.testing.assert_array_equal(line.get_xdata(), truth.t_s)
    legend_text = [t.get_text() for leg in figure_legends(fig) for t in leg.get_texts()]
    assert _label(line) in legend_text

    # A log has no truth: no truth line.
    fig = build_figures(_log_like(scenario_data))[0]["ttc"]
    assert not [ln for ln in fig.axes[0].get_lines() if _label(ln).startswith("truth")]


def test_ttc_plot_drawn_from_truth_alone(scenario_data: PlotData) -> None:
    """The estimator never gave a TTC, but the truth closes: the plot shows the truth."""
    results = [
        {**d, "objects": [{**o, "ttc_s": None, "collision_course": False} for o in d["objects"]]}
        for d in scenario_data.results
    ]
    data = PlotData(source="x", results=results, truth=scenario_data.truth)
    figures, skipped = build_figures(data)
    assert "ttc" in figures and "ttc" not in skipped
    labels = [_label(ln) for ln in figures["ttc"].axes[0].get_lines()]
    assert any(lbl.startswith("truth") for lbl in labels)
