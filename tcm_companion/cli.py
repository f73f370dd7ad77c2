"""Command line: ``tcm-companion <command>``.

Commands: ``run`` (the flight daemon), ``sitl`` (mock autopilot + simulated camera +
daemon), ``config check``, ``demo`` (simulate the paper's flights and print the
evaluation), ``replay``, ``eval``, ``bench``, ``mock-autopilot``, ``sim export`` and
``sim list``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from . import __version__
from .config import AppConfig, ConfigError, load_config
from .core.classify import METHODS

DEFAULT_CONFIG = Path("config.toml")


def _config(path: str | None) -> AppConfig:
    if path is not None:
        return load_config(path)
    return load_config(DEFAULT_CONFIG) if DEFAULT_CONFIG.is_file() else AppConfig()


def _resolution(text: str) -> tuple[int, int]:
    try:
        w, h = text.lower().split("x")
        size = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"resolution must look like 360x220, got {text!r}"
        ) from None
    if min(size) <= 0:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    return size


def _progress(total: int, desc: str, enabled: bool) -> Any:
    from tqdm import tqdm

    return tqdm(
        total=total, desc=desc, unit="frame", disable=not enabled, leave=False, file=sys.stderr
    )


# -- replay ------------------------------------------------------------------------------
def _is_log(path: str) -> bool:
    p = Path(path)
    return p.suffix == ".mcap" or (p.is_dir() and any(p.glob("tcm-*.mcap")))


def cmd_replay_log(args: argparse.Namespace) -> int:
    """A flight log: recompute every processed frame and compare with what was logged."""
    from .io.outputs import atomic_text
    from .io.results import ResultsWriter
    from .replay_log import compare, replay_log

    rows = mismatched = frames = 0
    diffs: list[str] = []
    with atomic_text(args.results, force=args.force) as fh:
        writer = ResultsWriter(fh)
        for frame in replay_log(args.scenario, args.camera_id):
            writer.write(frame.result)
            frames += 1
            d = compare(frame)
            if d:
                mismatched += 1
                diffs.extend(d)
        rows = writer.rows
    print(
        f"{args.scenario}: {frames} frames replayed, {rows} rows -> {args.results}; "
        f"{frames - mismatched} identical to the flight, {mismatched} differ"
    )
    for line in diffs[:20]:
        print(f"  {line}")
    return 1 if (args.check and mismatched) else 0


class _TolerantFrames:
    """A scenario whose unreadable frames are reported and replayed as ``None`` (the
    pipeline counts them as bad frames) instead of ending the replay."""

    def __init__(self, scenario: Any) -> None:
        self._inner = scenario
        self.unreadable: list[tuple[int, str]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def iter_frames(self) -> Any:
        return self._inner.iter_frames_tolerant(lambda i, why: self.unreadable.append((i, why)))


def _unknown_rows(previous: Any, frame_index: int, t_us: int) -> Any:
    """The objects of the last good frame, as ``unknown`` rows of an unreadable frame."""
    import dataclasses
    import math

    from .core.classify import unknown
    from .core.pipeline import FrameResult

    why = "unreadable frame"
    objects = tuple(
        dataclasses.replace(
            o,
            detected=False,
            state="unknown",
            reason=why,
            classification=unknown(why),
            ttc_s=math.nan,
            collision_course=False,
        )
        for o in (previous.objects if previous is not None else ())
    )
    return FrameResult(frame_index, t_us, objects, False, None, {})


def cmd_replay(args: argparse.Namespace) -> int:
    from .io.outputs import atomic_text
    from .io.results import ResultsWriter
    from .io.scenario import load_scenario
    from .replay import run_replay, with_method

    if _is_log(args.scenario):
        return cmd_replay_log(args)
    config = with_method(_config(args.config), args.method, bsm=args.method == "bsm")
    scenario = _TolerantFrames(load_scenario(args.scenario))
    for w in scenario.warnings:
        print(f"warning: {w}", file=sys.stderr)
    states: dict[str, int] = {}
    previous = None
    reported = 0
    with (
        atomic_text(args.results, force=args.force) as fh,
        _progress(scenario.n_frames, scenario.name, not args.quiet) as bar,
    ):
        writer = ResultsWriter(fh)
        for result in run_replay(scenario, config):
            if len(scenario.unreadable) > reported:  # this frame could not be read
                reported = len(scenario.unreadable)
                result = _unknown_rows(previous, result.frame_index, result.t_us)
            else:
                previous = result
            writer.write(result)
            for o in result.objects:
                states[o.state] = states.get(o.state, 0) + 1
            bar.update(1)
    for i, why in scenario.unreadable[:10]:
        print(f"warning: frame {i} skipped: {why}", file=sys.stderr)
    if len(scenario.unreadable) > 10:
        print(f"warning: ... {len(scenario.unreadable) - 10} more", file=sys.stderr)
    summary = ", ".join(f"{n} {s}" for s, n in sorted(states.items())) or "no objects"
    skipped = (
        f"; {len(scenario.unreadable)} unreadable frame(s) skipped" if scenario.unreadable else ""
    )
    print(
        f"{scenario.name}: {scenario.n_frames} frames, {writer.rows} rows ({summary})"
        f"{skipped} -> {args.results}"
    )
    return 0


# -- eval ----------------------------------------------------------------------------------
def _scenarios(args: argparse.Namespace) -> list[Any]:
    from .io.scenario import load_scenario

    out: list[Any] = [load_scenario(p) for p in args.scenarios]
    if args.sim:
        from .sim import make_scenario

        camera = None
        for name in args.sim:
            if args.camera is not None:
                from .sim.cameras import preset_camera

                camera = preset_camera(args.camera, None, name)
            out.append(make_scenario(name, camera=camera, duration_s=args.duration, seed=args.seed))
    if not out:
        raise SystemExit("eval: give scenario directories and/or --sim NAME ...")
    return out


def run_evaluation(
    scenarios: Sequence[Any],
    config: AppConfig,
    resolutions: Sequence[tuple[int, int] | None],
    out_dir: Path | None,
    intervals: tuple[int, ...] = (),
    with_bsm: bool = True,
    progress: bool = True,
) -> str:
    """Evaluate scenarios at each resolution; return the printable report (and write plots)."""
    from .eval.evaluate import at_resolution, evaluate_scenario, summarize
    from .eval.report import (
        methods_table,
        per_scenario_table,
        plot_disparity_over_time,
        plot_roc,
        plot_separation,
        separation_by_interval,
        ttc_table,
    )

    cls = config.pipeline.classifier
    evals = []
    groups = []
    for res in resolutions:
        group_evals = []
        for sc in scenarios:
            src = sc if res is None else at_resolution(sc, *res)
            with _progress(
                src.n_frames, f"{sc.name} {src.camera.width}x{src.camera.height}", progress
            ) as bar:
                ev = evaluate_scenario(
                    src,
                    config,
                    with_bsm=with_bsm,
                    intervals=intervals,
                    on_frame=lambda _r: bar.update(1),
                )
            group_evals.append(ev)
        evals.extend(group_evals)
        records = [r for ev in group_evals for r in ev.records]
        label = "native" if res is None else f"{res[0]}x{res[1]}"
        groups.append((label, summarize(records, cls)))
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
            plot_roc(records, cls, out_dir / f"roc_{label}.png", f"ROC, pooled scenarios, {label}")
            plot_disparity_over_time(group_evals, cls, out_dir / f"disparity_{label}.png")
    parts = [
        "Per scenario (TCM at the configured threshold):",
        per_scenario_table(evals, cls),
        "",
        "Per method, static and moving flights pooled (paper Tables 2-3, Fig. 10):",
        methods_table(groups),
    ]
    ttc = ttc_table(evals)
    if ttc.count("\n"):
        parts += ["", "Time to contact (rows where both estimate and truth exist):", ttc]
    if intervals:
        sep = separation_by_interval(evals)
        parts += ["", "Separation by frame interval (paper Fig. 4):"]
        parts += [f"  k={k:>2}  separation {v:+.3f}" for k, v in sep.items()]
        if out_dir is not None:
            plot_separation(sep, out_dir / "separation.png")
    if out_dir is not None:
        parts += ["", f"plots written to {out_dir}/"]
    return "\n".join(parts)


def cmd_eval(args: argparse.Namespace) -> int:
    config = _config(args.config)
    scenarios = _scenarios(args)
    resolutions: list[tuple[int, int] | None] = (
        list(args.resolutions) if args.resolutions else [None]
    )
    intervals = tuple(range(1, 41)) if args.intervals else ()
    out = Path(args.out) if args.out else None
    report = run_evaluation(
        scenarios,
        config,
        resolutions,
        out,
        intervals,
        with_bsm=not args.no_bsm,
        progress=not args.quiet,
    )
    print(report)
    if out is not None:
        (out / "report.txt").write_text(report + "\n")
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    """The default job: the paper's three flights, simulated, evaluated."""
    from .sim import make_scenario

    config = _config(args.config)
    print("Simulating the paper's flights TS, T45, T90 (360x220 panorama) and evaluating TCM,")
    print("ECM, BSM and fused TCM+ECM on them...", flush=True)
    scenarios = [
        make_scenario(n, duration_s=args.duration, seed=args.seed) for n in ("TS", "T45", "T90")
    ]
    out = Path(args.out)
    print(run_evaluation(scenarios, config, [None], out, progress=not args.quiet))
    return 0


