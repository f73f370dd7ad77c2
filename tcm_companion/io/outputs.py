"""Output files and directories that appear whole or not at all, and never at the cost of
an input or of something this program did not write.

A command that writes a results CSV, a scenario directory or a log writes it under a
temporary name beside the target and renames it into place only when it is complete, so
an interrupted or failed run never leaves a partial output behind (nor destroys the
previous one). Before any work, :func:`check_output` refuses (:class:`OutputRefused`, one
line naming both paths):

- an output that is, lies inside or contains one of the command's inputs (real paths,
  symbolic links resolved; a log directory contains its parts), or another of its outputs;
- an output that is a symbolic link, a device, a FIFO or a socket, or whose parent is not
  a directory;
- an existing output that is not what the command writes (its :class:`OutputKind`: a
  results CSV by its header, a scenario directory by its ``scenario.toml`` and nothing
  but a scenario's files in it, a flight log by the MCAP header this program writes).

An existing output of the right kind is replaced only when asked (``--force``);
:class:`OutputExists` otherwise. A folder the command adds files to (plots, a flight log
directory) is never replaced: :func:`check_folder` checks it against the inputs, and each
file written into it is one output of its own (:func:`atomic_path` with ``force=True``:
only a file of its kind is replaced). What is written gets the mode a new file would
(0666 or 0777 less the umask), whatever the temporary file was created with.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import stat
import tempfile
import threading
import tomllib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

PathLike = Path | str


class OutputExists(FileExistsError):
    """The output is there already and replacing it was not asked for."""


class OutputRefused(OSError):
    """Writing the output would destroy an input, or something this program did not
    write; the message names the paths (one line)."""


@dataclass(frozen=True)
class OutputKind:
    """What a command writes: ``what`` names it in messages; ``is_dir`` for a directory;
    ``recognise(path)`` says why an existing ``path`` is not one this program wrote
    (None when it is: ``--force`` may replace it)."""

    what: str
    recognise: Callable[[Path], str | None]
    is_dir: bool = False


# -- what this program writes, recognised ---------------------------------------------------
def _head(path: Path, n: int) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(n)


def text_starting(first_line: str) -> Callable[[Path], str | None]:
    """A recogniser: a regular file whose first line is ``first_line``."""

    def recognise(path: Path) -> str | None:
        want = first_line.encode()
        head = _head(path, len(want) + 2)
        if head.rstrip(b"\r\n") != want and not head.startswith(want + b"\n"):
            return f"its first line is not {first_line[:60]!r}"
        return None

    return recognise


PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
MCAP_MAGIC = b"\x89MCAP0\r\n"
#: The start of the MCAP header's ``library`` field in every log this program writes
#: (``tcm_companion/flightlog/writer.py``; a test keeps them equal).
MCAP_LIBRARY_PREFIX = "tcm-companion/"


def _png(path: Path) -> str | None:
    return None if _head(path, len(PNG_MAGIC)) == PNG_MAGIC else "it is not a PNG image"


def _flight_log(path: Path) -> str | None:
    from mcap.records import Header
    from mcap.stream_reader import StreamReader

    if _head(path, len(MCAP_MAGIC)) != MCAP_MAGIC:
        return "it is not an MCAP file"
    try:
        with open(path, "rb") as fh:
            header = next(iter(StreamReader(fh, record_size_limit=1 << 16).records))
    except Exception:  # any damage to the first record: not recognisably ours
        header = None
    if not isinstance(header, Header) or not header.library.startswith(MCAP_LIBRARY_PREFIX):
        return "its MCAP header does not say tcm-companion wrote it"
    return None


#: The files of a ``tcm-scenario/1`` directory besides its frames (shared/docs/scenario-format.md).
SCENARIO_FILES = ("scenario.toml", "frames.csv", "telemetry.tlog", "truth.csv", "detections.csv")
_FRAME_FILE_DIGITS = 6


def _is_frame_name(name: str) -> bool:
    stem, dot, ext = name.partition(".")
    return len(stem) == _FRAME_FILE_DIGITS and stem.isdigit() and dot == "." and ext == "png"


def _scenario_dir(path: Path) -> str | None:
    from .scenario import FORMAT

    toml = path / "scenario.toml"
    try:
        if not stat.S_ISREG(toml.lstat().st_mode):
            return "its scenario.toml is not a regular file"
        meta = tomllib.loads(toml.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return "it has no scenario.toml"
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return "its scenario.toml cannot be read"
    if meta.get("format") != FORMAT:
        return f"its scenario.toml is not {FORMAT}"
    if isinstance(meta.get("cameras"), list):
        return _rig_dir(path, meta["cameras"])
    return _camera_files(path, meta)


def _rig_dir(path: Path, cameras: list[Any]) -> str | None:
    """A rig (``[[cameras]]``): ``scenario.toml``, ``telemetry.tlog`` and the cameras'
    dirs at the top (each ``NAME`` or ``cameras/NAME``: one level of ``cameras/``), each
    camera's dir holding only a camera's files."""
    dirs: dict[str, set[str]] = {}  # top-level entry -> the camera dirs under it
    for table in cameras:
        d = table.get("dir") if isinstance(table, dict) else None
        parts = Path(d).parts if isinstance(d, str) else ()
        if not parts or len(parts) > 2 or any(p in ("..", ".") for p in parts):
            return "its cameras' dirs are not ones a writer of scenarios makes"
        dirs.setdefault(parts[0], set()).add(parts[1] if len(parts) == 2 else "")
    for entry in path.iterdir():
        mode = entry.lstat().st_mode
        if entry.name in ("scenario.toml", "telemetry.tlog"):
            if not stat.S_ISREG(mode):
                return f"its {entry.name} is not a regular file"
            continue
        if entry.name not in dirs or not stat.S_ISDIR(mode):
            return f"it holds {entry.name}, which is not a scenario's"
        subs = dirs[entry.name]
        if "" in subs:
            why = _camera_files(entry, {"frames_dir": "frames"})
        else:
            why = None
            for sub in entry.iterdir():
                if sub.name not in subs or not stat.S_ISDIR(sub.lstat().st_mode):
                    return f"its {entry.name}/ holds {sub.name}, which is not a camera's"
                why = why or _camera_files(sub, {"frames_dir": "frames"})
        if why is not None:
            return why
    return None


def _camera_files(path: Path, meta: dict[str, Any]) -> str | None:
    """A one-camera scenario's files (or a rig camera's dir): nothing else."""
    frames = meta.get("frames_dir")
    video = meta.get("video")
    allowed = set(SCENARIO_FILES)
    for name in (frames, video):
        if isinstance(name, str) and name and Path(name).name == name:
            allowed.add(name)
    for entry in path.iterdir():
        mode = entry.lstat().st_mode
        if entry.name not in allowed:
            return f"it holds {entry.name}, which is not a scenario's"
        if entry.name == frames:
            if not stat.S_ISDIR(mode):
                return f"its {entry.name} is not a directory"
            for f in entry.iterdir():
                if not (_is_frame_name(f.name) and stat.S_ISREG(f.lstat().st_mode)):
                    return f"its {entry.name}/ holds {f.name}, which is not a frame"
        elif not stat.S_ISREG(mode):
            return f"its {entry.name} is not a regular file"
    return None


def _summary_json(path: Path) -> str | None:
    try:
        if path.stat().st_size > 1 << 20:
            return "it is not a run summary (too large)"
        doc = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return "it is not a run summary (not JSON)"
    if not isinstance(doc, dict) or not {"frames_balance", "processed"} <= doc.keys():
        return "it is not a run summary"
    return None


def _results_csv(path: Path) -> str | None:
    from .results import RESULTS_HEADER, RIG_RESULTS_HEADER

    rig = text_starting(",".join(RIG_RESULTS_HEADER))(path)
    return rig if rig is None else text_starting(",".join(RESULTS_HEADER))(path)


RESULTS_CSV = OutputKind("results CSV", _results_csv)
SCENARIO_DIR = OutputKind("scenario directory", _scenario_dir, is_dir=True)
FLIGHT_LOG = OutputKind("flight log (MCAP)", _flight_log)
PNG_FILE = OutputKind("PNG image", _png)
SUMMARY_JSON = OutputKind("run summary (JSON)", _summary_json)


# -- the checks -----------------------------------------------------------------------------
def _real(path: PathLike) -> Path:
    return Path(os.path.realpath(path))


def _relation(out: Path, other: Path) -> str | None:
    """How the real path ``out`` stands to the real path ``other``, if they overlap."""
    if out == other:
        return "is"
    with contextlib.suppress(OSError):
        if os.path.samefile(out, other):  # a hard link, a bind mount
            return "is"
    if other in out.parents:
        return "lies inside"
    if out in other.parents:
        return "contains"
    return None


def _refuse_overlap(
    p: Path, inputs: Iterable[PathLike | None], others: Iterable[PathLike | None]
) -> None:
    real = _real(p)
    shown = f"{p} (= {real})" if real != Path(os.path.abspath(p)) else str(p)
    for role, paths in (("input", inputs), ("other output", others)):
        for other in paths:
            if other is None or str(other) == "":
                continue
            how = _relation(real, _real(other))
            if how is not None:
                raise OutputRefused(
                    f"the output {shown} {how} the {role} {other}: nothing written;"
                    " give another output path"
                )


def _special(mode: int) -> str | None:
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return None


def _check_parent(p: Path) -> None:
    for anc in p.parents:
        try:
            mode = anc.stat().st_mode
        except FileNotFoundError:
            continue
        except NotADirectoryError:
            continue  # a file further up: found on the way up
        if not stat.S_ISDIR(mode):
            raise OutputRefused(f"{p}: {anc} is not a directory")
        return


def check_output(
    path: PathLike,
    kind: OutputKind,
    *,
    force: bool = False,
    inputs: Iterable[PathLike | None] = (),
    others: Iterable[PathLike | None] = (),
) -> Path:
    """``path`` as a Path, when writing ``kind`` there destroys nothing it should not.

    :class:`OutputRefused` when it is, lies inside or contains one of ``inputs`` or of
    ``others`` (the command's other outputs), is a symbolic link, a device, a FIFO or a
    socket, its parent is not a directory, or it exists and is not a ``kind`` this
    program writes; :class:`OutputExists` when it is one and ``force`` is off."""
    p = Path(path)
    _refuse_overlap(p, inputs, others)
    try:
        st = p.lstat()
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        st = None  # a file where a directory of its path should be: _check_parent says so
    if st is None:
        _check_parent(p)
        return p
    if stat.S_ISLNK(st.st_mode):
        raise OutputRefused(
            f"{p}: is a symbolic link (to {os.readlink(p)}): not replaced, nor what it points"
            " to; give the path of a file of its own"
        )
    special = _special(st.st_mode)
    if special is not None:
        raise OutputRefused(f"{p}: is {special}, not a {kind.what}: not replaced")
    if stat.S_ISDIR(st.st_mode) != kind.is_dir:
        have = "a directory" if stat.S_ISDIR(st.st_mode) else "a file"
        raise OutputRefused(f"{p}: is {have}, not a {kind.what}: not replaced")
    try:
        why = kind.recognise(p)
    except OSError as exc:
        why = f"it cannot be read ({exc.strerror or exc})"
    if why is not None:
        raise OutputRefused(
            f"{p}: not replaced: {why}; only a {kind.what} this program wrote is replaced"
        )
    if not force:
        what = "directory" if kind.is_dir else "file"
        raise OutputExists(f"{p}: the {what} exists; pass --force to replace it")
    return p


def check_folder(
    path: PathLike,
    *,
    inputs: Iterable[PathLike | None] = (),
    others: Iterable[PathLike | None] = (),
    files: Iterable[tuple[str, OutputKind]] = (),
    create: bool = False,
) -> Path:
    """A folder the command adds files to (plots, a report, flight log parts), never
    replaces: it must not be, lie inside or contain an input (nor another output), must
    be a directory if it exists (a symbolic link to one is followed), and each of
    ``files`` (name, kind) already in it must be a file of that kind (it is replaced).
    With ``create`` it is made now (with its parents) and must be writable: a folder a
    long run writes into later (a flight log) is refused at the start, not after."""
    p = Path(path)
    _refuse_overlap(p, inputs, others)
    if os.path.lexists(p):
        if not p.is_dir():
            raise OutputRefused(f"{p}: is not a directory: no files written into it")
    else:
        _check_parent(p)
    for name, kind in files:
        check_output(p / name, kind, force=True)
    if create:
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise OutputRefused(f"{p}: {exc.strerror or exc}") from None
        if not os.access(p, os.W_OK | os.X_OK):
            raise OutputRefused(f"{p}: not writable by this user")
    return p


# -- writing --------------------------------------------------------------------------------
def _umask() -> int:
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    old = os.umask(0o022)  # no /proc: read it by setting it (and put it back at once)
    os.umask(old)
    return old


def _new_mode(is_dir: bool) -> int:
    return (0o777 if is_dir else 0o666) & ~_umask()


_STOPS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """SIGINT and SIGTERM wait (in the main thread) while a temporary is created and
    registered for clean-up, or while an output is swapped into place: an interruption
    lands before or after, never between the two renames of a swap."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, _STOPS)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


@contextlib.contextmanager
def atomic_text(
    path: PathLike,
    *,
    kind: OutputKind,
    force: bool = False,
    inputs: Iterable[PathLike | None] = (),
    others: Iterable[PathLike | None] = (),
) -> Iterator[TextIO]:
    """A text file (newline="" for csv) written as ``.<name>.*.tmp`` beside ``path`` and
    renamed over it (after an fsync) when the ``with`` block ends without an error; on
    an error (or SIGINT/SIGTERM, which the command line turns into one) the temporary
    file is removed and ``path`` is untouched. :func:`check_output` first."""
    inputs, others = tuple(inputs), tuple(others)  # checked again before the rename
    p = check_output(path, kind, force=force, inputs=inputs, others=others)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = ""
    try:
        with _signals_held():
            fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent)
        os.fchmod(fd, _new_mode(False))
        with os.fdopen(fd, "w", newline="") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        check_output(p, kind, force=force, inputs=inputs, others=others)  # not changed since
        os.replace(tmp, p)
    except BaseException:
        if tmp:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(
    path: PathLike,
    *,
    kind: OutputKind,
    force: bool = False,
    inputs: Iterable[PathLike | None] = (),
    others: Iterable[PathLike | None] = (),
) -> Iterator[Path]:
    """A temporary path beside ``path`` for a writer that wants a path of its own (a
    directory when ``kind.is_dir``, else a file name not yet created); moved over
    ``path`` when the ``with`` block ends without an error, removed otherwise (SIGINT and
    SIGTERM included). :func:`check_output` first, and again just before the move."""
    inputs, others = tuple(inputs), tuple(others)
    p = check_output(path, kind, force=force, inputs=inputs, others=others)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp: Path | None = None
    try:
        with _signals_held():
            tmp = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".tmp", dir=p.parent))
        target = tmp if kind.is_dir else tmp / p.name
        yield target
        check_output(p, kind, force=force, inputs=inputs, others=others)
        if kind.is_dir:
            os.chmod(target, _new_mode(True))
        _swap_into_place(target, p)
    finally:
        if tmp is not None and os.path.lexists(tmp):
            shutil.rmtree(tmp, ignore_errors=True)


def _swap_into_place(new: Path, p: Path) -> None:
    """Rename ``new`` to ``p``; an existing directory ``p`` is set aside first and removed
    after, or put back if the rename fails."""
    if not (p.is_dir() and not p.is_symlink()):
        os.replace(new, p)
        return
    old: Path | None = None
    try:
        with _signals_held():
            old = Path(tempfile.mkdtemp(prefix=f".{p.name}.", suffix=".old", dir=p.parent))
            os.replace(p, old / p.name)
            try:
                os.replace(new, p)
            except BaseException:
                os.replace(old / p.name, p)
                raise
    finally:  # a signal held during the swap lands here, after it: the old one still goes
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
