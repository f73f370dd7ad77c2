"""Generate the Python module of our dialect from ``tcm.xml`` with pymavlink's mavgen.

``tcm.xml`` includes ``common.xml`` and ``ardupilotmega.xml``; mavgen resolves includes
relative to the XML's folder, so the XML is generated from a temporary folder next to
copies of the dialect XMLs that pymavlink ships. The generated module is committed
(``tcm_dialect.py``) so that nothing runs the generator at import time; a test checks it
against the XML.

    .venv/bin/python -m tcm_companion.mavlink.generate     # rewrites tcm_dialect.py
"""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path

import pymavlink
from pymavlink.generator import mavgen

HERE = Path(__file__).resolve().parent
XML = HERE / "tcm.xml"
MODULE = HERE / "tcm_dialect.py"
_SHIPPED = Path(pymavlink.__file__).resolve().parent / "dialects" / "v20"


def generate(output: Path = MODULE, xml: Path = XML) -> Path:
    """Run mavgen (Python 3, MAVLink 2) on ``xml``; write the module to ``output``."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for shipped in _SHIPPED.glob("*.xml"):
            shutil.copy(shipped, folder / shipped.name)
        shutil.copy(xml, folder / "tcm.xml")
        opts = mavgen.Opts(
            str(folder / "tcm"), wire_protocol="2.0", language="Python3", validate=True
        )
        if not mavgen.mavgen(opts, [str(folder / "tcm.xml")]):
            raise RuntimeError(f"mavgen failed on {xml}")
        shutil.copy(folder / "tcm.py", output)
    return output


if __name__ == "__main__":
    print(f"wrote {generate()}")