# -- bench ---------------------------------------------------------------------------------
def cmd_bench(args: argparse.Namespace) -> int:
    from .bench import run_bench, run_mavlink_bench

    if args.mavlink:
        print(run_mavlink_bench())
        return 0
    if args.daemon:
        from .service.daemon_bench import print_daemon_bench, run_daemon_bench

        print_daemon_bench(run_daemon_bench(args.duration))
        return 0
    print(
        run_bench(_config(args.config), args.resolutions or [(360, 220), (900, 550)], args.frames)
    )
    return 0


# -- logs ----------------------------------------------------------------------------------
def cmd_export(args: argparse.Namespace) -> int:
    from .io.outputs import atomic_path
    from .logtools.convert import log_to_scenario

    with atomic_path(args.scenario, force=args.force, is_dir=True) as tmp:
        log_to_scenario(args.log, tmp, camera_id=args.camera_id)
    print(f"{args.log} -> {args.scenario}")
    return 0


def cmd_import(args: argparse.Namespace) -> int:
    from .io.outputs import atomic_path
    from .logtools.convert import scenario_to_log

    with atomic_path(args.log, force=args.force) as tmp:
        scenario_to_log(args.scenario, tmp, image_format=args.image_format, results=args.results)
    print(f"{args.scenario} -> {args.log}")
    return 0


