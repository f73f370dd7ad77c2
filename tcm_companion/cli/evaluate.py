"""``tcm-companion eval`` and ``demo``: TCM, ECM, BSM and the fused decision scored
against the truth of recorded or simulated scenarios."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..sim.scene.names import SCENARIO_NAMES
from .common import (
    CAMERA_PRESETS,
    SEED_RANGE,
    TOOLS_HINT,
    TolerantFrames,
    add_command,
    add_config_arguments,
    add_quiet_argument,
    config_file,
    config_from_args,
    flight_seconds,
    progress,
    require_inputs,
    resolution,
    whole_number,
)
from .sim import RIG_CHOICES

if TYPE_CHECKING:
    from ..config import AppConfig

#: The first line of report.txt (how an earlier report is recognised, to be replaced).
REPORT_FIRST_LINE = "Per scenario (TCM at the configured threshold):"

#: Where ``eval`` writes its plots and report.txt without ``--out``.
DEFAULT_EVAL_OUT = "out/eval"
#: ... and ``demo``.
DEFAULT_DEMO_OUT = "out/demo"


def _is_rig(sc: Any) -> bool:
    """A camera rig (a rig scenario or a simulated rig): it has ``camera_names``."""
    return hasattr(sc, "camera_names") and hasattr(sc, "cameras")


def _scenarios(args: argparse.Namespace, config: AppConfig) -> list[Any]:
    from ..io.scenario import load_any

    out: list[Any] = [load_any(p) for p in args.scenarios]
    for sc in out:  # all of them before evaluating any
        for cam in sc.cameras if _is_rig(sc) else [sc]:
            require_inputs(cam, config, truth=True)
    rig_name = getattr(args, "rig", None)
    if args.sim and rig_name is not None:
        from ..sim.scene.rig_scenario import make_rig

        for name in args.sim:
            rig = make_rig(
                name, rig_name, duration_s=args.duration, seed=args.seed, shorter_ok=True
            )
            out.append(rig)
    elif args.sim:
        from ..sim import make_scenario

        camera = None
        for name in args.sim:
            if args.camera is not None:
                from ..sim.scene.cameras import preset_camera

                camera = preset_camera(args.camera, None, name)
            sim = make_scenario(
                name, camera=camera, duration_s=args.duration, seed=args.seed, shorter_ok=True
            )
            if args.duration is not None and sim.plan.duration_s < args.duration:
                # one --duration over several flights: a collision or head-on course
                # ends before contact, so it keeps its own length and says so
                print(
                    f"eval: {sim.name} lasts {sim.plan.duration_s:.2f} s, not the "
                    f"--duration {args.duration:g} asked (the flight ends before contact)",
                    file=sys.stderr,
                )
            out.append(sim)
    if not out:
        raise SystemExit("eval: give scenario directories and/or --sim NAME ...")
    return out


def _no_decision(records: Sequence[Any], cls: Any) -> str | None:
    """Why nothing can be scored in ``records`` ("no decision ..."), None when something
    was decided after the warm-up."""
    from ..io.scoring import after_warmup

    after = after_warmup(list(records), cls)
    if any(r.state != "unknown" for r in after):
        return None
    if not after:
        return f"no decision: no object-frame after the {cls.interval_s:g} s warm-up"
    return f"no decision: none of the {len(after)} object-frames after the warm-up was decided"


class _FrameCounter:
    """``evaluate_scenario``'s ``on_frame``: advances the progress bar and counts the
    frames the pipeline had no attitude for (telemetry that does not cover them); not
    those it could not read (``unreadable``: their ``(index, why)``, reported apart)."""

    def __init__(self, bar: Any, unreadable: Sequence[tuple[int, str]] = ()) -> None:
        self.bar = bar
        self.no_attitude = 0
        self._unreadable = unreadable

    def __call__(self, result: Any) -> None:
        skipped = self._unreadable and self._unreadable[-1][0] == result.frame_index
        if not result.attitude_ok and not skipped:
            self.no_attitude += 1
        self.bar.update(1)


def _report_kind() -> Any:
    """report.txt: recognised by its first line."""
    from ..io.outputs import OutputKind, text_starting

    return OutputKind("eval report", text_starting(REPORT_FIRST_LINE))


def _label(res: tuple[int, int] | None) -> str:
    return "native" if res is None else f"{res[0]}x{res[1]}"


def check_out_dir(
    out: Path,
    inputs: Sequence[str | None],
    resolutions: Sequence[tuple[int, int] | None],
    intervals: bool = False,
    report: bool = False,
) -> None:
    """Before any work: ``out`` is not, does not lie inside and does not contain an input,
    and the files the evaluation will write there (plots, report.txt) are, if present,
    ones it wrote (else :class:`~tcm_companion.io.outputs.OutputRefused`)."""
    from ..io.outputs import PNG_FILE, check_folder

    files = [
        (f"{kind}_{_label(r)}.png", PNG_FILE) for r in resolutions for kind in ("roc", "disparity")
    ]
    if intervals:
        files.append(("separation.png", PNG_FILE))
    if report:
        files.append(("report.txt", _report_kind()))
    check_folder(out, inputs=inputs, files=files)


def run_evaluation(
    scenarios: Sequence[Any],
    config: AppConfig,
    resolutions: Sequence[tuple[int, int] | None],
    out_dir: Path | None,
    intervals: tuple[int, ...] = (),
    with_bsm: bool = True,
    progress_bars: bool = True,
) -> str:
    """Evaluate scenarios at each resolution; return the printable report (and write plots
    into ``out_dir`` unless it is None, or matplotlib, of the ``tools`` extra, is missing).

    What makes the scores partial is printed on stderr as it is found (``warning: ...``,
    as ``replay`` does) and repeated at the end of the report: the readers' warnings about
    a scenario (a ``.tlog`` cut short or with junk appended), frames the telemetry's
    attitude does not cover, and a scenario or group that decided nothing."""
    import importlib.util

    from ..eval.evaluate import at_resolution, evaluate_scenario, summarize

    no_plots = ""
    if out_dir is not None and importlib.util.find_spec("matplotlib") is None:
        no_plots = f"no plots in {out_dir}/: {TOOLS_HINT}"
        out_dir = None
    from ..eval.report import (
        methods_table,
        per_scenario_table,
        plot_disparity_over_time,
        plot_roc,
        plot_separation,
        separation_by_interval,
        ttc_table,
    )

    warnings: list[str] = []

    def warn(text: str) -> None:
        warnings.append(text)
        print(f"warning: {text}", file=sys.stderr, flush=True)

    for sc in scenarios:
        for w in getattr(sc, "warnings", ()):
            warn(f"{sc.name}: {w}")

    cls = config.pipeline.classifier
    evals = []
    groups = []
    no_decision: list[str] = []
    rig_evals: list[Any] = []
    for res in resolutions:
        group_evals = []
        for sc in scenarios:
            if _is_rig(sc):
                rev = _evaluate_rig(sc, config, res, with_bsm, progress_bars, warn)
                rig_evals.append(rev)
                evals.extend(rev.cameras)
                why = _no_decision(rev.overall.records, cls)
                if why is not None:
                    no_decision.append(f"{rev.overall.name} {_label(res)}: {why}")
                group_evals.append(rev.overall)
                continue
            # An unreadable frame is skipped and reported, as replay and plot do (its truth
            # objects count as undecided), not the end of the evaluation.
            base = TolerantFrames(sc) if hasattr(sc, "iter_frames_tolerant") else sc
            src = base if res is None else at_resolution(base, *res)
            size = f"{src.camera.width}x{src.camera.height}"
            with progress(src.n_frames, f"{sc.name} {size}", progress_bars) as bar:
                counter = _FrameCounter(bar, getattr(base, "unreadable", []))
                ev = evaluate_scenario(
                    src, config, with_bsm=with_bsm, intervals=intervals, on_frame=counter
                )
            unreadable = getattr(base, "unreadable", [])
            if unreadable:
                first = "; ".join(why for _, why in unreadable[:3])
                more = f" and {len(unreadable) - 3} more" if len(unreadable) > 3 else ""
                warn(
                    f"{sc.name} {size}: {len(unreadable)} unreadable frame(s) skipped"
                    f" ({first}{more}): their objects count as undecided"
                )
            if counter.no_attitude:
                warn(
                    f"{sc.name} {size}: {counter.no_attitude} of {src.n_frames} frames have no"
                    " attitude (the telemetry does not cover them): their objects are not"
                    " decided, which lowers the coverage"
                )
            why = _no_decision(ev.records, cls)
            if why is not None:
                no_decision.append(f"{sc.name} {size}: {why}")
            group_evals.append(ev)
        evals.extend(group_evals)
        records = [r for ev in group_evals for r in ev.records]
        label = _label(res)
        groups.append((label, summarize(records, cls)))
        if len(group_evals) > 1:
            why = _no_decision(records, cls)
            if why is not None:
                no_decision.append(f"{label}, pooled: {why}")
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
            plot_roc(records, cls, out_dir / f"roc_{label}.png", f"ROC, pooled scenarios, {label}")
            plot_disparity_over_time(group_evals, cls, out_dir / f"disparity_{label}.png")
    parts = [
        REPORT_FIRST_LINE,
        per_scenario_table(evals, cls),
        "",
        "Per method, static and moving flights pooled (paper Tables 2-3, Fig. 10):",
        methods_table(groups),
    ]
    parts += [f"  {line}" for line in no_decision]
    if rig_evals:
        from ..eval.rig import handover_text

        parts += [
            "",
            "Camera rigs: handover (truth objects measured by two cameras or more, distinct"
            " track ids each; target 1):",
            *handover_text(rig_evals),
        ]
    ttc = ttc_table([ev for ev in evals if not _is_rig_camera(ev, rig_evals)])
    if ttc.count("\n"):
        parts += ["", "Time to contact (rows where both estimate and truth exist):", ttc]
    if intervals:
        sep = separation_by_interval(evals)
        parts += ["", "Separation by frame interval (paper Fig. 4):"]
        parts += [f"  k={k:>2}  separation {v:+.3f}" for k, v in sep.items()]
        if rig_evals:
            parts += ["  (camera rigs are left out of this study: one camera's pipeline each)"]
        if out_dir is not None:
            plot_separation(sep, out_dir / "separation.png")
    if warnings:
        parts += ["", "Warnings (also on stderr; the scores cover what was usable):"]
        parts += [f"  {w}" for w in warnings]
    if out_dir is not None:
        parts += ["", f"plots written to {out_dir}/"]
    elif no_plots:
        parts += ["", no_plots]
    return "\n".join(parts)


def _is_rig_camera(ev: Any, rig_evals: Sequence[Any]) -> bool:
    """A rig's per-camera evaluation (its overall one is scored in the pooled tables)."""
    return any(ev is c for r in rig_evals for c in r.cameras)


