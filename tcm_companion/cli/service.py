"""``tcm-companion run``, ``sitl`` and ``config check``: the service, its simulated runs
and its configuration.

``run`` is the service systemd starts: it loads the configuration (CLI ``--set`` >
environment > file > defaults), builds the camera source, and runs the daemon on uvloop
until SIGTERM (exit 0) or SIGINT (exit 130), notifying systemd (READY, STATUS, WATCHDOG,
STOPPING). ``sitl`` cut short by a signal exits 128 + the signal (docs/daemon.md,
"Stopping and exit status"). With
``[camera] source = "sim"`` there is no vehicle to look at, so ``run`` flies the mock
autopilot in the same process (SITL) and goes on until stopped.

asyncio and everything beyond the standard library are imported by the commands, not
here (see :mod:`.common`).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import logging
import os
import signal
import sys
import threading
from collections.abc import Callable, Coroutine, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from ..sim.scene.names import SCENARIO_NAMES
from .common import (
    add_command,
    add_config_arguments,
    add_log_level_argument,
    add_set_argument,
    config_file,
    config_from_args,
    percent,
    run_seconds,
    setup_logging,
)

if TYPE_CHECKING:
    import asyncio

    from ..config import AppConfig
    from ..service.plumbing import DaemonSummary
    from ..sitl.mock import SitlReport

log = logging.getLogger("tcm_companion")
_T = TypeVar("_T")


def state_dir_for(config: AppConfig) -> Path:
    """``[daemon] state_dir``, else systemd's, XDG's or ~/.local/state/tcm-companion."""
    if config.daemon.state_dir:
        return Path(config.daemon.state_dir)
    env = os.environ.get("STATE_DIRECTORY")
    if env:
        return Path(env.split(":")[0])
    xdg = os.environ.get("XDG_STATE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".local" / "state"
    return base / "tcm-companion"


def _run_loop(main: Callable[[], Coroutine[Any, Any, _T]]) -> _T:
    """Run ``main`` on uvloop (the asyncio loop written in libuv), asyncio if missing."""
    try:
        import uvloop
    except ImportError:  # pragma: no cover - uvloop is a dependency; a bare install still runs
        import asyncio

        return asyncio.run(main())
    return uvloop.run(main())


class _Signals:
    """SIGINT and SIGTERM stop the run (``stop``); :attr:`received` says which came first.

    Exit status of a run a signal cut short (:meth:`exit_status`): 128 + the signal, the
    shell's convention (130 for SIGINT, 143 for SIGTERM) — except SIGTERM for ``run``,
    which is how systemd stops the service: that is a normal end (0).
    """

    HANDLED = (signal.SIGINT, signal.SIGTERM)

    def __init__(self) -> None:
        self.received: signal.Signals | None = None

    def _got(self, sig: signal.Signals, stop: Callable[[], object]) -> None:
        if self.received is None:
            self.received = sig
        stop()

    def install(self, stop: asyncio.Event) -> None:
        """On the running event loop (real time)."""
        import asyncio

        loop = asyncio.get_running_loop()
        for sig in self.HANDLED:
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.add_signal_handler(sig, self._got, sig, stop.set)

    @contextlib.contextmanager
    def installed(self, stop: Callable[[], object]) -> Iterator[None]:
        """As Python signal handlers while the block runs (virtual time: no event loop)."""
        previous: dict[signal.Signals, Any] = {}
        for sig in self.HANDLED:

            def handler(signum: int, frame: Any, sig: signal.Signals = sig) -> None:
                self._got(sig, stop)

            with contextlib.suppress(ValueError):  # not the main thread
                previous[sig] = signal.signal(sig, handler)
        try:
            yield
        finally:
            for sig, old in previous.items():
                signal.signal(sig, old)

    def stopped_by(self, stopped_early: bool) -> str:
        """What ended a run: its signal's name if a signal cut it short ("" if not)."""
        return self.received.name if stopped_early and self.received is not None else ""

    @staticmethod
    def exit_status(ok: bool, stopped_by: str, *, service: bool = False) -> int:
        """0 (1 if the run failed); 128 + the signal that cut it short (see the class)."""
        if stopped_by in ("SIGINT", "SIGTERM") and not (service and stopped_by == "SIGTERM"):
            return 128 + int(signal.Signals[stopped_by])
        return 0 if ok else 1


