"""What the commands share: the configuration's arguments and its one loader, logging,
progress bars, image sizes and the light constants the parser offers as choices.

Everything here imports only the standard library at module level: building the parser
(``tcm-companion --help``) must not pull in numpy, OpenCV, SciPy or the MAVLink dialect.
The configuration itself (:mod:`tcm_companion.config` imports the pipeline) is loaded by
:func:`config_from_args`, when a command runs.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..sim.scene.names import MAX_FLIGHT_S

if TYPE_CHECKING:
    from ..config import AppConfig

#: Read when ``--config`` is not given and the file exists (else the built-in defaults).
DEFAULT_CONFIG = Path("config.toml")

#: The decision methods (``tcm_companion.core.classify.METHODS``; a test keeps them equal).
METHODS: tuple[str, ...] = ("tcm", "ecm", "bsm", "fused")

#: The simulator's camera presets (``tcm_companion.sim.scene.cameras.PRESETS``; a test keeps them
#: equal).
CAMERA_PRESETS: tuple[str, ...] = ("panorama", "pinhole", "fisheye")

FORCE_HELP = (
    "replace the output if it exists and is one this program wrote (it is written beside it"
    " and renamed into place when complete)"
)

CONFIG_EPILOG = (
    "Configuration: --set TABLE.KEY=VALUE > environment TCM_COMPANION__TABLE__KEY=VALUE >"
    " --config FILE (default ./config.toml if present) > built-in defaults."
)


def add_command(sub: Any, name: str, description: str, help: str | None = None) -> Any:
    """A command whose ``--help`` says what it does (``description``). The top level
    lists its commands in its own description; a group's subcommands (``sim export``,
    ``config check``) are listed by argparse with their one-line ``help``."""
    if help is None:
        return sub.add_parser(name, description=description)
    return sub.add_parser(name, help=help, description=description)


def add_set_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="TABLE.KEY=VALUE",
        help="override one setting (repeatable; beats TCM_COMPANION__TABLE__KEY and the file)",
    )


def add_config_arguments(p: argparse.ArgumentParser, *, what: str = "") -> None:
    """``--config`` and ``--set``, read by :func:`config_from_args` (every command that
    uses the configuration takes both, and the environment, the same way)."""
    p.add_argument(
        "--config",
        metavar="FILE",
        help="config.toml (default: ./config.toml if present, else built-in)" + what,
    )
    add_set_argument(p)
    if p.epilog is None:
        p.epilog = CONFIG_EPILOG


def config_from_args(args: argparse.Namespace) -> AppConfig:
    """The configuration a command runs with: ``--set`` > environment
    (``TCM_COMPANION__TABLE__KEY``) > ``--config`` (or ./config.toml) > defaults."""
    from ..config import load_config

    return load_config(config_file(args), environ=os.environ, sets=list(args.set))


def config_file(args: argparse.Namespace) -> str | None:
    """The configuration file a command reads (``--config``, else ./config.toml if
    present): one of its inputs, which no output may overwrite."""
    path = getattr(args, "config", None)
    if path is None and DEFAULT_CONFIG.is_file():
        return str(DEFAULT_CONFIG)
    return path


def add_log_level_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--log-level",
        default="INFO",
        choices=("DEBUG", "INFO", "WARNING", "ERROR"),
        help="log messages to stderr at this level (journald keeps them under systemd)",
    )


def setup_logging(level: str) -> None:
    # Under systemd stderr goes to the journal, which adds its own time stamps.
    fmt = (
        "%(levelname)s %(name)s: %(message)s"
        if os.environ.get("JOURNAL_STREAM")
        else "%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    logging.basicConfig(level=getattr(logging, level), format=fmt, stream=sys.stderr)


#: Plots and progress bars come with the ``tools`` extra (the drone's install leaves it out).
TOOLS_HINT = "matplotlib is not installed: pip install 'tcm-companion[tools]' (make installs it)"


def add_quiet_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")


def progress(total: int, desc: str, enabled: bool) -> Any:
    """Progress of ``total`` frames on stderr (tqdm's bar, or plain lines without it)."""
    from ..io.progress import progress as bar

    return bar(total, desc, enabled)


#: An image size on the command line: each side in the range of ``[camera] width`` and
#: ``height`` ...
RESOLUTION_SIDE_PX = (16, 16384)
#: ... and at most this many pixels (4096x4096; 4K video is 3840x2160): the renderer and
#: the pipeline hold several float images of this size at once.
MAX_RESOLUTION_PX = 4096 * 4096


def resolution(text: str) -> tuple[int, int]:
    """``argparse`` type of an image size: ``360x220`` -> ``(360, 220)``, each side in
    :data:`RESOLUTION_SIDE_PX` and at most :data:`MAX_RESOLUTION_PX` pixels."""
    try:
        w, h = text.lower().split("x")
        size = int(w), int(h)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"resolution must look like 360x220, got {text!r}"
        ) from None
    if min(size) <= 0:
        raise argparse.ArgumentTypeError(f"resolution must be positive, got {text!r}")
    lo, hi = RESOLUTION_SIDE_PX
    if not (lo <= size[0] <= hi and lo <= size[1] <= hi):
        raise argparse.ArgumentTypeError(
            f"resolution must be {lo} to {hi} pixels a side, got {text!r}"
        )
    if size[0] * size[1] > MAX_RESOLUTION_PX:
        raise argparse.ArgumentTypeError(
            f"resolution must be at most {MAX_RESOLUTION_PX:,} pixels (4096x4096), got"
            f" {text!r} ({size[0] * size[1]:,})"
        )
    return size


