"""Command line: ``tcm-companion <command>`` (:func:`main`, the console script).

One module per group of commands, each with ``add_parsers(sub)`` and its ``cmd_*``
functions: :mod:`.run`, :mod:`.sitl`, :mod:`.config_check` (``config check``), :mod:`.replay`,
:mod:`.evaluate` (``eval``, ``demo``), :mod:`.bench`, :mod:`.logs` (``export``,
``import``, ``plot``) and :mod:`.sim` (``sim export``, ``sim list``, ``mock-autopilot``);
:mod:`.common` holds what they share, above all the one configuration loader
(:func:`~.common.add_config_arguments`, :func:`~.common.config_from_args`). ``run`` and
``sitl`` share the live status line (:mod:`.status_line`), their signal handling
(:mod:`.interrupts`, :mod:`.event_loop`) and the checks of what they read and write
(:mod:`.run_outputs`).

Building the parser imports the standard library and light constants only
(``tcm-companion --help`` in well under half a second; ``tests/test_cli.py`` checks that
numpy, OpenCV, SciPy, matplotlib, mcap and the MAVLink dialect stay unimported): every
command imports what it needs when it runs.
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import Any

from .. import __version__
from . import bench, config_check, evaluate, logs, replay, run, sim, sitl
from .common import config_from_args
from .interrupts import EXIT_SIGINT, EXIT_SIGTERM, Terminated, sigterm_raises

__all__ = ["build_parser", "config_from_args", "main"]

DESCRIPTION = """\
The drone companion computer's service: tells the flight controller, 25 times a second,
whether each object its cameras see is moving or stationary (Triangle Closure Method)
and how soon it would hit.

commands:
  run             the flight daemon (what systemd starts)
  sitl            the daemon against the mock autopilot and a simulated camera, or
                  against real ArduCopter SITL (--autopilot ardupilot); then a summary
  config check    validate a config file and print the effective settings
  replay          a tcm-scenario/1 directory or a flight log through the core -> results CSV
  eval            accuracy, coverage and ROC of TCM/ECM/BSM/fused against truth, with plots
  demo            simulate the paper's flights TS/T45/T90 and print its evaluation
  bench           per-stage time per frame; --mavlink: the link; --daemon: the service
  export          flight log -> tcm-scenario/1 directory (frames + .tlog)
  import          tcm-scenario/1 directory -> flight log (.mcap)
  plot            PNG plots of a flight log or a scenario
  sim export      render a simulated scenario as a tcm-scenario/1 directory
  sim list        list the simulated scenarios
  mock-autopilot  an ArduPilot-like MAVLink vehicle flying a simulated scenario

Every command that reads the configuration (run, sitl, config check, replay, eval, demo,
bench, import --results, plot) takes it the same way: --set TABLE.KEY=VALUE (repeatable)
> environment TCM_COMPANION__TABLE__KEY=VALUE > --config FILE (default ./config.toml if
present) > built-in defaults.
"""


class _Parser(argparse.ArgumentParser):
    """A parser that reports arguments it does not know itself, with its own usage: the
    command's (``tcm-companion sim export: error: unrecognized arguments: --bogus``), where
    argparse leaves them to the top level, which printed its own usage instead. Every
    command's parser is one (``add_subparsers`` makes its parsers of the parent's class)."""

    def parse_known_args(  # type: ignore[override]
        self, args: Any = None, namespace: Any = None
    ) -> tuple[argparse.Namespace, list[str]]:
        parsed, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return parsed, extras


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tcm-companion",
        description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=__version__)
    # The description lists the commands (argparse's own list would repeat it).
    sub = parser.add_subparsers(
        dest="command",
        required=True,
        metavar="COMMAND",
        help="one of the commands above; tcm-companion COMMAND --help shows its options",
    )
    run.add_parsers(sub)
    sitl.add_parsers(sub)
    config_check.add_parsers(sub)  # config check
    replay.add_parsers(sub)
    evaluate.add_parsers(sub)  # eval, demo
    bench.add_parsers(sub)
    logs.add_parsers(sub)  # export, import, plot
    sim.add_parsers(sub)  # sim, mock-autopilot
    return parser


def _error_message(exc: BaseException) -> str | None:
    """What ``main`` prints for an expected error (exit 2), None for a bug (re-raised)."""
    from ..config import ConfigError

    if isinstance(exc, ConfigError):  # one line per error (config check reports all)
        return "\n".join(f"config error: {e}" for e in exc.errors)
    if isinstance(exc, OSError):
        if exc.filename is not None and exc.strerror:  # not "[Errno 21] Is a directory: 'x'"
            other = f" -> {exc.filename2}" if exc.filename2 is not None else ""
            return f"error: {exc.filename}{other}: {exc.strerror}"
        return f"error: {exc}"
    if isinstance(exc, MemoryError):  # what the bounds on sizes and durations left over
        return (
            f"error: out of memory ({exc or 'no detail'}): ask for less (a smaller"
            " --resolution, a shorter --duration, fewer --frames)"
        )
    from ..core.detection import OnnxModelError
    from ..flightlog.reader import FlightSelectionError
    from ..io.scenario import ScenarioError
    from ..io.transports import TransportError
    from ..logtools.convert import LogConversionError
    from ..replay.log import LogReplayError

    if isinstance(
        exc,
        ScenarioError
        | LogConversionError
        | LogReplayError
        | FlightSelectionError
        | TransportError
        | OnnxModelError,
    ):
        return f"error: {exc}"
    return None


#: The exit status when stdout is closed under us (``tcm-companion sim list | head -1``):
#: 128 + SIGPIPE, what the shell reports for ``cat``, ``yes`` or ``seq`` in the same pipe.
EXIT_BROKEN_PIPE = 128 + 13


def _stdout_to_devnull() -> None:
    """Point the stdout file descriptor at /dev/null, so that the interpreter's own flush
    of what is still buffered at exit neither fails nor prints ``Exception ignored ...
    BrokenPipeError``."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return  # not a real file (a test's capture): nothing is flushed to a pipe at exit
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


def main(argv: list[str] | None = None) -> int:
    """The console script. A reader that closes stdout early (``| head``) ends the command
    quietly with :data:`EXIT_BROKEN_PIPE`, as other Unix tools do, whatever it was
    printing (help and usage messages included)."""
    try:
        try:
            status = _main(argv)
        except SystemExit:
            sys.stdout.flush()  # --help, --version: their text is still in the buffer
            raise
        sys.stdout.flush()
        return status
    except BrokenPipeError:
        _stdout_to_devnull()
        return EXIT_BROKEN_PIPE


def _main(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)
    from ..io.allocator import tune_allocator

    tune_allocator()
    try:
        with sigterm_raises():
            return int(args.func(args))
    except KeyboardInterrupt:  # the outputs being written are gone (their finally ran)
        print("\ninterrupted (SIGINT)", file=sys.stderr)
        return EXIT_SIGINT
    except Terminated:
        print("terminated (SIGTERM)", file=sys.stderr)
        return int(getattr(args, "sigterm_status", EXIT_SIGTERM))
    except BrokenPipeError:
        raise  # stdout closed by its reader: main ends quietly, not "error: Broken pipe"
    except Exception as exc:  # a bug (no message) is raised again, whole
        message = _error_message(exc)
        if message is None:
            raise
        print(message, file=sys.stderr)
        return 2