class _StatusPrinter:
    """The live one-line status on ``stream`` (stderr).

    On a terminal the line is rewritten in place, cut to the terminal's width, and log
    records never land on it: while it is shown (:meth:`logs_above`), the root logger's
    handlers that write to the same terminal are wrapped so that each record clears the
    line, is written, and the line is drawn again below it (one lock for both, as
    records come from the camera and flight-log threads too). Not a terminal (a pipe,
    the journal): a plain line every ``every`` status updates (once a second: every N
    s), and log records go out as they come, whole lines either way.
    """

    def __init__(self, stream: Any = None, every: int = 5) -> None:
        if every < 1:
            raise ValueError(f"every must be >= 1 (no printer at all for no status), got {every}")
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every = every
        self.n = 0
        self.lock = threading.RLock()
        self.shown = ""  # the line on the terminal now ("" none)
        self._wrapped: list[tuple[logging.Handler, _AboveStatusLine]] = []

    def _width(self) -> int:
        try:
            columns = os.get_terminal_size(self.stream.fileno()).columns
        except (AttributeError, OSError, ValueError):
            columns = 0
        return max(20, columns - 1) if columns > 0 else 199  # 0: the size is not known

    def __call__(self, line: str) -> None:
        with self.lock:
            self.n += 1
            if self.tty:
                # One physical row: a wrapped line could not be cleared by \r.
                self.shown = line[: self._width()]
                self.stream.write("\r\x1b[2K" + self.shown)
                self.stream.flush()
            elif (self.n - 1) % self.every == 0:
                self.stream.write(line + "\n")
                self.stream.flush()

    def erase(self) -> None:
        """Clear the line (the cursor back at its start); :meth:`redraw` puts it back."""
        with self.lock:
            if self.tty and self.shown:
                self.stream.write("\r\x1b[2K")
                self.stream.flush()

    def redraw(self) -> None:
        with self.lock:
            if self.tty and self.shown:
                self.stream.write(self.shown)
                self.stream.flush()

    def _same_stream(self, handler: logging.Handler) -> bool:
        stream = getattr(handler, "stream", None)
        if stream is None:
            return False
        if stream is self.stream:
            return True
        try:
            return os.path.samestat(os.fstat(stream.fileno()), os.fstat(self.stream.fileno()))
        except (AttributeError, OSError, ValueError):
            return False

    @contextlib.contextmanager
    def logs_above(self) -> Iterator[_StatusPrinter]:
        """While the block runs, log records go above the live line (a terminal only);
        at its end the line is left as it was, with a new line after it."""
        root = logging.getLogger()
        if self.tty:
            for i, h in enumerate(root.handlers):  # in place: the order stays
                if isinstance(h, logging.StreamHandler) and self._same_stream(h):
                    above = _AboveStatusLine(h, self)
                    root.handlers[i] = above
                    self._wrapped.append((h, above))
        try:
            yield self
        finally:
            for inner, wrapper in self._wrapped:
                if wrapper in root.handlers:
                    root.handlers[root.handlers.index(wrapper)] = inner
            self._wrapped.clear()
            self.done()

    def done(self) -> None:
        with self.lock:
            if self.tty and self.shown:
                self.stream.write("\n")
                self.stream.flush()
            self.shown = ""


class _AboveStatusLine(logging.Handler):
    """A log handler that writes through ``inner`` above the printer's live line."""

    def __init__(self, inner: logging.Handler, printer: _StatusPrinter) -> None:
        super().__init__(inner.level)
        self.inner = inner
        self.printer = printer

    def emit(self, record: logging.LogRecord) -> None:
        with self.printer.lock:
            self.printer.erase()
            try:
                self.inner.handle(record)
            finally:
                self.printer.redraw()