def _rig_at_resolution(rig: Any, res: tuple[int, int] | None) -> Any:
    """The rig with each camera at ``res`` (re-rendered if simulated, else resized)."""
    if res is None:
        return rig
    import copy

    from ..eval.evaluate import at_resolution

    out = copy.copy(rig)
    out.cameras = []
    for cam in rig.cameras:
        scaled = at_resolution(cam, *res)
        if scaled is not cam and hasattr(scaled, "plan"):
            scaled.name = cam.name  # a re-rendered camera is named after its flight
            scaled.telemetry = rig.telemetry
        out.cameras.append(scaled)
    return out


def _evaluate_rig(
    rig: Any,
    config: AppConfig,
    res: tuple[int, int] | None,
    with_bsm: bool,
    progress_bars: bool,
    warn: Any,
) -> Any:
    """One rig evaluated at one resolution (:func:`tcm_companion.eval.rig.evaluate_rig`):
    its per-camera and overall evaluations are named ``"<rig>/<camera>"`` and
    ``"<rig>/all"``; what made them partial is warned about as for one camera."""
    from ..eval.rig import evaluate_rig

    base = _rig_at_resolution(rig, res)
    cams = [TolerantFrames(c) if hasattr(c, "iter_frames_tolerant") else c for c in base.cameras]
    import copy

    tolerant = copy.copy(base)
    tolerant.cameras = cams
    n = sum(c.n_frames for c in cams)
    with progress(n, f"{rig.name} rig {_label(res)}", progress_bars) as bar:
        rev = evaluate_rig(tolerant, config, with_bsm=with_bsm, on_frame=lambda k, r: bar.update(1))
    for name, c, missing in zip(rev.camera_names, cams, rev.no_attitude):
        unreadable = getattr(c, "unreadable", [])
        if unreadable:
            warn(
                f"{rig.name}/{name}: {len(unreadable)} unreadable frame(s) skipped: their"
                " objects count as undecided"
            )
        if missing:
            warn(
                f"{rig.name}/{name}: {missing} of {c.n_frames} frames have no attitude (the"
                " telemetry does not cover them): they are not scored"
            )
    return rev


