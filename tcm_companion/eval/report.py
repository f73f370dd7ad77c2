"""Tables and plots of an evaluation (the paper's Tables 2–3 and Figs. 4, 8, 10)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.classify import ClassifierConfig
from ..io.scoring import after_warmup
from .evaluate import MethodSummary, ObjectFrame, ScenarioEval, summarize
from .metrics import roc, separation

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def _pct(x: float) -> str:
    return "   -  " if not math.isfinite(x) else f"{100 * x:5.1f}%"


def _num(x: float, fmt: str = "6.3f") -> str:
    return "     -" if not math.isfinite(x) else format(x, fmt)


def per_scenario_table(evals: Sequence[ScenarioEval], cls: ClassifierConfig) -> str:
    """One row per scenario and resolution: accuracy of each method at its configured
    threshold, TCM coverage and disparity, measurement errors against truth."""
    lines = [
        "scenario      resolution  frames  TCM acc  ECM acc  BSM acc  fused    coverage  "
        "mean δ ± sd     bearing err  radius err  false tracks",
    ]
    for ev in evals:
        summ = {s.method: s for s in summarize(ev.records, cls)}

        def acc(method: str, summ: dict[str, MethodSummary] = summ) -> str:
            m = summ.get(method)
            return _pct(m.accuracy if m else math.nan)

        tcm = summ.get("tcm")
        after = [r for r in after_warmup(ev.records, cls) if r.state != "unknown"]
        d = np.array([r.disparity for r in after], dtype=np.float64)
        berr = np.array([r.bearing_error_rad for r in ev.records if r.matched])
        rerr = np.array([r.radius_error_rel for r in ev.records if r.matched])
        n_frames = len({r.frame for r in ev.records})
        lines.append(
            f"{ev.name:<13} {ev.resolution[0]:>4}x{ev.resolution[1]:<5} {n_frames:>7}  "
            f"{acc('tcm')}   {acc('ecm')}   {acc('bsm')}   {acc('fused')}   "
            f"{_pct(tcm.coverage if tcm else math.nan)}   "
            f"{_num(float(np.mean(d)) if len(d) else math.nan, '5.3f')} ± "
            f"{_num(float(np.std(d)) if len(d) else math.nan, '5.3f')}   "
            f"{_num(math.degrees(float(np.median(berr))) if len(berr) else math.nan, '6.2f')}°     "
            f"{_num(100 * float(np.median(np.abs(rerr))) if len(rerr) else math.nan, '5.1f')}%   "
            f"{ev.false_tracks:>6}"
        )
    return "\n".join(lines)


def methods_table(rows: Sequence[tuple[str, list[MethodSummary]]]) -> str:
    """Per method (and group, e.g. resolution): the paper's Table 3 columns."""
    lines = [
        "group         method  decided  coverage  accuracy@th   TPR     FPR    ROC AUC  best th   best acc",
    ]
    for group, summaries in rows:
        for s in summaries:
            lines.append(
                f"{group:<13} {s.method:<6} {s.n_decided:>8}   {_pct(s.coverage)}    {_pct(s.accuracy)}   "
                f"{_pct(s.tpr)}  {_pct(s.fpr)}   {_num(s.auc, '6.3f')}  {_num(s.best_threshold, '7.3f')}   "
                f"{_pct(s.best_accuracy)}"
            )
    return "\n".join(lines)


def ttc_table(evals: Sequence[ScenarioEval], horizon_s: float = 10.0) -> str:
    """TTC error where the object really approaches within ``horizon_s``, and the
    collision-course flag against the truth's closest approach (precision / recall)."""
    lines = [
        f"scenario      TTC rows (true τ ≤ {horizon_s:g} s)  median |err|  p90 |err|   "
        "collision flag: truth frames  precision  recall",
    ]
    for ev in evals:
        recs = [r for r in ev.records if r.matched]
        ttc = [
            r
            for r in recs
            if math.isfinite(r.ttc_s) and math.isfinite(r.true_ttc_s) and r.true_ttc_s <= horizon_s
        ]
        err = np.array([abs(r.ttc_s - r.true_ttc_s) / r.true_ttc_s for r in ttc])
        flagged = [r for r in recs if r.collision_course]
        true_c = [r for r in recs if r.true_collision_course]
        precision = np.mean([r.true_collision_course for r in flagged]) if flagged else math.nan
        recall = np.mean([r.collision_course for r in true_c]) if true_c else math.nan
        lines.append(
            f"{ev.name:<13} {len(ttc):>25}  {_pct(float(np.median(err)) if len(err) else math.nan)}      "
            f"{_pct(float(np.percentile(err, 90)) if len(err) else math.nan)}   {len(true_c):>28}   "
            f"{_pct(float(precision))}   {_pct(float(recall))}"
        )
    return "\n".join(lines)