def _status_printer(every: int, enabled: bool = True) -> contextlib.AbstractContextManager[Any]:
    """The live status line (:class:`_StatusPrinter`, logs above it), or None when
    ``enabled`` is false or ``every`` is 0 (``--status-every 0``: no status line)."""
    if not enabled or every == 0:
        return contextlib.nullcontext(None)
    return _StatusPrinter(every=every).logs_above()


def _status_every(text: str) -> int:
    """``argparse`` type of ``--status-every``: whole seconds >= 0 (0: no status line)."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(
            f"must be a whole number of seconds >= 0 (0: no status line), got {text!r}"
        )
    return value


def _add_status_every(p: argparse.ArgumentParser) -> None:
    """``--status-every N`` (``run`` and ``sitl``)."""
    p.add_argument(
        "--status-every",
        type=_status_every,
        default=5,
        metavar="N",
        help="status line every N s when not a terminal (default 5; 0: no status line)",
    )


def _interruptible(cmd: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """A Ctrl-C while the run's own handlers are not in place (loading the configuration
    and the imports before it, the moment after it) ends the command with 130 and one
    line, not a traceback."""

    def wrapped(args: argparse.Namespace) -> int:
        try:
            return cmd(args)
        except KeyboardInterrupt:
            print("\ninterrupted (SIGINT)", file=sys.stderr)
            return 128 + int(signal.SIGINT)

    wrapped.__doc__ = cmd.__doc__
    return wrapped


# -- run ------------------------------------------------------------------------------------
@_interruptible
def cmd_run(args: argparse.Namespace) -> int:
    """The service. Exit 0 when SIGTERM (systemd's stop) or ``--duration`` ends it,
    130 when SIGINT (Ctrl-C) does, 2 on a configuration or start-up error."""
    setup_logging(args.log_level)
    config = config_from_args(args)
    from ..io.sdnotify import Notifier, watchdog_interval_us

    notifier = Notifier.from_env()
    wd_us = watchdog_interval_us(os.environ)
    state = state_dir_for(config)
    try:
        state.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"error: state directory {state}: {exc.strerror}", file=sys.stderr)
        return 2
    from ..service.endpoint_setup import resolve_state_paths

    config = dataclasses.replace(config, mavlink=resolve_state_paths(config.mavlink, state))
    inputs = _inputs(args, config)
    run_log_dir = None
    if config.logging.enabled:
        from ..logsetup import log_directory

        run_log_dir = log_directory(config, state)
    # found now, not after a flight of hours
    _check_outputs(inputs, run_log_dir, args.summary_json, "[logging] directory")
    if config.camera.source.source == "scenario":
        try:
            config = camera_from_scenario(config, _lens_overrides(args.set, os.environ))
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    signals = _Signals()
    ran_out: list[bool] = []  # --duration ended the run (not a signal)

    if config.camera.source.source == "sim":
        log.info("camera source is the simulator: flying the mock autopilot (SITL)")
        _warn_url_ignored(config, 'with [camera] source = "sim"')
        from ..logsetup import log_directory

        log_dir = str(log_directory(config, state)) if config.logging.enabled else None
        # The service's exit status is about the service, not the simulation's accuracy.
        return _run_sitl_until(
            config,
            args.duration,
            _status_printer(args.status_every, not args.no_status),
            signals,
            service=True,
            notifier=notifier,
            state_dir=str(state),
            log_dir=log_dir,
            min_accuracy=None,
            summary_json=(
                None
                if args.summary_json is None
                else lambda summary: write_summary_json(
                    args.summary_json, summary, inputs=inputs, others=[log_dir]
                )
            ),
        )

    async def main_flight(printer: _StatusPrinter | None) -> DaemonSummary | int:
        import asyncio

        from ..io.cameras.base import CameraError
        from ..io.cameras.settings import open_source
        from ..service.daemon import CameraInput, Daemon
        from ..sim.sources import register_sim_sources

        register_sim_sources()  # source = "sim_autopilot" is the simulator's
        cam = config.camera
        try:
            source = open_source(cam.source, cam.model)
        except CameraError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        stop = asyncio.Event()
        signals.install(stop)
        if args.duration is not None:

            def time_up() -> None:
                if not stop.is_set():
                    ran_out.append(True)
                stop.set()

            asyncio.get_running_loop().call_later(args.duration, time_up)
        from ..io.aio import monotonic_us
        from ..io.persist import SigningKeyError
        from ..service.endpoint_setup import make_endpoint, persist

        # The camera is expected at the rate it is set to ([camera] fps).
        cameras = [CameraInput(cam.name, cam.model, source, fps=cam.source.fps)]
        try:
            endpoint, warnings = make_endpoint(config.mavlink, monotonic_us(), config.pipeline)
        except SigningKeyError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        for w in warnings:
            log.warning("%s", w)
        flight_log = None
        if config.logging.enabled:
            from ..logsetup import log_directory, start_flight_log

            log_dir = log_directory(config, state)
            # The parameters in force at start (persisted ones included): replay needs them.
            flight_log = start_flight_log(config, log_dir, cameras, dict(endpoint.params.values))
            log.info("flight log in %s", log_dir)
        daemon = Daemon(
            config,
            cameras,
            endpoint=endpoint,
            persist_params=True,
            notifier=notifier,
            watchdog_interval_us=wd_us,
            on_status=printer,
            flight_log=flight_log,
        )
        try:
            return await daemon.run(stop)
        finally:
            if flight_log is not None:
                await asyncio.to_thread(flight_log.stop)  # drains the queue; off the loop
            with contextlib.suppress(OSError):
                persist(config.mavlink, endpoint)

    with _status_printer(args.status_every, not args.no_status) as printer:
        summary = _run_loop(lambda: main_flight(printer))
    if isinstance(summary, int):
        return summary
    if args.summary_json:
        write_summary_json(args.summary_json, summary, inputs=inputs, others=[run_log_dir])
    from ..service.plumbing import run_length_text

    stopped_by = "" if ran_out else signals.stopped_by(True) or "stop"
    lat = summary.latency_percentile_ms(99)
    latency = f"latency p99 {lat:.2f} ms" if summary.latencies_ms else "latency n/a"
    ran = run_length_text(summary.duration_s, args.duration, stopped_by)
    if not ran.startswith(("stopped", "interrupted")):
        ran = f"stopped after {ran}"
    feed = f"; box feed {summary.box_feed}" if summary.box_feed else ""
    feed += f"; link {summary.link}" if summary.link else ""
    print(
        f"{ran}: captured {summary.captured}, processed {summary.processed}, dropped"
        f" {summary.dropped}, failed {summary.failed}, rejected {summary.rejected}; {latency};"
        f" faults {summary.faults or 'none'}{feed}"
    )
    silent = cameras_without_frames(summary.camera_stats)
    for line in silent:
        print(f"error: {line}", file=sys.stderr)
    return _Signals.exit_status(not silent, stopped_by, service=True)


def cameras_without_frames(camera_stats: dict[str, Any]) -> list[str]:
    """Why each camera that delivered no frame in the whole run did not, one line each
    (a run that saw nothing is not a success, whatever stopped it)."""
    out = []
    for name, s in camera_stats.items():
        if s.delivered:
            continue
        if s.captured:
            why = (
                f"all {s.captured} images it returned were rejected ({s.rejected_empty} empty,"
                f" {s.rejected_size} of the wrong size)"
            )
        elif s.open_failures:
            why = f"it could not be opened ({s.open_failures} tries; last: {s.last_error})"
        elif s.last_error:
            why = f"reading failed ({s.last_error})"
        else:
            why = "it returned no image"
        out.append(f"camera {name} never produced a frame: {why}")
    return out


def _lens_overrides(sets: list[str], environ: Any) -> dict[str, str]:
    """The ``[camera]`` lens keys this run sets with ``--set`` or the environment, and
    how (``{"width": "--set camera.width"}``)."""
    from ..config import ENV_PREFIX, LENS_KEYS

    out = {}
    for name in environ:
        parts = name.removeprefix(ENV_PREFIX).lower().split("__")
        if name.startswith(ENV_PREFIX) and len(parts) == 2 and parts[0] == "camera":
            if parts[1] in LENS_KEYS:
                out[parts[1]] = f"environment {name}"
    for item in sets:
        table, _, key = item.partition("=")[0].strip().partition(".")
        if table == "camera" and key in LENS_KEYS:
            out[key] = f"--set camera.{key}"
    return out


def camera_from_scenario(config: AppConfig, overrides: dict[str, str]) -> AppConfig:
    """``config`` with the camera model ``[camera] path``'s scenario declares (its
    ``scenario.toml`` ``[camera]``): with ``source = "scenario"`` the recorded frames are
    the camera. The configuration's own lens keys (the drone's camera) are replaced, with
    a warning naming those that differ; a differing key this run sets itself
    (``overrides``: ``--set``, environment) is a conflict, a ValueError naming it."""
    from ..io.scenario import ScenarioError, load_scenario

    path = config.camera.source.path
    if not Path(path).is_dir():
        return config  # the source says "no such directory"
    try:
        declared = load_scenario(path, check_frames=False).camera
    except (ScenarioError, OSError) as exc:
        raise ValueError(f"camera.path: {exc} (camera.source = 'scenario')") from None
    mine, theirs = config.camera.model.to_dict(), declared.to_dict()
    differ = [k for k in {**mine, **theirs} if mine.get(k) != theirs.get(k)]
    what = f"{declared.model_name} {declared.width}x{declared.height}"
    conflicts = [k for k in differ if k in overrides]
    if conflicts:

        def show(d: dict[str, Any], k: str) -> str:
            return repr(d[k]) if k in d else "(none)"

        raise ValueError(
            f"camera.source = 'scenario': scenario {path} declares a {what} camera (its"
            " scenario.toml [camera]), and this run sets "
            + ", ".join(
                f"camera.{k} = {show(mine, k)} ({overrides[k]}; the scenario's: {show(theirs, k)})"
                for k in conflicts
            )
            + ": drop the override to take the scenario's camera"
        )
    if differ:
        from ..config import CameraConfig

        # The built-in default (or the repository's config.toml, which writes it out) is
        # not a camera someone described: replacing it is worth a note, not a warning.
        described = config.camera.model != CameraConfig().model
        log.log(
            logging.WARNING if described else logging.INFO,
            "camera model: scenario %s declares a %s camera; the configuration's [camera]"
            " %s are replaced by the scenario's",
            path,
            what,
            ", ".join(differ),
        )
    else:
        log.info("camera model: scenario %s declares a %s camera", path, what)
    return dataclasses.replace(config, camera=dataclasses.replace(config.camera, model=declared))


def _inputs(args: argparse.Namespace, config: AppConfig) -> list[str | None]:
    """What a run reads from files, which its outputs must not overwrite: the
    configuration file, and the camera's video, frames or scenario."""
    src = config.camera.source
    camera = src.path if src.source in ("file", "frames", "scenario") and src.path else None
    return [config_file(args), camera]


