"""Create (once) and locate the MAVProxy environment of the interop tests (tests/test_interop.py).

MAVProxy cannot live in the project's venv: its package requires the GUI OpenCV build,
VTK and matplotlib, which would replace opencv-python-headless there. So it gets its own
venv, ``.venv-interop/`` at the repository root (git-ignored), built with
``pip install --no-deps`` from this recipe:

==================  ================================================================
``MAVProxy``        pinned (the tests drive it through its settings and commands)
``pymavlink``       the version the project's venv has, i.e. the mavgen that generated
                    ``tcm_dialect.py`` (the generated module imports pymavlink internals)
``pyserial``        imported by pymavlink's ``mavutil`` and MAVProxy's link module
``numpy``           a declared dependency of MAVProxy; its default ``terrain`` module
                    fails to load without it
``pillow``          its default ``adsb`` module imports ``PIL.ImageColor`` (we may send
                    ADSB_VEHICLE, so that module should be the stock one)
==================  ================================================================

Nothing else is imported by ``mavproxy.py --daemon --non-interactive`` with its default
modules (found by running it with ``--moddebug=3``: all 22 modules load): not the GUI stack (wxPython,
OpenCV, VTK, matplotlib), not ``pynmeagps`` or ``defusedxml`` (only the NMEA and
parameter-documentation commands use those), and not pymavlink's ``lxml`` (only its
generator validates XML) or ``fastcrc`` (it falls back to a pure-Python CRC).

Then our dialect is installed into that venv's pymavlink as the dialect ``tcm``:
``tcm_dialect.py`` is copied to ``pymavlink/dialects/v20/tcm.py`` and ``tcm.xml`` beside
it (``common.xml`` and ``ardupilotmega.xml``, which it includes, ship there already), so
that ``mavproxy.py --dialect=tcm`` and ``mavlogdump.py --dialect=tcm`` decode our
messages.

Idempotent and cached: a stamp file in the venv records the recipe and a hash of the
dialect files; an unchanged recipe costs nothing, a changed dialect is re-copied, a
changed package list (or Python) rebuilds the venv. A file lock serialises concurrent
callers (pytest-xdist workers). The first build takes ~10-15 s (measured: 13 s with an
empty pip cache, ~60 MB of wheels from PyPI; 10 s with a warm one); after that, 0.1 s.

    .venv/bin/python tools/interop_env.py            # build if needed; print where it is
    .venv/bin/python tools/interop_env.py --quiet    # what .ci/run and `make interop-env` run
    .venv/bin/python tools/interop_env.py --rebuild  # from scratch

Tests load this file by path and call :func:`ensure`.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_VENV = ROOT / ".venv-interop"
DIALECT_MODULE = ROOT / "tcm_companion" / "mavlink" / "tcm_dialect.py"
DIALECT_XML = ROOT / "tcm_companion" / "mavlink" / "tcm.xml"
DIALECT_NAME = "tcm"
MAVPROXY = "MAVProxy==1.8.75"
STAMP_NAME = ".tcm-interop.json"
RECIPE_VERSION = 1  # bump to force a rebuild when the build steps change


class InteropEnvError(RuntimeError):
    """The environment could not be built or is broken; the message says which step."""


@dataclass(frozen=True)
class InteropEnv:
    venv: Path
    python: Path
    mavproxy: Path  # bin/mavproxy.py (run it with ``python``: its shebang is absolute)
    mavlogdump: Path  # bin/mavlogdump.py, pymavlink's log dumper
    dialect_dir: Path  # pymavlink/dialects/v20 inside the venv


def packages() -> list[str]:
    """What ``pip install --no-deps`` gets (see the module docstring for why each)."""
    try:
        pymavlink = metadata.version("pymavlink")
    except metadata.PackageNotFoundError:
        raise InteropEnvError(
            "pymavlink is not installed in this interpreter: run this with the project's "
            "venv (.venv/bin/python tools/interop_env.py)"
        ) from None
    return [MAVPROXY, f"pymavlink=={pymavlink}", "pyserial>=3.5", "numpy", "pillow"]


def _recipe() -> dict[str, object]:
    return {
        "recipe": RECIPE_VERSION,
        "python": list(sys.version_info[:2]),
        "packages": packages(),
    }


def _dialect_hash() -> str:
    h = hashlib.sha256()
    for path in (DIALECT_MODULE, DIALECT_XML):
        h.update(path.read_bytes())
    return h.hexdigest()


def _paths(venv: Path, dialect_dir: Path) -> InteropEnv:
    bin_dir = venv / "bin"
    return InteropEnv(
        venv=venv,
        python=bin_dir / "python",
        mavproxy=bin_dir / "mavproxy.py",
        mavlogdump=bin_dir / "mavlogdump.py",
        dialect_dir=dialect_dir,
    )


def _read_stamp(venv: Path) -> dict[str, object] | None:
    try:
        stamp = json.loads((venv / STAMP_NAME).read_text())
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) else None


def locate(venv: Path = DEFAULT_VENV) -> InteropEnv | None:
    """The environment if it is built from the current recipe and dialect, else None."""
    stamp = _read_stamp(venv)
    if stamp is None or stamp.get("recipe_spec") != _recipe():
        return None
    if stamp.get("dialect_sha256") != _dialect_hash():
        return None
    env = _paths(venv, Path(str(stamp.get("dialect_dir", ""))))
    if not (env.python.exists() and env.mavproxy.exists() and env.dialect_dir.is_dir()):
        return None
    return env


@contextlib.contextmanager
def _lock(venv: Path) -> Iterator[None]:
    key = hashlib.sha256(str(venv.resolve()).encode()).hexdigest()[:12]
    path = Path(tempfile.gettempdir()) / f"tcm-interop-{key}.lock"
    with open(path, "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def _run(step: str, cmd: list[str], timeout_s: float = 600.0) -> str:
    """Run a build step quietly; on failure raise with the step and its output's tail."""
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1", "PIP_NO_INPUT": "1"}
    env.pop("PYTHONPATH", None)
    try:
        proc = subprocess.run(
            cmd,
            stdin=subprocess.DEVNULL,
            capture_output=True,
            text=True,
            timeout=timeout_s,
            env=env,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise InteropEnvError(f"{step}: {exc}") from None
    if proc.returncode != 0:
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-25:])
        raise InteropEnvError(f"{step} failed (exit {proc.returncode}):\n{tail}")
    return proc.stdout


