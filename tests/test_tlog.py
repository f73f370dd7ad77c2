"""The .tlog reader: round trip, bad records counted rather than fatal, and damage (a log
cut short, junk appended, a corrupt stretch in the middle) kept to what it touched and
reported (issue 13)."""

from __future__ import annotations

import random
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from tcm_companion.io.tlog import TlogError, TlogGap, TlogStats, iter_tlog, read_tlog, write_tlog

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


def test_round_trip_v1_and_v2(tmp_path: Path) -> None:
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
    stats = TlogStats()
    records = list(iter_tlog(data, "x.tlog", stats))
    assert len(records) == 1
    assert stats.skipped["bad CRC"] == 1
    assert sum(v for k, v in stats.skipped.items() if k.startswith("unknown message id")) == 1


def test_a_framing_error_is_skipped_and_named_not_fatal() -> None:
    recs = packed(2)
    data = struct.pack(">Q", recs[0][0]) + recs[0][1] + struct.pack(">Q", T0) + b"\x00garbage"
    stats = TlogStats()
    assert len(list(iter_tlog(data, "x.tlog", stats))) == 1
    (gap,) = stats.gaps
    assert (gap.offset, gap.length, gap.record, gap.resumed_at) == (36, 16, 1, None)
    assert "record 1: byte 0x00 is not a MAVLink magic byte" in stats.summary()
    assert "16 bytes skipped at byte 36, to the end of the file" in stats.summary()


def test_nothing_usable_is_an_error_naming_file_record_and_offset(tmp_path: Path) -> None:
    junk = bytes(random.Random(5).randrange(256) for _ in range(3000))
    with pytest.raises(TlogError, match=r"x\.tlog: no usable MAVLink record in 3000 bytes "):
        list(iter_tlog(junk, "x.tlog"))
    path = tmp_path / "t.tlog"
    path.write_bytes(struct.pack(">Q", T0) + b"\x00garbage and more garbage")
    with pytest.raises(TlogError, match=rf"{path}: .*record 0 at byte 0: byte 0x00 is not"):
        read_tlog(path)
    path.write_bytes(tlog(packed(1))[:20])  # one record, cut short
    with pytest.raises(TlogError, match=r"record 0 at byte 0: the file ends inside it"):
        read_tlog(path)
    path.write_bytes(b"")  # empty: no records, but nothing damaged either
    assert read_tlog(path)[0] == []


def tlog(recs: list[tuple[int, bytes]]) -> bytes:
    return b"".join(struct.pack(">Q", t) + f for t, f in recs)


def mixed(n: int) -> list[tuple[int, bytes]]:
    """Records of ATTITUDE, HEARTBEAT and LOCAL_POSITION_NED, MAVLink 2 and 1 mixed."""
    mav2 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav1 = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    mav1.WIRE_PROTOCOL_VERSION = "1.0"
    out = []
    for k in range(n):
        mav = mav1 if k % 5 == 3 else mav2
        if k % 3 == 0:
            msg: object = mavlink2.MAVLink_heartbeat_message(2, 3, 0, 0, 4, 3)
        elif k % 3 == 1:
            msg = mavlink2.MAVLink_attitude_message(1000 + 20 * k, 0.01 * k, 0.02, 0.5, 0, 0, 0)
        else:
            msg = mavlink2.MAVLink_local_position_ned_message(1000 + 20 * k, k, 2 * k, -2, 1, 0, 0)
        out.append((T0 + 20_000 * k, msg.pack(mav)))  # type: ignore[attr-defined]
    return out


def bounds(recs: list[tuple[int, bytes]]) -> list[tuple[int, int]]:
    """(start, end) byte offsets of each record."""
    out, pos = [], 0
    for _, f in recs:
        out.append((pos, pos + 8 + len(f)))
        pos += 8 + len(f)
    return out