def _check_outputs(
    inputs: list[str | None], log_dir: str | Path | None, summary_json: str | None, log_what: str
) -> None:
    """The flight log's directory (made now, writable; files are added to it, none
    replaced) and the summary (a summary of an earlier run is replaced, nothing else)
    destroy no input and are not one another: :mod:`tcm_companion.io.outputs`
    (OutputRefused: one ``error:`` line; the log directory's names ``log_what``)."""
    from ..io.outputs import SUMMARY_JSON, OutputRefused, check_folder, check_output

    if summary_json is not None:
        check_output(summary_json, SUMMARY_JSON, force=True, inputs=inputs)
    if log_dir is not None:
        try:
            check_folder(log_dir, inputs=inputs, others=[summary_json], create=True)
        except OutputRefused as exc:
            raise OutputRefused(f"{log_what} {exc}") from None


def write_summary_json(
    path: str,
    summary: Any,
    *,
    inputs: list[str | None] | None = None,
    others: list[Any] | None = None,
) -> None:
    """Latency percentiles, frame accounting and faults of a run, for tools and benches;
    whole or not at all, over an earlier summary only (:data:`~tcm_companion.io.outputs.SUMMARY_JSON`)."""
    import json

    import numpy as np

    doc = {
        "duration_s": summary.duration_s,
        "captured": summary.captured,
        "processed": summary.processed,
        "dropped": summary.dropped,
        "failed": summary.failed,
        "rejected": summary.rejected,
        "frames_balance": summary.frames_balance,
        "latency_p50_ms": summary.latency_percentile_ms(50),
        "latency_p90_ms": summary.latency_percentile_ms(90),
        "latency_p99_ms": summary.latency_percentile_ms(99),
        "latency_max_ms": summary.latency_percentile_ms(100),
        "faults": summary.faults,
        "watchdog_pings": summary.watchdog_pings,
        "watchdog_withheld": summary.watchdog_withheld,
        "frames_waited_for_attitude": summary.stats.frames_waited,
        "objects_sent": summary.stats.objects_sent,
        "box_feed": getattr(summary, "box_feed", {}),
        "link": getattr(summary, "link", {}),
        "stages_ms": {
            k: {
                "p50": float(np.percentile(v, 50)) if v else None,
                "p99": float(np.percentile(v, 99)) if v else None,
            }
            for k, v in summary.stage_ms.items()
        },
    }
    from ..io.outputs import SUMMARY_JSON, atomic_text

    with atomic_text(
        path, kind=SUMMARY_JSON, force=True, inputs=inputs or (), others=others or ()
    ) as fh:
        fh.write(json.dumps(doc, indent=2))