def cmd_plot(args: argparse.Namespace) -> int:
    from .logtools.plot import plot_log, plot_scenario

    paths = (
        plot_log(args.source, args.out)
        if _is_log(args.source)
        else plot_scenario(args.source, args.out)
    )
    for p in paths:
        print(p)
    for name, why in getattr(paths, "skipped", {}).items():
        print(f"skipped {name}: {why}", file=sys.stderr)
    return 0


# -- sim -----------------------------------------------------------------------------------
def _camera_arg(args: argparse.Namespace) -> Any:
    if args.camera is None:
        return None
    from .sim.cameras import preset_camera

    return preset_camera(args.camera, args.resolution, args.name)


def cmd_sim_export(args: argparse.Namespace) -> int:
    from .sim import make_scenario
    from .sim.export import export_scenario

    camera = _camera_arg(args)
    sim = make_scenario(args.name, camera=camera, duration_s=args.duration, seed=args.seed)
    if camera is None and args.resolution is not None:
        sim = make_scenario(
            args.name,
            camera=sim.camera.scaled(*args.resolution),
            duration_s=args.duration,
            seed=args.seed,
        )
    from .io.outputs import atomic_path

    with atomic_path(args.dir, force=args.force, is_dir=True) as tmp:
        export_scenario(sim, tmp, detections=args.detections or None)
    print(
        f"wrote {sim.name}: {sim.n_frames} frames, {sim.camera.model_name} "
        f"{sim.camera.width}x{sim.camera.height} -> {args.dir}"
    )
    return 0