def test_a_log_cut_anywhere_keeps_its_whole_records_and_reports_the_rest() -> None:
    recs = mixed(12)
    data = tlog(recs)
    spans = bounds(recs)
    for cut in range(1, len(data) + 1):
        whole = sum(1 for _, end in spans if end <= cut)
        stats = TlogStats()
        if whole == 0:
            with pytest.raises(TlogError, match=r"x\.tlog: .*record 0 at byte 0: the file ends"):
                list(iter_tlog(data[:cut], "x.tlog", stats))
            continue
        got = list(iter_tlog(data[:cut], "x.tlog", stats))
        assert [(r.recv_us, r.offset) for r in got] == [
            (t, start) for (t, _), (start, _) in zip(recs[:whole], spans)
        ], cut
        assert stats.decoded == whole and not stats.skipped
        end = spans[whole - 1][1]
        if cut == end:
            assert stats.gaps == [] and stats.truncated_tail_bytes == 0
            continue
        assert stats.gaps == [
            TlogGap(end, cut - end, whole, stats.gaps[0].reason, None, got[-1].recv_us)
        ]
        assert stats.gaps[0].reason.startswith("the file ends inside it"), cut
        assert stats.truncated_tail_bytes == cut - end
        assert f"truncated last record: {cut - end} bytes at byte {end}" in stats.summary()


@pytest.mark.parametrize(
    "junk",
    [
        bytes(random.Random(1).randrange(256) for _ in range(4000)),
        b"\x00" * 1000,
        b"garbage appended by a careless copy\n" * 20,
        b"\xfe" * 3000,  # every byte a MAVLink 1 magic
        b"\xfd\x09\x00" * 700,  # every third byte a MAVLink 2 magic
        b"ab",
    ],
    ids=["random", "zeros", "text", "v1-magics", "v2-magics", "two-bytes"],
)
def test_junk_appended_keeps_every_record_and_reports_the_junk(junk: bytes) -> None:
    """Treated as a cut log is: the records kept, the rest reported (it refused the
    whole log before)."""
    recs = mixed(12)
    data = tlog(recs)
    stats = TlogStats()
    got = list(iter_tlog(data + junk, "x.tlog", stats))
    assert [r.recv_us for r in got] == [t for t, _ in recs]
    (gap,) = stats.gaps
    assert (gap.offset, gap.length, gap.record, gap.resumed_at) == (len(data), len(junk), 12, None)
    assert gap.after_us == recs[-1][0]
    assert stats.bytes_skipped == len(junk) and stats.size_bytes == len(data) + len(junk)
    summary = stats.summary()
    assert summary.startswith("12 records kept (12/12 decoded); ")
    assert f"{len(junk)} bytes" in summary and f"at byte {len(data)}" in summary


def _overwrite(data: bytes, at: int, new: bytes) -> bytes:
    return data[:at] + new + data[at + len(new) :]