# -- sitl -----------------------------------------------------------------------------------
@_interruptible
def cmd_sitl(args: argparse.Namespace) -> int:
    """SITL for ``--duration``. Exit 0, 1 if the run failed, 128 + the signal (130 for
    SIGINT) if one cut it short."""
    setup_logging(args.log_level)
    config = config_from_args(args)
    if args.autopilot == "ardupilot":
        return _run_ardupilot(args, config)
    if args.scenario and args.scenario not in SCENARIO_NAMES:
        print(
            f"error: --scenario {args.scenario} is not one of the mock autopilot's"
            f" ({', '.join(SCENARIO_NAMES)}); CROSSING and HEADON of --autopilot ardupilot"
            " are flown by the real firmware",
            file=sys.stderr,
        )
        return 2
    if args.scenario:
        config = dataclasses.replace(
            config, sim=dataclasses.replace(config.sim, scenario=args.scenario)
        )
    _warn_url_ignored(config, "by sitl")
    from ..sitl.mock import DEFAULT_MIN_ACCURACY

    pct = 100.0 * DEFAULT_MIN_ACCURACY if args.min_accuracy is None else args.min_accuracy
    min_accuracy = None if pct <= 0 else pct / 100.0
    printer = _status_printer(args.status_every, not args.no_status)
    if args.log is not None:
        _check_outputs(_inputs(args, config), args.log, None, "--log")
    signals = _Signals()
    if args.clock == "virtual":
        return _run_sitl_virtual(config, args.duration, printer, signals, args.log, min_accuracy)
    return _run_sitl_until(
        config, args.duration, printer, signals, log_dir=args.log, min_accuracy=min_accuracy
    )


