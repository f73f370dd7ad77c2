"""``tcm-companion replay``: a scenario directory, or a flight log, through the core."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from .common import (
    FORCE_HELP,
    METHODS,
    add_command,
    add_config_arguments,
    add_quiet_argument,
    config_from_args,
    is_log,
    progress,
)


def cmd_replay_log(args: argparse.Namespace) -> int:
    """A flight log: recompute every processed frame and compare with what was logged."""
    from ..io.outputs import atomic_text
    from ..io.results import ResultsWriter
    from ..replay.log import compare, replay_log

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


def cmd_replay(args: argparse.Namespace) -> int:
    from ..io.outputs import atomic_text
    from ..io.results import ResultsWriter
    from ..io.scenario import load_scenario
    from ..replay.scenario import run_replay, with_method

    if is_log(args.scenario):
        return cmd_replay_log(args)
    config = with_method(config_from_args(args), args.method, bsm=args.method == "bsm")
    scenario = _TolerantFrames(load_scenario(args.scenario))
    for w in scenario.warnings:
        print(f"warning: {w}", file=sys.stderr)
    states: dict[str, int] = {}
    previous = None
    reported = 0
    with (
        atomic_text(args.results, force=args.force) as fh,
        progress(scenario.n_frames, scenario.name, not args.quiet) as bar,
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
        help="flight log: exit 1 unless every replayed frame equals the logged one",
    )
    p.add_argument(
        "--camera-id", type=int, default=0, metavar="N", help="flight log: which camera (default 0)"
    )
    p.add_argument("--results", required=True, metavar="FILE", help="results CSV to write")
    p.add_argument("--force", action="store_true", help=FORCE_HELP)
    p.add_argument(
        "--method",
        choices=METHODS,
        default=None,
        help="decision method of a scenario's replay (default: the configuration's)",
    )
    p.set_defaults(func=cmd_replay)
