"""The .tlog reader: round trip, and bad records counted rather than fatal."""

from __future__ import annotations

import struct

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from tcm_companion.io.tlog import TlogError, iter_tlog, read_tlog, write_tlog

T0 = 1_718_000_000_000_000


def packed(n: int = 5, v1: bool = False) -> list[tuple[int, bytes]]:
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    if v1:
        mav.WIRE_PROTOCOL_VERSION = "1.0"
    out = []
    for k in range(n):
        msg = mavlink2.MAVLink_attitude_message(1000 + 20 * k, 0.01 * k, 0.0, 0.5, 0.0, 0.0, 0.0)
        out.append((T0 + 20_000 * k, msg.pack(mav)))
    return out


def test_round_trip_v1_and_v2(tmp_path) -> None:
    path = tmp_path / "t.tlog"
    write_tlog(path, packed(3) + packed(2, v1=True))
    records, stats = read_tlog(path)
    assert [r.msg.get_type() for r in records] == ["ATTITUDE"] * 5
    assert records[0].recv_us == T0 and records[0].offset == 0
    assert stats.decoded == 5 and not stats.skipped


def test_bad_crc_and_unknown_id_are_skipped_and_counted() -> None:
    recs = packed(3)
    bad = bytearray(recs[1][1])
    bad[-1] ^= 0xFF
    unknown = bytearray(recs[2][1])
    unknown[7] = 0x34  # message id low byte → an id common.xml does not define
    unknown[8] = 0x12
    data = b"".join(
        struct.pack(">Q", t) + f
        for t, f in [recs[0], (recs[1][0], bytes(bad)), (recs[2][0], bytes(unknown))]
    )
    from tcm_companion.io.tlog import TlogStats

    stats = TlogStats()
    records = list(iter_tlog(data, "x.tlog", stats))
    assert len(records) == 1
    assert stats.skipped["bad CRC"] == 1
    assert sum(v for k, v in stats.skipped.items() if k.startswith("unknown message id")) == 1


def test_framing_error_names_record_and_offset() -> None:
    recs = packed(2)
    data = struct.pack(">Q", recs[0][0]) + recs[0][1] + struct.pack(">Q", T0) + b"\x00garbage"
    with pytest.raises(TlogError, match=r"x\.tlog: record 1 at byte 36"):
        list(iter_tlog(data, "x.tlog"))


def test_truncated_last_record_is_reported_not_fatal() -> None:
    recs = packed(2)
    data = b"".join(struct.pack(">Q", t) + f for t, f in recs)[:-5]
    from tcm_companion.io.tlog import TlogStats

    stats = TlogStats()
    assert len(list(iter_tlog(data, "x", stats))) == 1
    assert stats.truncated_tail_bytes > 0
    assert "truncated" in stats.summary()


def test_missing_file(tmp_path) -> None:
    with pytest.raises(TlogError, match="cannot read"):
        read_tlog(tmp_path / "nope.tlog")
