"""Re-record process replay's reference logs (tests/data/logs), like openpilot's
``--update-refs``: the command tests/data/logs/README.md used to spell out by hand.

For each reference ``NAME`` (all of them, or those named):

1. the daemon flies it again in SITL with its recording settings (:data:`RECORDINGS`:
   real time over loopback UDP, lossless PNG frames, no sensor noise) into a temporary
   log directory, and the flight's log becomes ``NAME.mcap``;
2. the new log is replayed on this install and must equal the flight to the bit (process
   replay on the install that wrote it), or nothing is written;
3. ``NAME.results.csv`` is the replay's results CSV (what ``tcm-companion replay NAME.mcap
   --results ...`` writes), and ``NAME.env.json`` this install's numeric environment
   (tests/numerics.py), in which tests/test_log_replay.py then wants a bit-exact replay.

``--results-only`` keeps the logs and rewrites only ``NAME.results.csv`` from their replay,
after checking that the replay still equals the flight within the tolerance
tests/test_log_replay.py allows (a change to what the results CSV holds or how it rounds,
not to the core's results: those need the logs re-recorded).

Run from the repository root, then review ``git diff --stat tests/data/logs`` and say in
the commit why the references changed::

    .venv/bin/python tools/update_refs.py                 # re-record every reference
    .venv/bin/python tools/update_refs.py sitl-t90        # one of them
    .venv/bin/python tools/update_refs.py --results-only  # the expected CSVs only
    .venv/bin/python tools/update_refs.py --into /tmp/refs  # elsewhere, to compare first
"""

from __future__ import annotations

import argparse
import datetime
import io
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOGS = ROOT / "tests" / "data" / "logs"

#: How each reference log is flown: ``tcm-companion sitl`` arguments (besides ``--log``).
#: ``sitl-t90``: the default scenario (T90) against the mock autopilot, 3.5 s of real time
#: (61 frames on a quiet machine, once the simulated camera has started), PNG frames
#: without sensor noise so the file stays small and replays bit-exactly.
RECORDINGS: dict[str, list[str]] = {
    "sitl-t90": [
        "--scenario", "T90",
        "--duration", "3.5",
        "--set", 'logging.image_format="png"',
        "--set", "camera.sim_noise_dn=0",
    ],
}  # fmt: skip
#: A re-recorded flight with fewer processed frames than this is refused (a busy machine
#: starts the simulated camera late): nothing is written.
MIN_FRAMES = 40


def record(name: str, into: Path) -> None:
    """Fly reference ``name`` in SITL and move its flight log to ``into`` (an .mcap)."""
    with tempfile.TemporaryDirectory(prefix="tcm-refs-") as tmp:
        log_dir = Path(tmp) / "log"
        command = [
            sys.executable, "-m", "tcm_companion", "sitl", *RECORDINGS[name],
            "--log", str(log_dir), "--no-status",
        ]  # fmt: skip
        print(f"{name}: {' '.join(command[1:])}", flush=True)
        done = subprocess.run(
            command,
            cwd=ROOT,  # its ./config.toml, as the references were made
            # a state directory of its own: nothing persisted by earlier runs
            env={**os.environ, "TCM_COMPANION__DAEMON__STATE_DIR": str(Path(tmp) / "state")},
        )
        if done.returncode != 0:
            raise SystemExit(f"{name}: the flight failed (exit {done.returncode}): nothing written")
        (log,) = sorted(log_dir.glob("*.mcap"))
        shutil.move(log, into)


def replay(log: Path, rel_tol: float) -> tuple[int, str]:
    """Replay ``log``: its number of frames and its results CSV. Raises SystemExit when
    a replayed frame differs from the flight beyond ``rel_tol`` relative."""
    from tcm_companion.io.results import ResultsWriter
    from tcm_companion.replay.log import compare, replay_log

    buf = io.StringIO()
    writer = ResultsWriter(buf)
    n = 0
    for frame in replay_log(log):
        diffs = compare(frame, rel_tol=rel_tol)
        if diffs:
            raise SystemExit(
                f"{log.name}: the replay differs from the flight (rel_tol {rel_tol:g}): "
                f"{diffs[:3]}; nothing written"
            )
        writer.write(frame.result)
        n += 1
    return n, buf.getvalue()


def update(name: str, results_only: bool, into: Path) -> None:
    """Update reference ``name``'s files in ``into`` (tests/data/logs, or a copy)."""
    log = (LOGS if results_only else into) / f"{name}.mcap"
    sys.path.insert(0, str(ROOT))
    from tcm_companion.replay.log import ROUNDING_REL_TOL
    from tests.numerics import numeric_environment

    if results_only:
        n, results = replay(log, ROUNDING_REL_TOL)
    else:
        with tempfile.TemporaryDirectory(prefix="tcm-refs-") as tmp:
            new = Path(tmp) / f"{name}.mcap"
            record(name, new)
            n, results = replay(new, 0.0)  # bit-exact on the install that wrote it
            if n < MIN_FRAMES:
                raise SystemExit(
                    f"{name}: only {n} frames processed in the flight (at least {MIN_FRAMES} "
                    "wanted; the machine is busy?): nothing written"
                )
            shutil.move(new, log)
        today = datetime.date.today().isoformat()
        env = {
            "about": (
                f"The numeric environment in which {name}.mcap was written and replays "
                f"bit-exactly (verified {today}: {n} frames replayed, 0 differences); "
                "test_log_replay.py requires bit-exact replay where this install's "
                "environment equals it and 1e-9 relative elsewhere. Written by "
                "tools/update_refs.py (tests/data/logs/README.md)."
            ),
            "environment": numeric_environment(),
        }
        (into / f"{name}.env.json").write_text(json.dumps(env, indent=2) + "\n")
    (into / f"{name}.results.csv").write_text(results)
    what = "results" if results_only else "log, results and environment"
    print(f"{name}: {what} written ({n} frames replayed)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=(
            "Re-record process replay's reference logs in tests/data/logs (the SITL "
            "flight, its results CSV and numeric environment), or with --results-only "
            "rewrite only the expected results CSVs from the logs' replay."
        )
    )
    parser.add_argument(
        "names",
        nargs="*",
        metavar="NAME",
        help=f"references to update (default: all: {', '.join(sorted(RECORDINGS))})",
    )
    parser.add_argument(
        "--results-only",
        action="store_true",
        help="keep the logs; rewrite NAME.results.csv from their replay",
    )
    parser.add_argument(
        "--into",
        type=Path,
        default=LOGS,
        metavar="DIR",
        help="write the new files here instead of tests/data/logs (to compare first)",
    )
    args = parser.parse_args(argv)
    names = args.names or sorted(RECORDINGS)
    unknown = [n for n in names if n not in RECORDINGS]
    if unknown:
        parser.error(f"unknown reference {unknown}; known: {sorted(RECORDINGS)}")
    args.into.mkdir(parents=True, exist_ok=True)
    for name in names:
        update(name, args.results_only, args.into)
    return 0


if __name__ == "__main__":
    sys.exit(main())