DPI = 110


def _figure(width: float, height: float) -> Figure:
    """A matplotlib figure with constrained layout (which makes room for legends outside
    the axes); no pyplot, so no global state and no interactive backend. matplotlib (the
    ``tools`` extra) is imported only to draw."""
    from matplotlib.figure import Figure

    return Figure(figsize=(width, height), dpi=DPI, layout="constrained")


def _save(fig: Figure, path: Path) -> None:
    """Whole or not at all; an earlier PNG of that name is replaced, nothing else is
    (:func:`~tcm_companion.io.outputs.atomic_path`)."""
    from ..io.outputs import PNG_FILE, atomic_path

    with atomic_path(path, kind=PNG_FILE, force=True) as tmp:
        fig.savefig(tmp, dpi=DPI)


#: How each method's ROC curve is drawn, in drawing order, bottom to top: wide, pale
#: lines under narrower dashed ones, each with its own marker (on the curve's own
#: vertices, staggered between methods), so that curves lying on top of each other all
#: stay visible. The data are drawn as they are: no offsets.
ROC_STYLES: dict[str, dict[str, Any]] = {
    "fused": dict(
        color="#9467bd66", lw=7.0, ls="-", marker="o", ms=11, mfc="none", mec="tab:purple"
    ),
    "tcm": dict(color="tab:green", lw=3.2, ls="--", marker="s", ms=7, mfc="none", mew=1.5),
    "ecm": dict(color="tab:blue", lw=1.6, ls="-.", marker="^", ms=6),
    "bsm": dict(color="k", lw=1.2, ls=":", marker="x", ms=6),
}
ROC_ORDER = ("tcm", "ecm", "bsm", "fused")  # legend order


def plot_disparity_over_time(
    evals: Sequence[ScenarioEval], cls: ClassifierConfig, path: Path
) -> None:
    """Fig. 8: TCM disparity against time per scenario, with the threshold."""
    _save(disparity_over_time_figure(evals, cls), path)


def disparity_over_time_figure(evals: Sequence[ScenarioEval], cls: ClassifierConfig) -> Figure:
    """The figure of :func:`plot_disparity_over_time`: one row per scenario, each with its
    legend right of the axes (never over the data); the δ axis shows every value."""
    fig = _figure(10, 0.6 + 2.4 * len(evals))
    axes = fig.subplots(len(evals), 1, sharex=True, squeeze=False)
    for ax, ev in zip(axes[:, 0], evals):
        recs = [r for r in ev.records if r.state != "unknown"]
        top = max(0.6, 3 * cls.tcm_threshold)
        if recs:
            t0 = min(r.t_us for r in ev.records)
            for oid in sorted({r.object_id for r in recs}):
                rr = [r for r in recs if r.object_id == oid]
                t = np.array([(r.t_us - t0) * 1e-6 for r in rr])
                d = np.array([r.disparity for r in rr])
                moving = rr[0].truth_moving
                ax.plot(
                    t,
                    d,
                    ".",
                    ms=2.5,
                    color="tab:green" if moving else "tab:red",
                    label=f"object {oid} ({'moving' if moving else 'static'})",
                )
                if np.isfinite(d).any():
                    top = max(top, 1.05 * float(np.nanmax(d)))
        ax.axhline(cls.tcm_threshold, color="k", lw=1, ls="--", label=f"δ_th = {cls.tcm_threshold}")
        ax.set_ylabel("δ")
        ax.set_ylim(0, top)
        ax.set_title(f"{ev.name} ({ev.resolution[0]}×{ev.resolution[1]})", fontsize=9)
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    axes[-1, 0].set_xlabel("time (s)")
    return fig


def plot_roc(records: Sequence[ObjectFrame], cls: ClassifierConfig, path: Path, title: str) -> None:
    """Fig. 10: ROC curves of TCM, ECM, BSM and fused on pooled records."""
    _save(roc_figure(records, cls, title), path)


