"""Build a Lua 5.4 interpreter with 32-bit integers and floats, as ArduPilot's scripting is.

ArduPilot compiles Lua with ``LUA_32BITS``: integers and floats are 32 bits wide, so
``string.unpack`` of an 8-byte integer above 2^31 raises "8-byte integer does not fit
into Lua Integer" and the firmware removes the script. Debian's ``lua5.4`` and lupa are
64-bit and cannot show this; ``tests/test_lua_applet.py`` runs the applet's harness in
this interpreter as well.

The Lua sources come from the lupa source distribution on PyPI (it bundles Lua 5.4's
``onelua.c``), pinned by version and SHA-256; ``luaconf.h`` is switched to
``LUA_32BITS`` and the one file is compiled with gcc.

    python tools/ardupilot/build_lua32.py [--out .venv/bin/lua5.4-32]
"""

from __future__ import annotations

import argparse
import hashlib
import io
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.request
from pathlib import Path

LUPA_VERSION = "2.8"
LUPA_SHA256 = "d8022641b9ec8ecf2c5ecbe9f47e5a70e0b87c4b5ae921b92cb02a638e0acd08"
LUPA_URL = (  # PyPI's file store (addresses are stable and content-derived)
    "https://files.pythonhosted.org/packages/c3/a6/"
    f"0f869fbb07c393f15473b1eefefb7b5bec162fb7481803d040ed4dc46002/lupa-{LUPA_VERSION}.tar.gz"
)
LUA_DIR = f"lupa-{LUPA_VERSION}/third-party/lua54/"
DEFAULT_OUT = Path(__file__).resolve().parents[2] / ".venv" / "bin" / "lua5.4-32"


def fetch_sources(dest: Path) -> Path:
    """Download the pinned lupa sdist, check its hash, extract Lua's sources to ``dest``."""
    with urllib.request.urlopen(LUPA_URL, timeout=120) as resp:
        data = resp.read()
    digest = hashlib.sha256(data).hexdigest()
    if digest != LUPA_SHA256:
        raise RuntimeError(f"lupa-{LUPA_VERSION}.tar.gz: sha256 {digest}, expected {LUPA_SHA256}")
    with tarfile.open(fileobj=io.BytesIO(data), mode="r:gz") as tar:
        members = [
            m
            for m in tar.getmembers()
            if m.name.startswith(LUA_DIR) and m.name.endswith((".c", ".h"))
        ]
        tar.extractall(dest, members=members, filter="data")
    return dest / LUA_DIR


def build(out: Path) -> Path:
    cc = shutil.which("gcc") or shutil.which("cc")
    if cc is None:
        raise RuntimeError("no C compiler (gcc) found")
    with tempfile.TemporaryDirectory() as tmp:
        src = fetch_sources(Path(tmp))
        conf = src / "luaconf.h"
        text = conf.read_text()
        if "#define LUA_32BITS\t0" not in text:
            raise RuntimeError("luaconf.h: no '#define LUA_32BITS 0' to switch")
        conf.write_text(text.replace("#define LUA_32BITS\t0", "#define LUA_32BITS\t1"))
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp_out = out.with_suffix(".tmp")
        subprocess.run(
            [
                cc,
                "-O2",
                "-std=gnu99",
                "-DLUA_USE_LINUX",
                "-w",
                str(src / "onelua.c"),
                "-o",
                str(tmp_out),
                "-lm",
                "-ldl",
            ],
            check=True,
        )
    probe = subprocess.run(
        [str(tmp_out), "-e", "io.write(math.maxinteger)"],
        capture_output=True,
        text=True,
        check=True,
    )
    if probe.stdout != "2147483647":
        raise RuntimeError(f"built interpreter is not 32-bit (math.maxinteger = {probe.stdout})")
    tmp_out.replace(out)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="where to put the interpreter")
    args = ap.parse_args()
    try:
        path = build(args.out)
    except Exception as exc:  # one line, for make's output
        print(f"build_lua32: {exc}", file=sys.stderr)
        return 1
    print(f"built {path} (Lua 5.4, 32-bit integers and floats, as ArduPilot)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