def _warn_url_ignored(config: AppConfig, when: str) -> None:
    """Say that ``[mavlink] url`` is not used (``when``): the daemon then talks to the
    mock autopilot in the same process, over a loopback UDP pair of its own."""
    from ..service.endpoint_setup import MavlinkSettings

    url = config.mavlink.url
    if url != MavlinkSettings.url:
        log.warning(
            "[mavlink] url = %r is ignored %s: the daemon talks to the mock autopilot in this"
            " process over loopback UDP; to fly the simulated camera against your own"
            ' autopilot, use [camera] source = "sim_autopilot" with sim_url',
            url,
            when,
        )


def _finish(report: SitlReport, signals: _Signals, *, service: bool = False) -> int:
    """Print ``report`` (naming the signal that cut it short) and return the exit status."""
    stopped_by = signals.stopped_by(report.stopped_by == "stop")
    if stopped_by:
        report = dataclasses.replace(report, stopped_by=stopped_by)
    print("\n".join(report.lines()))
    return _Signals.exit_status(report.ok, stopped_by, service=service)


def _run_sitl_virtual(
    config: AppConfig,
    duration_s: float,
    printer: contextlib.AbstractContextManager[_StatusPrinter | None],
    signals: _Signals,
    log_dir: str | None,
    min_accuracy: float | None,
) -> int:
    """``sitl --clock virtual``: no event loop; SIGINT/SIGTERM end the simulation early."""
    from ..sitl.mock import run_sitl_virtual

    stop = threading.Event()
    with printer as on_status, signals.installed(stop.set):
        report = run_sitl_virtual(
            config,
            camera_model=config.camera.model,
            duration_s=duration_s,
            should_stop=stop.is_set,
            on_status=on_status,
            log_dir=log_dir,
            min_accuracy=min_accuracy,
        )
    return _finish(report, signals)