def same_curve(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> bool:
    """Do two ROC curves ``(fpr, tpr)`` (monotone paths from (0, 0) to (1, 1)) draw the
    same line? Exact for polylines: both are compared as functions of ``fpr + tpr``,
    which grows along a monotone path, at every vertex of either."""

    def param(fpr: np.ndarray, tpr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        s = np.asarray(fpr, dtype=np.float64) + np.asarray(tpr, dtype=np.float64)
        keep = np.r_[True, np.diff(s) > 1e-12]  # repeated points
        return s[keep], np.asarray(fpr, dtype=np.float64)[keep]

    if not (len(a[0]) and len(b[0])):
        return False
    sa, fa = param(*a)
    sb, fb = param(*b)
    if abs(sa[0] - sb[0]) > 1e-9 or abs(sa[-1] - sb[-1]) > 1e-9:
        return False
    grid = np.union1d(sa, sb)
    return bool(np.allclose(np.interp(grid, sa, fa), np.interp(grid, sb, fb), atol=1e-9))


def roc_figure(records: Sequence[ObjectFrame], cls: ClassifierConfig, title: str) -> Figure:
    """The figure of :func:`plot_roc`. Curves that coincide (e.g. every method at AUC 1)
    all stay visible (:data:`ROC_STYLES`) and the legend, below the axes, says which
    coincide."""
    decided = [r for r in after_warmup(list(records), cls) if r.state != "unknown"]
    truth = np.array([r.truth_moving for r in decided], dtype=bool)
    curves = {}
    for method in ROC_ORDER:
        score = np.array([r.score(method, cls) for r in decided])  # type: ignore[arg-type]
        if not np.any(np.isfinite(score)):
            continue
        curve = roc(truth, score)
        if len(curve.fpr):
            curves[method] = curve
    fig = _figure(5.5, 7.0)
    ax = fig.add_subplot()
    handles = {}
    for k, method in enumerate(m for m in ROC_STYLES if m in curves):
        curve = curves[method]
        same = [
            o.upper()
            for o in ROC_ORDER
            if o != method
            and o in curves
            and same_curve((curve.fpr, curve.tpr), (curves[o].fpr, curves[o].tpr))
        ]
        label = f"{method.upper()} (AUC {curve.auc:.3f})"
        if same:
            label += f", same curve as {' and '.join(same)}"
        (handles[method],) = ax.plot(
            curve.fpr,
            curve.tpr,
            label=label,
            zorder=2 + k,
            markevery=(0.035 * k, 0.14),
            **ROC_STYLES[method],
        )
    (chance,) = ax.plot([0, 1], [0, 1], color="0.7", lw=0.8, zorder=1, label="chance")
    if not curves:
        ax.text(0.5, 0.55, "no ROC: the records hold one class only", ha="center", fontsize=8)
    ax.set_xlim(-0.02, 1.02)  # curves along the axes' edges stay visible
    ax.set_ylim(-0.02, 1.02)
    ax.set_aspect("equal")
    ax.set_xlabel("false positive rate")
    ax.set_ylabel("true positive rate")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    legend = [handles[m] for m in ROC_ORDER if m in handles] + [chance]
    fig.legend(handles=legend, loc="outside lower center", fontsize=8)
    return fig


def separation_by_interval(evals: Sequence[ScenarioEval]) -> dict[int, float]:
    """Fig. 4(b): separation of static and moving disparities per frame interval."""
    pooled: dict[int, list[tuple[bool, float]]] = {}
    for ev in evals:
        for k, vals in ev.interval_disparities.items():
            pooled.setdefault(k, []).extend(vals)
    out = {}
    for k in sorted(pooled):
        arr = pooled[k]
        static = np.array([d for m, d in arr if not m])
        moving = np.array([d for m, d in arr if m])
        out[k] = separation(static, moving)
    return out


def plot_separation(sep: dict[int, float], path: Path) -> None:
    """Fig. 4(b): separation of static and moving disparities against frame interval."""
    _save(separation_figure(sep), path)


def separation_figure(sep: dict[int, float]) -> Figure:
    """The figure of :func:`plot_separation` (its legend right of the axes)."""
    ks = np.array(sorted(sep))
    vals = np.array([sep[k] for k in ks])
    fig = _figure(7, 3.5)
    ax = fig.add_subplot()
    ax.plot(ks, vals, "o-", ms=3, label="separation")
    ok = np.isfinite(vals)
    if ok.sum() >= 4:
        coef = np.polyfit(ks[ok], vals[ok], 3)
        xx = np.linspace(ks.min(), ks.max(), 200)
        ax.plot(xx, np.polyval(coef, xx), "--", color="0.4", label="cubic fit")
        fig.legend(loc="outside right upper", fontsize=8)
    ax.axhline(0, color="0.7", lw=0.8)
    ax.set_xlabel("frame interval k")
    ax.set_ylabel("separation (μm−σm)−(μs+σs)")
    return fig