def cmd_eval(args: argparse.Namespace) -> int:
    if args.rig is not None and (not args.sim or args.camera is not None):
        why = "give --camera or --rig, not both" if args.sim else "it needs --sim NAME ..."
        print(f"tcm-companion eval: error: argument --rig: {why}", file=sys.stderr)
        return 2
    config = config_from_args(args)
    resolutions: list[tuple[int, int] | None] = (
        list(args.resolutions) if args.resolutions else [None]
    )
    intervals = tuple(range(1, 41)) if args.intervals else ()
    out = Path(args.out)
    inputs = [*args.scenarios, config_file(args)]
    check_out_dir(out, inputs, resolutions, bool(intervals), report=True)
    scenarios = _scenarios(args, config)
    report = run_evaluation(
        scenarios,
        config,
        resolutions,
        out,
        intervals,
        with_bsm=not args.no_bsm,
        progress_bars=not args.quiet,
    )
    from ..io.outputs import atomic_text

    with atomic_text(out / "report.txt", kind=_report_kind(), force=True, inputs=inputs) as fh:
        fh.write(report + "\n")
    print(report)
    print(f"report written to {out / 'report.txt'}")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """The default job: the paper's three flights, simulated, evaluated."""
    from ..sim import make_scenario

    config = config_from_args(args)
    out = Path(args.out)
    check_out_dir(out, [config_file(args)], [None])
    print("Simulating the paper's flights TS, T45, T90 (360x220 panorama) and evaluating TCM,")
    print("ECM, BSM and fused TCM+ECM on them...", flush=True)
    scenarios = [
        make_scenario(n, duration_s=args.duration, seed=args.seed) for n in ("TS", "T45", "T90")
    ]
    print(run_evaluation(scenarios, config, [None], out, progress_bars=not args.quiet))
    return 0