def _run_ardupilot(args: argparse.Namespace, config: AppConfig) -> int:
    """``sitl --autopilot ardupilot``: real ArduCopter SITL with the applet, one flight."""
    from ..sitl.ardupilot import SCENES
    from ..sitl.ardupilot_process import skip_reason

    scene = (args.scenario or "CROSSING").lower()
    if scene not in SCENES:
        print(
            f"error: with --autopilot ardupilot, --scenario is one of"
            f" {', '.join(s.upper() for s in SCENES)}, got {args.scenario}",
            file=sys.stderr,
        )
        return 2
    missing = skip_reason()
    if missing:
        print(f"error: {missing}", file=sys.stderr)
        return 2

    async def main() -> int:
        from ..sitl.ardupilot import run_ardupilot_sitl

        report = await run_ardupilot_sitl(config, scene, pilot_mode=args.pilot_mode)
        print("\n".join(report.lines()))
        return 0 if report.ok else 1

    return _run_loop(main)


def _run_sitl_until(
    config: AppConfig,
    duration_s: float | None,
    printer: contextlib.AbstractContextManager[_StatusPrinter | None],
    signals: _Signals,
    *,
    service: bool = False,
    summary_json: Callable[[DaemonSummary], None] | None = None,
    **kwargs: Any,
) -> int:
    """SITL on uvloop until ``duration_s`` or SIGINT/SIGTERM; prints the report.
    ``service``: ``run`` (SIGTERM is its normal stop, exit 0); ``summary_json`` writes
    the daemon's summary (``run --summary-json``)."""

    async def main(on_status: _StatusPrinter | None) -> SitlReport:
        import asyncio

        from ..sitl.mock import run_sitl

        stop = asyncio.Event()
        signals.install(stop)
        return await run_sitl(
            config,
            camera_model=config.camera.model,
            duration_s=duration_s,
            stop=stop,
            on_status=on_status,
            **kwargs,
        )

    with printer as on_status:
        report = _run_loop(lambda: main(on_status))
    if summary_json is not None:
        summary_json(report.summary)
    return _finish(report, signals, service=service)


# -- config check ---------------------------------------------------------------------------
def cmd_config_check(args: argparse.Namespace) -> int:
    from ..config import config_to_toml

    config = config_from_args(args)  # a ConfigError is reported by main: exit 2
    print(f"# {args.config}: OK. Effective configuration (CLI > environment > file > defaults):")
    print(config_to_toml(config))
    return 0


