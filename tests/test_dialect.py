"""Our MAVLink dialect: private ids, generated module matches the XML, fields documented."""

from __future__ import annotations

import glob
import xml.etree.ElementTree as ET
from pathlib import Path

import pymavlink
from pymavlink.generator import mavparse

from tcm_companion.mavlink import tcm_dialect
from tcm_companion.mavlink.generate import XML, generate

SHIPPED = Path(pymavlink.__file__).resolve().parent / "dialects"


def our_messages() -> list[ET.Element]:
    return list(ET.parse(XML).getroot().iter("message"))


def test_ids_collide_with_no_dialect_shipped_in_pymavlink() -> None:
    ours = {int(m.get("id", -1)) for m in our_messages()}
    names = {m.get("name") for m in our_messages()}
    assert ours and all(45100 <= i < 45110 for i in ours)
    xmls = glob.glob(str(SHIPPED / "v*" / "*.xml"))
    assert len(xmls) > 10
    for path in xmls:
        for m in ET.parse(path).getroot().iter("message"):
            assert int(m.get("id", -1)) not in ours, f"{path} uses id {m.get('id')}"
            assert m.get("name") not in names, f"{path} defines {m.get('name')}"


def test_generated_module_matches_the_xml() -> None:
    xml = mavparse.MAVXML(str(XML), "2.0")
    assert xml.message
    for m in xml.message:
        cls = tcm_dialect.mavlink_map[m.id]
        assert cls.msgname == m.name
        assert cls.crc_extra == m.crc_extra
        assert list(cls.fieldnames) == [f.name for f in m.fields]
        assert list(cls.fieldtypes) == [f.type for f in m.fields]
        units = {f.name: f.units.strip("[]") for f in m.fields if f.units}
        assert dict(cls.fieldunits_by_name) == units


def test_regeneration_reproduces_the_committed_module(tmp_path: Path) -> None:
    fresh = generate(tmp_path / "tcm.py")
    committed = Path(tcm_dialect.__file__).read_text()
    assert fresh.read_text() == committed


def test_every_field_is_documented_and_angles_and_times_have_units() -> None:
    for m in our_messages():
        assert (m.findtext("description") or "").strip()
        for f in m.iter("field"):
            assert (f.text or "").strip(), f"{m.get('name')}.{f.get('name')} undocumented"
            name = f.get("name", "")
            if name in ("azimuth", "elevation", "angular_radius"):
                assert f.get("units") == "rad"
            if name.endswith("_ms") or name == "ttc" or name == "range":
                assert f.get("units"), f"{name} has no units"


def test_round_trip_of_our_messages() -> None:
    mav = tcm_dialect.MAVLink(None, srcSystem=1, srcComponent=191)
    msg = tcm_dialect.MAVLink_tcm_object_status_message(
        1234,
        7,
        0,
        tcm_dialect.TCM_OBJECT_STATE_MOVING,
        0,
        0.31,
        0.09,
        2.5,
        1,
        0.4,
        -0.1,
        0.05,
        4.0,
        80,
    )
    got = tcm_dialect.MAVLink(None).decode(bytearray(msg.pack(mav)))
    assert got.get_type() == "TCM_OBJECT_STATUS"
    assert got.track_id == 7 and got.state == 2 and abs(got.ttc - 2.5) < 1e-6