def add_parsers(sub: Any) -> None:
    p = add_command(
        sub,
        "eval",
        "Score scenarios that have truth.csv: per scenario and pooled, per method (TCM, ECM,"
        " BSM, fused), accuracy at the configured threshold, coverage, ROC area and the"
        " accuracy-optimal threshold, at each resolution asked; PNG plots and report.txt in"
        f" --out (default {DEFAULT_EVAL_OUT}).",
    )
    add_config_arguments(p)
    add_quiet_argument(p)
    p.add_argument("scenarios", nargs="*", help="scenario directories (with truth.csv)")
    p.add_argument(
        "--sim",
        nargs="+",
        metavar="NAME",
        type=str.upper,
        choices=SCENARIO_NAMES,
        help="also simulate these scenarios (see: tcm-companion sim list)",
    )
    p.add_argument(
        "--camera",
        choices=CAMERA_PRESETS,
        default=None,
        help="camera for --sim scenarios (default: the paper's panorama)",
    )
    p.add_argument(
        "--rig",
        choices=RIG_CHOICES,
        default=None,
        help="see each --sim flight through this camera rig (quad: four 100° pinholes,"
        " front-back: two) and score it per camera, overall and for handover",
    )
    p.add_argument(
        "--duration",
        type=flight_seconds,
        default=None,
        metavar="S",
        help="seconds of each --sim flight, at most 3600 (default: the scenario's)",
    )
    p.add_argument(
        "--seed",
        type=whole_number(*SEED_RANGE),
        default=0,
        metavar="N",
        help="seed of the --sim flights (turbulence, noise), 0 to 4294967295",
    )
    p.add_argument(
        "--resolutions",
        type=resolution,
        nargs="+",
        metavar="WxH",
        help="evaluate at these image sizes (same field of view; 16 to 16384 pixels a side,"
        " at most 4096x4096 pixels; default: the scenario's own)",
    )
    p.add_argument(
        "--intervals", action="store_true", help="separation study over frame intervals 1..40"
    )
    p.add_argument(
        "--no-bsm", action="store_true", help="skip the (slow) background subtraction baseline"
    )
    p.add_argument(
        "--out",
        default=DEFAULT_EVAL_OUT,
        metavar="DIR",
        help=f"folder for the plots and report.txt (default {DEFAULT_EVAL_OUT})",
    )
    p.set_defaults(func=cmd_eval)

    p = add_command(
        sub,
        "demo",
        "Simulate the paper's three flights (TS, T45, T90), evaluate TCM, ECM, BSM and the"
        " fused decision on them at 360x220 and print the tables, with plots in --out (about"
        " 3 minutes of one core, up to 9 on a busy machine).",
    )
    add_config_arguments(p)
    add_quiet_argument(p)
    p.add_argument(
        "--duration",
        type=flight_seconds,
        default=None,
        metavar="S",
        help="seconds per flight, at most 3600 (default: the scenario's)",
    )
    p.add_argument(
        "--seed",
        type=whole_number(*SEED_RANGE),
        default=0,
        metavar="N",
        help="seed of the flights (turbulence, noise), 0 to 4294967295",
    )
    p.add_argument(
        "--out",
        default=DEFAULT_DEMO_OUT,
        metavar="DIR",
        help=f"folder for the plots (default {DEFAULT_DEMO_OUT})",
    )
    p.set_defaults(func=cmd_demo)
