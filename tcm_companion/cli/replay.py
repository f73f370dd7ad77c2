"""``tcm-companion replay``: a scenario directory, or a flight log, through the core."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import (
    FLIGHT_HELP,
    FORCE_HELP,
    METHODS,
    TolerantFrames,
    add_command,
    add_config_arguments,
    add_quiet_argument,
    config_file,
    config_from_args,
    is_log,
    non_negative_number,
    progress,
    require_inputs,
    whole_number,
)


def _inputs(args: argparse.Namespace) -> list[str | None]:
    """What replay reads, which --results must not overwrite: the scenario or log, the
    configuration file."""
    return [args.scenario, config_file(args)]


def cmd_replay_log(args: argparse.Namespace) -> int:
    """A flight log: recompute every processed frame and compare with what was logged.

    A truncated or damaged log replays as far as it is readable and says so (stderr, and
    in the summary line); ``--check`` fails on it, as on a frame that differs and on a log
    with no frame to compare. Processed frames the log lacks (dropped by the writer) are
    counted and skipped; the frames after the first of them are replayed but not compared
    (replay.log's docstring), and ``--check`` passes on what it could compare."""
    from ..flightlog.reader import LogReport, read_metadata
    from ..io.outputs import RESULTS_CSV, atomic_text
    from ..io.results import ResultsWriter
    from ..replay.log import ROUNDING_REL_TOL, MissingFrame, compare, log_cameras, replay_log

    rows = mismatched = rounding = beyond = frames = after_gap = after_same = 0
    diffs: list[str] = []
    report = LogReport()
    missing: list[MissingFrame] = []
    with atomic_text(args.results, kind=RESULTS_CSV, force=args.force, inputs=_inputs(args)) as fh:
        # A rig's log (two cameras or more) replays the whole rig; its rows say which
        # camera measured them (the results CSV's camera column).
        names = log_cameras(args.scenario, args.flight)
        writer = ResultsWriter(fh, names if len(names) >= 2 else None)
        for frame in replay_log(args.scenario, args.camera_id, report, args.flight, missing):
            writer.write(frame.result, frame.camera_id)
            frames += 1
            d = compare(frame)
            if frame.after_gap:  # not comparable: its pipeline lacked a frame the flight's had
                after_gap += 1
                after_same += not d
                continue
            if d:
                mismatched += 1
                rounding += not compare(frame, rel_tol=ROUNDING_REL_TOL)
                beyond += bool(compare(frame, rel_tol=args.rel_tol)) if args.rel_tol else 1
                diffs.extend(d)
        rows = writer.rows
    problems = report.problems()
    for line in report.notes + problems:
        print(f"warning: {line}", file=sys.stderr)
    incomplete = ""
    if problems and not report.damaged:  # the flight's own: a part missing, ...
        incomplete = f"; INCOMPLETE: {len(problems)} problem(s) with its parts (see the warnings)"
    elif problems:
        if len(report.parts) > 1:
            which = ", ".join(
                f"part {k + 1} ({p.path.name}) {p.kind}"
                for k, p in enumerate(report.parts)
                if p.damaged
            )
            incomplete = f"; INCOMPLETE: of {len(report.parts)} parts, {which}"
        else:
            part = report.parts[0]
            last = report.last_time_s
            upto = f"readable to {last:.2f} s" if last is not None else "no message readable"
            share = (
                f", {100.0 * part.read_bytes / part.size_bytes:.1f}% of the file"
                if part.size_bytes
                else ""
            )
            incomplete = f"; INCOMPLETE: the log is {part.kind} ({upto}{share})"
    # A log replayed on another machine differs in the last bits (docs/logging.md): say
    # when that is all, so that it does not read as a changed behaviour.
    how = (
        f" ({rounding} of them only by float rounding, within {ROUNDING_REL_TOL:g} relative:"
        " another CPU or numeric library; --check is bit-exact unless --rel-tol)"
        if rounding
        else ""
    )
    holes = ""
    if missing:
        holes = "; " + _missing_text(missing, after_gap, after_same)
    compared = frames - after_gap
    print(
        f"{args.scenario}: {frames} frames replayed, {rows} rows -> {args.results}; "
        f"{compared - mismatched} identical to the flight, {mismatched} differ{how}{holes}"
        f"{incomplete}"
    )
    for line in diffs[:20]:
        print(f"  {line}")
    jpeg = ""
    if mismatched and read_metadata(args.scenario, args.flight).get("image_format") == "jpeg":
        jpeg = (
            ": the log's frames are JPEG (lossy), and replay runs on the decoded images, not"
            " on the frames the daemon processed, so it cannot give the flight's results"
            ' exactly; log PNG frames for an exact replay: [logging] image_format = "png"'
            " (or --set logging.image_format=png)"
        )
        print(f"note: {mismatched} frame(s) differ{jpeg}", file=sys.stderr)
    if not args.check:
        return 0
    failed = []
    if beyond:
        within = f" beyond {args.rel_tol:g} relative" if args.rel_tol else ""
        failed.append(f"{beyond} frame(s) differ from the flight{within}{jpeg}")
    if problems:
        failed.append("the log is not whole (see the warnings above)")
    if not frames:
        which = "" if args.camera_id is None else f" of camera {args.camera_id}"
        failed.append(f"no processed frame{which} to compare")
    elif not compared:
        failed.append("no frame could be compared (the log lacks the first processed frame)")
    for why in failed:
        print(f"check failed: {why}", file=sys.stderr)
    return 1 if failed else 0


def _missing_text(missing: list[Any], after_gap: int, after_same: int) -> str:
    """The summary's words for what the log lacks, and for the frames after the first hole."""

    def why(kind: str) -> str:
        whys = sorted({m.why for m in missing if m.kind == kind})
        return " / ".join("dropped by the writer" if w == "not logged" else w for w in whys)

    def count(kind: str) -> int:
        return sum(m.count for m in missing if m.kind == kind)

    holes = []
    if count("image"):
        holes.append(
            f"{count('image')} processed frame(s) whose image is not in the log"
            f" ({why('image')}), not replayed"
        )
    if count("result"):
        holes.append(f"{count('result')} whose result is not ({why('result')}), not replayed")
    if count("messages"):
        holes.append(
            f"{count('messages')} other message(s) the writer dropped (MAVLink, box feed, ...:"
            " the log's health records count them)"
        )
    return (
        f"{'; '.join(holes)}; {after_gap} frame(s) after the first hole replayed without what"
        f" it lacks, not compared ({after_same} identical anyway)"
    )


def _unknown_rows(previous: Any, frame_index: int, t_us: int) -> Any:
    """The objects of the last good frame, as ``unknown`` rows of an unreadable frame."""
    import dataclasses
    import math

    from ..core.classify import unknown
    from ..core.pipeline import FrameResult

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


def _attitude_gaps(
    no_attitude: list[tuple[int, int]], frame_times_us: Any, attitude_us: list[int]
) -> list[str]:
    """Runs of consecutive frames the pipeline had no attitude for, each with its frames,
    times (seconds from the first frame) and what the telemetry says about it."""
    t0 = int(frame_times_us[0])
    runs: list[list[tuple[int, int]]] = []
    for i, t in no_attitude:
        if runs and runs[-1][-1][0] == i - 1:
            runs[-1].append((i, t))
        else:
            runs.append([(i, t)])
    att = sorted(attitude_us)

    def s(t_us: int) -> str:
        return f"{(t_us - t0) / 1e6:.2f} s"

    out = []
    for run in runs:
        (i0, ta), (i1, tb) = run[0], run[-1]
        frames = (
            f"frame {i0} ({s(ta)})"
            if i0 == i1
            else f"frames {i0}–{i1} ({(ta - t0) / 1e6:.2f}–{s(tb)})"
        )
        before = [a for a in att if a <= tb]
        after = [a for a in att if a > ta]
        if not att:
            why = "the .tlog has no attitude"
        elif not after:
            why = f"the .tlog's attitude ends at {s(att[-1])}"
        elif not before:
            why = f"the .tlog's attitude starts at {s(att[0])}"
        else:
            gap_from = max(a for a in att if a <= ta) if any(a <= ta for a in att) else att[0]
            gap_to = min(after)
            why = f"no attitude received between {s(gap_from)} and {s(gap_to)}"
        out.append(f"{frames}: {why}")
    return out


def cmd_replay(args: argparse.Namespace) -> int:
    from ..io.outputs import RESULTS_CSV, atomic_text, check_output
    from ..io.results import ResultsWriter
    from ..io.scenario import load_scenario
    from ..replay.scenario import run_replay, with_method

    # before reading anything: nothing is written over an input or what is not ours
    check_output(args.results, RESULTS_CSV, force=args.force, inputs=_inputs(args))
    if is_log(args.scenario):
        return cmd_replay_log(args)
    config = with_method(config_from_args(args), args.method, bsm=args.method == "bsm")
    scenario = TolerantFrames(load_scenario(args.scenario))
    require_inputs(scenario, config)
    for w in scenario.warnings:
        print(f"warning: {w}", file=sys.stderr)
    states: dict[str, int] = {}
    previous = None
    reported = 0
    no_attitude: list[tuple[int, int]] = []  # readable frames no attitude covered
    with (
        atomic_text(args.results, kind=RESULTS_CSV, force=args.force, inputs=_inputs(args)) as fh,
        progress(scenario.n_frames, scenario.name, not args.quiet) as bar,
    ):
        writer = ResultsWriter(fh)
        for result in run_replay(scenario, config):
            if len(scenario.unreadable) > reported:  # this frame could not be read
                reported = len(scenario.unreadable)
                result = _unknown_rows(previous, result.frame_index, result.t_us)
            else:
                previous = result
                if not result.attitude_ok:
                    no_attitude.append((result.frame_index, result.t_us))
            writer.write(result)
            for o in result.objects:
                states[o.state] = states.get(o.state, 0) + 1
            bar.update(1)
    scenario.report_unreadable()
    missing = ""
    if no_attitude:
        # the telemetry does not cover these frames (a .tlog that ends early, a damaged
        # stretch of it): what they saw could not be placed, so the results are partial
        gaps = _attitude_gaps(
            no_attitude, scenario.frame_times_us, [a.recv_us for a in scenario.attitude_samples()]
        )
        print(
            f"warning: {len(no_attitude)} of {scenario.n_frames} frames have no attitude"
            " (objects in them are not placed or classified; times from the first frame):",
            file=sys.stderr,
        )
        for line in gaps[:10]:
            print(f"warning:   {line}", file=sys.stderr)
        if len(gaps) > 10:
            print(f"warning:   ... {len(gaps) - 10} more stretches", file=sys.stderr)
        missing = f"; {len(no_attitude)} frame(s) without attitude (see the warnings)"
    summary = ", ".join(f"{n} {s}" for s, n in sorted(states.items())) or "no objects"
    skipped = (
        f"; {len(scenario.unreadable)} unreadable frame(s) skipped" if scenario.unreadable else ""
    )
    print(
        f"{scenario.name}: {scenario.n_frames} frames, {writer.rows} rows ({summary})"
        f"{skipped}{missing} -> {args.results}"
    )
    return 0


def add_parsers(sub: Any) -> None:
    p = add_command(
        sub,
        "replay",
        "Run a tcm-scenario/1 directory through the core and write the results CSV (one row"
        " per frame and tracked object; unreadable frames are reported and get unknown rows),"
        " or replay a flight log's frames and MAVLink bytes through a fresh endpoint and"
        " pipeline and compare with what the flight logged.",
    )
    add_config_arguments(p, what="; a scenario's replay (a flight log replays its own)")
    add_quiet_argument(p)
    p.add_argument("scenario", help="scenario directory, or a flight log file / log directory")
    p.add_argument(
        "--check",
        action="store_true",
        help="flight log: exit 1 unless every replayed frame equals the logged one and the"
        " log is whole (not truncated or damaged)",
    )
    p.add_argument(
        "--rel-tol",
        type=non_negative_number,
        default=0.0,
        metavar="X",
        help="flight log: --check accepts a disparity within X relative of the logged one"
        " (default 0: bit-exact; 1e-9 for a log written on another machine, whose last"
        " bits round differently; states and tracks always exactly)",
    )
    p.add_argument(
        "--camera-id",
        type=whole_number(0),
        default=None,
        metavar="N",
        help="flight log: only this camera's frames (default: every camera; a rig's log"
        " replays every camera anyway, since each one's results depend on the others')",
    )
    p.add_argument("--flight", metavar="ID", default=None, help="flight log: " + FLIGHT_HELP)
    p.add_argument("--results", required=True, metavar="FILE", help="results CSV to write")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    p.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="decision method of a scenario's replay (default: the configuration's)",
    )
    p.set_defaults(func=cmd_replay)