def float_in(ok: Callable[[float], bool], must_be: str, what: str = "a number") -> Any:
    """An ``argparse`` type: a number (``what``) for which ``ok`` holds, else the usage
    error "must be ``must_be``, got ..."."""

    def parse(text: str) -> float:
        value = float(_number(text, float, what))
        if not ok(value):
            raise argparse.ArgumentTypeError(f"must be {must_be}, got {text!r}")
        return value

    return parse


def seconds_up_to(limit_s: float, why: str) -> Any:
    """``argparse`` type of a duration: a number of seconds in (0, ``limit_s``]; the
    usage error says the limit and ``why`` it is there."""
    return float_in(
        lambda v: math.isfinite(v) and 0 < v <= limit_s,
        f"a positive number of seconds up to {limit_s:g} ({why})",
        "a number of seconds",
    )


#: A simulated flight (``sim export``, ``eval --sim``, ``demo``): at most
#: :data:`~tcm_companion.sim.scene.names.MAX_FLIGHT_S`.
flight_seconds = seconds_up_to(MAX_FLIGHT_S, "an hour of flight, 90000 frames")
#: A run of the daemon that is to stop by itself (``run``, ``sitl``): at most a week
#: (``run`` without ``--duration`` runs until stopped).
MAX_RUN_S = 604800.0
run_seconds = seconds_up_to(MAX_RUN_S, "a week")
#: A measurement (``bench --daemon``): at most an hour.
bench_seconds = seconds_up_to(3600.0, "an hour")
#: A seed: a whole number that NumPy's seeding takes as is ([sim] seed's range).
SEED_RANGE = (0, 2**32 - 1)
#: A scale or a delay: a finite number >= 0.
non_negative_number = float_in(lambda v: math.isfinite(v) and v >= 0, "a number >= 0")
#: A finite number > 0.
positive_number = float_in(lambda v: math.isfinite(v) and v > 0, "a positive number")
#: A percentage, 0 to 100.
percent = float_in(
    lambda v: 0.0 <= v <= 100.0, "a percentage in [0, 100]", "a percentage in [0, 100]"
)


def whole_number(low: int, high: int | None = None) -> Any:
    """``argparse`` type of a whole number in ``low..high`` (no upper bound if None)."""

    def parse(text: str) -> int:
        value = _number(text, int, "a whole number")
        if value < low or (high is not None and value > high):
            span = f">= {low}" if high is None else f"in {low}..{high}"
            raise argparse.ArgumentTypeError(f"must be a whole number {span}, got {text!r}")
        return value

    parse.__name__ = "whole number"  # what argparse names in "invalid ... value"
    return parse


def _number(text: str, kind: Any, what: str) -> Any:
    try:
        return kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None


FLIGHT_HELP = (
    "a log directory of several flights: which one (its id or a unique prefix of it, as"
    " the error listing them shows; latest: the newest)"
)


def is_log(path: str) -> bool:
    """A flight log: an ``.mcap`` file or a directory of ``tcm-*.mcap`` parts."""
    p = Path(path)
    return p.suffix == ".mcap" or (p.is_dir() and any(p.glob("tcm-*.mcap")))


def require_inputs(scenario: Any, config: AppConfig, *, truth: bool = False) -> None:
    """Refuse, before any work, a scenario directory that lacks a file the run will need:
    ``truth.csv`` to score it (``truth``), ``detections.csv`` for the ``boxes`` detection
    backend. Raises :class:`~tcm_companion.io.scenario.ScenarioError` (one ``error:``
    line, exit 2) instead of a traceback halfway through."""
    from ..io.scenario import ScenarioError

    where = getattr(scenario, "root", None) or scenario.name
    if truth and getattr(scenario, "truth", None) is None:
        raise ScenarioError(f"{where}: no truth.csv: eval scores a scenario against its truth")
    if config.pipeline.detection.backend == "boxes" and scenario.detections is None:
        raise ScenarioError(
            f'{where}: no detections.csv, which [detection] backend = "boxes" replays'
            " (tcm-companion sim export NAME DIR --detections writes one)"
        )


class TolerantFrames:
    """A scenario whose unreadable frames are reported and replayed as ``None`` (the
    pipeline counts them as bad frames) instead of ending the replay."""

    def __init__(self, scenario: Any) -> None:
        self._inner = scenario
        self.unreadable: list[tuple[int, str]] = []

    def __getattr__(self, name: str) -> Any:
        return getattr(self._inner, name)

    def iter_frames(self) -> Any:
        return self._inner.iter_frames_tolerant(lambda i, why: self.unreadable.append((i, why)))

    def report_unreadable(self, limit: int = 10) -> None:
        """``warning: frame N skipped: why`` on stderr for the first ``limit`` unreadable
        frames, and how many more there were."""
        for i, why in self.unreadable[:limit]:
            print(f"warning: frame {i} skipped: {why}", file=sys.stderr)
        if len(self.unreadable) > limit:
            print(f"warning: ... {len(self.unreadable) - limit} more", file=sys.stderr)