def cmd_sim_list(_args: argparse.Namespace) -> int:
    from .sim.scenarios import SCENARIO_NAMES, describe_scenario

    for name in SCENARIO_NAMES:
        print(f"{name:<15} {describe_scenario(name)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tcm-companion",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=__version__)
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--config", help="config.toml (default: ./config.toml if present, else built-in)"
        )
        p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")

    p = sub.add_parser(
        "demo",
        help="simulate TS/T45/T90 and print the paper's evaluation (make demo; about 9 minutes)",
    )
    common(p)
    p.add_argument(
        "--duration", type=float, default=None, help="seconds per flight (default: scenario's)"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="out/demo", help="folder for plots (default out/demo)")
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser(
        "replay", help="run a tcm-scenario/1 directory or a flight log (.mcap) through the core"
    )
    common(p)
    p.add_argument("scenario", help="scenario directory, or a flight log file / log directory")
    p.add_argument(
        "--check",
        action="store_true",
        help="flight log: exit 1 unless every replayed frame equals the logged one",
    )
    p.add_argument("--camera-id", type=int, default=0, help="flight log: which camera")
    p.add_argument("--results", required=True, help="results CSV to write")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the output if it exists (it is written beside it and renamed into place when complete)",
    )
    p.add_argument(
        "--method", choices=METHODS, default=None, help="decision method (default: config)"
    )
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("eval", help="accuracy, coverage, ROC of TCM/ECM/BSM/fused against truth")
    common(p)
    p.add_argument("scenarios", nargs="*", help="scenario directories (with truth.csv)")
    p.add_argument("--sim", nargs="+", metavar="NAME", help="also simulate these scenarios")
    p.add_argument(
        "--camera",
        choices=("panorama", "pinhole", "fisheye"),
        default=None,
        help="camera for --sim scenarios (default: the paper's panorama)",
    )
    p.add_argument("--duration", type=float, default=None)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--resolutions",
        type=_resolution,
        nargs="+",
        metavar="WxH",
        help="evaluate at these image sizes (same field of view)",
    )
    p.add_argument(
        "--intervals", action="store_true", help="separation study over frame intervals 1..40"
    )
    p.add_argument(
        "--no-bsm", action="store_true", help="skip the (slow) background subtraction baseline"
    )
    p.add_argument("--out", help="folder for plots and report.txt")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("bench", help="per-stage time per frame, one core")
    common(p)
    p.add_argument("--resolutions", type=_resolution, nargs="+", metavar="WxH")
    p.add_argument("--frames", type=int, default=200, help="frames timed per resolution and method")
    p.add_argument(
        "--mavlink",
        action="store_true",
        help="instead: MAVLink encode cost and link latency (pty via socat, UDP)",
    )
    p.add_argument(
        "--daemon",
        action="store_true",
        help="instead: the running service's latency, CPU and memory (own process, 25 Hz)",
    )
    p.add_argument(
        "--duration", type=float, default=60.0, help="--daemon: seconds to run (default 60)"
    )
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser(
        "mock-autopilot", help="a MAVLink vehicle (ArduPilot-like) that flies a simulated scenario"
    )
    from .sim.mock_autopilot_run import add_arguments as mock_autopilot_arguments
    from .sim.mock_autopilot_run import run_from_args as run_mock_autopilot

    mock_autopilot_arguments(p)
    p.set_defaults(func=run_mock_autopilot)

    from .service.cli import add_parsers as service_parsers

    service_parsers(sub)

    p = sub.add_parser("export", help="flight log -> tcm-scenario/1 (frames + .tlog)")
    p.add_argument("log", help="flight log file or directory")
    p.add_argument("--scenario", required=True, metavar="DIR", help="scenario directory to write")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the output if it exists (it is written beside it and renamed into place when complete)",
    )
    p.add_argument("--camera-id", type=int, default=0)
    p.set_defaults(func=cmd_export)

    p = sub.add_parser("import", help="tcm-scenario/1 -> flight log (.mcap)")
    p.add_argument("scenario", help="scenario directory")
    p.add_argument("--log", required=True, metavar="FILE", help="MCAP file to write")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace the output if it exists (it is written beside it and renamed into place when complete)",
    )
    p.add_argument("--image-format", choices=("png", "jpeg"), default="png")
    p.add_argument(
        "--results",
        action="store_true",
        help="also replay the scenario and log /tcm/result (for plots and the Foxglove layout)",
    )
    p.set_defaults(func=cmd_import)

    p = sub.add_parser("plot", help="PNG plots of a flight log or a scenario")
    p.add_argument("source", help="flight log (file or directory) or scenario directory")
    p.add_argument("--out", default="out/plots", help="folder for the PNGs (default out/plots)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser("sim", help="the built-in simulator")
    ssub = p.add_subparsers(dest="sim_command", required=True)
    e = ssub.add_parser("export", help="write a simulated scenario as a tcm-scenario/1 directory")
    e.add_argument("name", help="scenario name (see `sim list`)")
    e.add_argument("dir", help="output directory")
    e.add_argument(
        "--force",
        action="store_true",
        help="replace the output if it exists (it is written beside it and renamed into place when complete)",
    )
    e.add_argument(
        "--detections",
        action="store_true",
        help="also write detections.csv: boxes from the simulated detector (jitter, misses,"
        " false boxes; tcm_companion/sim/detector_sim.py)",
    )
    e.add_argument("--camera", choices=("panorama", "pinhole", "fisheye"), default=None)
    e.add_argument("--resolution", type=_resolution, default=None, metavar="WxH")
    e.add_argument("--duration", type=float, default=None)
    e.add_argument("--seed", type=int, default=0)
    e.set_defaults(func=cmd_sim_export)
    ls = ssub.add_parser("list", help="list the simulated scenarios")
    ls.set_defaults(func=cmd_sim_list)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from .io.allocator import tune_allocator

    tune_allocator()
    try:
        return int(args.func(args))
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        return 2
    except (ValueError, OSError) as exc:
        from .io.scenario import ScenarioError
        from .logtools.convert import LogConversionError
        from .replay_log import LogReplayError

        if isinstance(exc, ScenarioError | OSError | LogConversionError | LogReplayError):
            print(f"error: {exc}", file=sys.stderr)
            return 2
        raise