@pytest.mark.parametrize(
    "damage",
    ["random", "zeros", "deleted", "inserted", "length-byte", "magic", "two-records"],
)
def test_a_corrupt_stretch_in_the_middle_is_skipped_and_reading_resynchronises(
    damage: str,
) -> None:
    recs = mixed(20)
    data = tlog(recs)
    spans = bounds(recs)
    s7, e7 = spans[7]
    rng = random.Random(7)
    lost = [7]
    if damage == "random":  # from its time stamp into its header: not a magic byte there
        noise = bytearray(rng.randrange(256) for _ in range(15))
        noise[5] = 0x42
        bad = _overwrite(data, s7 + 3, bytes(noise))
    elif damage == "zeros":
        bad = _overwrite(data, s7 + 9, b"\x00" * (e7 - s7 - 9))
    elif damage == "deleted":  # bytes lost from inside record 7
        bad = data[: s7 + 14] + data[s7 + 24 :]
    elif damage == "inserted":  # junk inside record 7
        bad = data[: s7 + 14] + bytes(rng.randrange(256) for _ in range(333)) + data[s7 + 14 :]
    elif damage == "length-byte":  # a frame length that no longer frames it
        bad = _overwrite(data, s7 + 9, bytes([(data[s7 + 9] + 3) % 256]))
    elif damage == "magic":
        bad = _overwrite(data, s7 + 8, b"\x55")
    else:  # records 7 and 8 overwritten
        bad = _overwrite(
            data, s7 + 4, bytes(rng.randrange(256) for _ in range(spans[8][1] - s7 - 8))
        )
        lost = [7, 8]
    stats = TlogStats()
    got = list(iter_tlog(bad, "x.tlog", stats))
    kept = [t for k, (t, _) in enumerate(recs) if k not in lost]
    assert [r.recv_us for r in got] == kept
    assert stats.decoded == len(kept) and stats.records == len(kept)
    (gap,) = stats.gaps
    resumed = len(bad) - (len(data) - spans[lost[-1]][1])  # the first intact record after
    assert (gap.offset, gap.resumed_at, gap.record) == (s7, resumed, 7)
    assert gap.length == resumed - s7 and gap.after_us == recs[6][0]
    assert f"{gap.length} bytes skipped at byte {s7}, resynchronised at byte {resumed}" in (
        stats.summary()
    )
    assert got[7].offset == resumed  # the records after it sit where they are


def test_damage_inside_a_record_that_keeps_the_framing_costs_that_record_only() -> None:
    recs = mixed(10)
    data = tlog(recs)
    s4, e4 = bounds(recs)[4]
    assert data[s4 + 8] == 0xFD  # MAVLink 2, header of 10 bytes
    bad = _overwrite(data, s4 + 8 + 10, b"\x00\xff" * ((e4 - s4 - 8 - 10 - 2) // 2))
    stats = TlogStats()
    got = list(iter_tlog(bad, "x", stats))
    assert [r.recv_us for r in got] == [t for k, (t, _) in enumerate(recs) if k != 4]
    assert stats.gaps == [] and stats.skipped == {"bad CRC": 1} and stats.records == 10


def test_runs_of_unknown_ids_and_bad_crcs_cost_one_record_each_not_a_resync() -> None:
    """Framing that holds (each record followed by another) is not damage to skip: a
    dialect we do not know, or a few bad CRCs, are counted per record as before."""
    recs = mixed(10)
    frames = []
    for k, (t, f) in enumerate(recs):
        b = bytearray(f)
        if 2 <= k <= 5 and b[0] == 0xFD:
            b[7], b[8], b[9] = 0x21, 0x43, 0x65  # an id common.xml does not define
        elif k in (7, 8):
            b[-1] ^= 0x5A
        frames.append((t, bytes(b)))
    stats = TlogStats()
    got = list(iter_tlog(tlog(frames), "x.tlog", stats))
    assert stats.gaps == [] and stats.records == 10
    assert stats.skipped["bad CRC"] == 2
    unknown = sum(n for why, n in stats.skipped.items() if why.startswith("unknown message id"))
    assert unknown == 10 - 2 - len(got) and unknown >= 3


@pytest.mark.slow  # 0.65-1.3 s of a test worker (make test-fast --durations, 2026-12-03)
def test_scenario_sized_damage_is_resynchronised_quickly() -> None:
    """The resynchronising scan is linear: 200 kB of MAVLink magic bytes (a candidate
    record at every byte) cost well under a few seconds."""
    import time

    recs = mixed(40)
    data = tlog(recs)
    cut = bounds(recs)[20][0]
    bad = data[:cut] + b"\xfe" * 200_000 + data[cut:]
    t = time.process_time()
    stats = TlogStats()
    assert len(list(iter_tlog(bad, "x", stats))) == 40
    assert time.process_time() - t < 10.0
    assert [(g.offset, g.length) for g in stats.gaps] == [(cut, 200_000)]


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(TlogError, match="cannot read"):
        read_tlog(tmp_path / "nope.tlog")