def add_parsers(sub: Any) -> None:
    """Register ``run``, ``sitl`` and ``config`` on the main parser's subparsers."""
    p = add_command(
        sub,
        "run",
        "The flight daemon: cameras in, one status per object and frame out on MAVLink, until"
        ' SIGTERM. With [camera] source = "sim" it flies the mock autopilot in the same'
        " process.",
    )
    add_config_arguments(p)
    add_log_level_argument(p)
    p.add_argument(
        "--duration",
        type=run_seconds,
        default=None,
        metavar="S",
        help="stop after S seconds (> 0, at most a week; default: until SIGTERM, exit 0, or"
        " SIGINT, exit 130)",
    )
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    _add_status_every(p)
    p.add_argument(
        "--summary-json", metavar="FILE", default=None, help="write the run's summary as JSON"
    )
    p.set_defaults(func=cmd_run, sigterm_status=0)  # systemd stops it so: a normal end

    p = add_command(
        sub,
        "sitl",
        "The daemon with a simulated camera against the mock autopilot (loopback UDP, or one"
        " simulated clock with --clock virtual) or against real ArduCopter SITL (--autopilot"
        " ardupilot), for a fixed time; then the summary. Exit 1 if the run failed.",
    )
    add_config_arguments(p)
    add_log_level_argument(p)
    p.add_argument(
        "--autopilot",
        choices=("mock", "ardupilot"),
        default="mock",
        help="mock: the built-in mock autopilot flies a scenario (default); ardupilot:"
        " ArduPilot's own SITL binary ($TCM_ARDUPILOT_SITL, or ../shared/ardupilot-sitl)"
        " with the Lua applet, flown in GUIDED at a ball on a collision course",
    )
    p.add_argument(
        "--scenario",
        type=str.upper,
        default=None,
        metavar="NAME",
        help=f"mock: {', '.join(SCENARIO_NAMES)} (default T90); ardupilot: CROSSING"
        " (default) or HEADON",
    )
    p.add_argument(
        "--pilot-mode",
        default=None,
        metavar="MODE",
        help="ardupilot: the pilot switches to this mode (e.g. LOITER) 1 s after the applet"
        " braked; the applet must stand down",
    )
    p.add_argument(
        "--duration",
        type=run_seconds,
        default=20.0,
        metavar="S",
        help="seconds, > 0, at most a week (default 20); SIGINT ends the run early (exit 130)",
    )
    p.add_argument(
        "--clock",
        choices=("real", "virtual"),
        default="real",
        help="mock: real (default) runs the daemon in real time over loopback UDP with a"
        " live status line; virtual runs the companion, the mock and the camera on one"
        " simulated clock as fast as the CPU allows, the same results and flight log"
        " every run",
    )
    p.add_argument(
        "--min-accuracy",
        type=percent,
        default=None,
        metavar="PCT",
        help="mock: fail (exit 1) when the accuracy of the decided object-frames after the"
        " warm-up is below this, or nothing was decided (default 90; 0: not judged)",
    )
    p.add_argument("--log", metavar="DIR", default=None, help="write the flight log (MCAP) here")
    p.add_argument("--no-status", action="store_true", help="no status line on stderr")
    _add_status_every(p)
    p.set_defaults(func=cmd_sitl)

    p = add_command(sub, "config", "Configuration tools: config check FILE.")
    csub = p.add_subparsers(dest="config_command", required=True, metavar="COMMAND", help="check")
    c = add_command(
        csub,
        "check",
        help="validate a config file and print the effective settings",
        description="Validate a config file with the environment (TCM_COMPANION__TABLE__KEY) and --set"
        " applied, and print the effective configuration as TOML. Errors name the file, table"
        " and key, and the variable or flag that set a bad value (exit 2).",
    )
    c.add_argument("config", metavar="FILE", help="the config.toml to check")
    add_set_argument(c)
    c.set_defaults(func=cmd_config_check)
