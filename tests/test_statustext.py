"""The STATUSTEXT chunks we send are the texts a receiver puts back together."""

from __future__ import annotations

from tcm_companion.mavlink import tcm_dialect as d
from tcm_companion.mavlink.codec import MavlinkCodec
from tcm_companion.mavlink.statustext import (
    TEXT_BYTES,
    StatustextAssembler,
    statustext_messages,
)


def _over_the_wire(msgs: list[object], system: int = 1, component: int = 191) -> list[object]:
    tx, rx = MavlinkCodec(system, component), MavlinkCodec(255, 190)
    return rx.feed(b"".join(tx.encode(m) for m in msgs))


def test_chunked_and_short_texts_come_back_whole_at_their_first_chunks_time() -> None:
    texts = [
        "short",
        "x" * TEXT_BYTES,
        "y" * (TEXT_BYTES + 1),
        "z" * 120,
        # A whole number of full chunks: only an empty last chunk can say the text ended.
        "w" * (2 * TEXT_BYTES),
        "v" * (3 * TEXT_BYTES),
    ]
    assembler = StatustextAssembler()
    out = []
    for i, text in enumerate(texts):
        for j, msg in enumerate(_over_the_wire(statustext_messages(4, text, 1_000 * (i + 1)))):
            whole = assembler.add(msg, t=10.0 * i + j)
            if whole is not None:
                out.append(whole)
    assert out == [(10.0 * i, text) for i, text in enumerate(texts)]


def test_interleaved_senders_are_kept_apart_and_incomplete_texts_are_bounded() -> None:
    a = _over_the_wire(statustext_messages(4, "a" * 70, 5_000), system=1)
    b = _over_the_wire(statustext_messages(4, "b" * 70, 5_000), system=2)
    assembler = StatustextAssembler(max_pending=1)
    assert assembler.add(a[0], 0.0) is None and assembler.add(b[0], 1.0) is None
    assert assembler.dropped == 1  # a's first chunk was forgotten
    assert assembler.add(b[1], 2.0) == (1.0, "b" * 70)
    assert assembler.add(a[1], 3.0) == (3.0, "a" * 20)
    assert d.MAVLINK_MSG_ID_STATUSTEXT == a[0].get_msgId()