_CHECK = f"""
import os, sys
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
mavutil.set_dialect("{DIALECT_NAME}")
assert mavutil.mavlink.MAVLINK_MSG_ID_TCM_OBJECT_STATUS == 45100
assert mavutil.mavlink.MAVLINK_MSG_ID_TCM_PIPELINE_HEALTH == 45101
import MAVProxy, serial, numpy, PIL
"""


def _install_dialect(env_python: Path) -> Path:
    out = _run(
        "locating pymavlink in the interop venv",
        [
            str(env_python),
            "-c",
            "import os, pymavlink; print(os.path.dirname(pymavlink.__file__))",
        ],
    )
    dialect_dir = Path(out.strip().splitlines()[-1]) / "dialects" / "v20"
    if not (dialect_dir / "common.xml").exists():
        raise InteropEnvError(f"{dialect_dir}: not a pymavlink v20 dialect folder")
    shutil.copyfile(DIALECT_MODULE, dialect_dir / f"{DIALECT_NAME}.py")
    shutil.copyfile(DIALECT_XML, dialect_dir / f"{DIALECT_NAME}.xml")
    _run(
        "importing the tcm dialect and MAVProxy in the interop venv",
        [str(env_python), "-c", _CHECK],
    )
    return dialect_dir


def _build(venv: Path, log: bool) -> None:
    started = time.monotonic()
    if log:
        print(f"interop env: building {venv} ({', '.join(packages())})", file=sys.stderr)
    shutil.rmtree(venv, ignore_errors=True)
    _run("creating the venv", [sys.executable, "-m", "venv", str(venv)])
    _run(
        "pip install --no-deps",
        [
            str(venv / "bin" / "python"),
            "-m",
            "pip",
            "install",
            "--no-deps",
            "--no-compile",
            *packages(),
        ],
    )
    if log:
        print(f"interop env: built in {time.monotonic() - started:.0f} s", file=sys.stderr)


def ensure(venv: Path = DEFAULT_VENV, *, rebuild: bool = False, log: bool = False) -> InteropEnv:
    """Build what is missing or stale (under a lock); return the ready environment."""
    venv = venv.absolute()
    if not rebuild:
        ready = locate(venv)
        if ready is not None:
            return ready
    with _lock(venv):
        if not rebuild:
            ready = locate(venv)  # another process may have built it meanwhile
            if ready is not None:
                return ready
        stamp = _read_stamp(venv)
        python = venv / "bin" / "python"
        if rebuild or stamp is None or stamp.get("recipe_spec") != _recipe() or not python.exists():
            (venv / STAMP_NAME).unlink(missing_ok=True)
            _build(venv, log)
        dialect_dir = _install_dialect(python)
        stamp = {
            "recipe_spec": _recipe(),
            "dialect_sha256": _dialect_hash(),
            "dialect_dir": str(dialect_dir),
        }
        (venv / STAMP_NAME).write_text(json.dumps(stamp, indent=2) + "\n")
    ready = locate(venv)
    if ready is None:
        raise InteropEnvError(f"{venv}: built, but not usable (see {venv / STAMP_NAME})")
    return ready


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--venv", type=Path, default=DEFAULT_VENV, help="where (default: %(default)s)"
    )
    parser.add_argument("--rebuild", action="store_true", help="build from scratch")
    parser.add_argument("--quiet", action="store_true", help="print nothing unless it fails")
    args = parser.parse_args(argv)
    try:
        env = ensure(args.venv, rebuild=args.rebuild, log=not args.quiet)
    except InteropEnvError as exc:
        print(f"interop env: {exc}", file=sys.stderr)
        return 1
    if not args.quiet:
        print(env.mavproxy)
    return 0


if __name__ == "__main__":
    sys.exit(main())
