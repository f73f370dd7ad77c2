"""MAVLink bytes ↔ messages, sans-IO, never raising into the caller.

pymavlink's generated ``MAVLink`` class packs messages and decodes a complete frame
(CRC, signature); the framing here is ours so that the receive path is bounded and
resynchronises: a frame that fails its CRC costs one byte of scanning, not the frames
that may start inside it, and garbage, truncated frames and floods are counted and
dropped. Every fault lands in :attr:`MavlinkCodec.stats`.

MAVLink 2 signing (optional): outgoing frames are signed; incoming unsigned or badly
signed frames are rejected and counted (``signature rejected``, and one counter per
reason: ``signature rejected: unsigned``, ``wrong key``, ``replayed timestamp``,
``timestamp too old``). The signing timestamp (10 µs units since 2015-01-01) follows the
caller's clock and never goes backwards; the edge persists
:attr:`MavlinkCodec.signing_timestamp` across restarts.

pymavlink's generated dialect logs every signature check at INFO ("new stream", "sig
mismatch": two lines per wrongly signed frame, over a thousand in 14 s from one bad
peer). Its logger is set to WARNING here; the counters above replace those lines, and
the endpoint logs them at most once a second.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass
from typing import Any

from . import tcm_dialect as dialect

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_SIGNED = 0x01
_SIGNATURE_LEN = 13
# 2015-01-01T00:00:00Z in µs since the Unix epoch: the signing timestamp's origin.
SIGNING_EPOCH_US = 1_420_070_400_000_000
# A new signing stream is refused when its timestamp is this far behind ours (pymavlink's
# rule: one minute, in 10 µs units).
_NEW_STREAM_SLACK = 6_000_000

logging.getLogger(dialect.__name__).setLevel(logging.WARNING)


@dataclass(frozen=True)
class SigningConfig:
    secret_key: bytes  # 32 bytes
    link_id: int = 0
    initial_timestamp: int = 0  # persisted from the last run (10 µs units)

    def __post_init__(self) -> None:
        if len(self.secret_key) != 32:
            raise ValueError("MAVLink signing key must be 32 bytes")


def _header_verdict(buf: bytearray, pos: int) -> str:
    """Why no frame can start at ``pos`` ("" if one can): known id, possible length.

    Unknown ids are dropped after decoding anyway, so refusing them here loses nothing,
    and it keeps a stray magic byte from stalling the stream while its made-up length
    arrives.
    """
    if buf[pos] == MAGIC_V1:
        length, msg_id = buf[pos + 1], buf[pos + 5]
    else:
        if buf[pos + 2] & ~_SIGNED:
            return "bad header"  # incompat flags other than "signed" are not defined
        length = buf[pos + 1]
        msg_id = buf[pos + 7] | (buf[pos + 8] << 8) | (buf[pos + 9] << 16)
    cls = dialect.mavlink_map.get(msg_id)
    if cls is None:
        return "unknown message id"
    full = cls.unpacker.size
    # MAVLink 2 trims trailing zeros (at least 1 byte stays); MAVLink 1 sends the base
    # message exactly (extensions are v2 only).
    ok = 1 <= length <= full if buf[pos] == MAGIC_V2 else length <= full
    return "" if ok else "bad header"


class MavlinkCodec:
    """One MAVLink endpoint's framing: ``feed(bytes) -> messages``, ``encode(msg) -> bytes``."""

    def __init__(
        self,
        src_system: int,
        src_component: int,
        signing: SigningConfig | None = None,
        max_buffer: int = 65536,
    ) -> None:
        self.mav = dialect.MAVLink(None, srcSystem=src_system, srcComponent=src_component)
        self.mav.robust_parsing = True
        self._rx = bytearray()
        self.max_buffer = max_buffer
        self.stats: Counter[str] = Counter()
        self.signing = signing
        if signing is not None:
            s = self.mav.signing
            s.secret_key = signing.secret_key
            s.link_id = signing.link_id
            s.timestamp = signing.initial_timestamp
            s.sign_outgoing = True
            s.allow_unsigned_callback = None

    # -- identity --------------------------------------------------------------------
    @property
    def src_system(self) -> int:
        return int(self.mav.srcSystem)

    @src_system.setter
    def src_system(self, value: int) -> None:
        self.mav.srcSystem = value

    @property
    def src_component(self) -> int:
        return int(self.mav.srcComponent)

    @property
    def signing_timestamp(self) -> int:
        return int(self.mav.signing.timestamp)

    # -- sending -----------------------------------------------------------------------
    def encode(self, msg: Any, now_us: int | None = None) -> bytes:
        """Pack one message (the next sequence number, 0..255 then 0 again; signed if
        signing is on)."""
        if self.signing is not None and now_us is not None:
            # The spec's timestamp: 10 µs ticks since 2015; strictly increasing.
            clock = (now_us - SIGNING_EPOCH_US) // 10
            if clock > self.mav.signing.timestamp:
                self.mav.signing.timestamp = clock
        frame = bytes(msg.pack(self.mav))
        # pymavlink advances the sequence number in MAVLink.send(), which we do not use:
        # every frame went out as seq 0 (a ground station reads that as 255 of 256 lost,
        # and a peer cannot tell one sender from two).
        self.mav.seq = (self.mav.seq + 1) % 256
        self.stats["sent"] += 1
        return frame

    # -- receiving ---------------------------------------------------------------------
    def feed(self, data: bytes) -> list[Any]:
        """Take received bytes; return the messages completed by them (maybe none)."""
        out: list[Any] = []
        if not data:
            return out
        self.stats["bytes"] += len(data)
        self._rx.extend(data)
        buf = self._rx
        pos = 0
        n = len(buf)
        while pos < n:
            magic = buf[pos]
            if magic != MAGIC_V1 and magic != MAGIC_V2:
                pos += 1
                self.stats["garbage bytes"] += 1
                continue
            header = 6 if magic == MAGIC_V1 else 10
            if n - pos < header:
                break
            verdict = _header_verdict(buf, pos)
            if verdict:
                # A stray magic byte, or another dialect's frame: do not wait for a
                # "frame" of its made-up length; rescan from the next byte.
                pos += 1
                self.stats[verdict] += 1
                continue
            if magic == MAGIC_V1:
                flen = 6 + buf[pos + 1] + 2
            else:
                flen = 10 + buf[pos + 1] + 2 + (_SIGNATURE_LEN if buf[pos + 2] & _SIGNED else 0)
            if n - pos < flen:
                break
            msg, whole = self._decode(bytearray(buf[pos : pos + flen]))
            if not whole:
                pos += 1  # not a frame after all: resynchronise one byte on
                continue
            pos += flen
            if msg is not None:
                out.append(msg)
        del buf[:pos]
        if len(buf) > self.max_buffer:
            # Parsed everything complete; what is left is a stuck partial "frame" or a
            # flood of one: keep the newest bytes only.
            drop = len(buf) - self.max_buffer
            del buf[:drop]
            self.stats["overflow bytes dropped"] += drop
        return out

    def _decode(self, frame: bytearray) -> tuple[Any | None, bool]:
        """``(message or None, the frame was a real frame to skip whole)``."""
        signed = frame[0] == MAGIC_V2 and bool(frame[2] & _SIGNED)
        if self.signing is not None and not signed:
            # Well-formed but unsigned: check the CRC without the signing layer, then refuse.
            key, self.mav.signing.secret_key = self.mav.signing.secret_key, None
            try:
                plain = self.mav.decode(frame)
            except Exception:
                plain = None
            finally:
                self.mav.signing.secret_key = key
            if plain is None:
                self.stats["bad CRC"] += 1
                return None, False
            self.stats["unsigned rejected"] += 1
            self._signature_rejected("unsigned")
            return None, True
        stream = (frame[-13], frame[5], frame[6]) if signed else None
        seen = self.mav.signing.stream_timestamps.get(stream) if stream else None
        reason = ""
        if self.signing is not None and signed:
            # Why pymavlink would refuse it (it only logs the reason): judged first.
            stamp = int.from_bytes(frame[-12:-6], "little")
            if seen is not None and stamp <= seen:
                reason = "replayed timestamp"
            elif seen is None and stamp + _NEW_STREAM_SLACK < self.mav.signing.timestamp:
                reason = "timestamp too old"
            else:
                reason = "wrong key"
        try:
            msg = self.mav.decode(frame)
        except dialect.MAVError as exc:
            text = str(exc)
            if "signature" in text.lower():
                # pymavlink records a stream's timestamp before checking the signature, so
                # a forged frame with a future timestamp would lock the real sender out.
                if stream is not None:
                    if seen is None:
                        self.mav.signing.stream_timestamps.pop(stream, None)
                    else:
                        self.mav.signing.stream_timestamps[stream] = seen
                self.stats["bad signature"] += 1
                self._signature_rejected(reason or "wrong key")
                return None, True
            self.stats["bad CRC" if "CRC" in text else "undecodable"] += 1
            return None, False
        except Exception:  # pymavlink may raise anything on hostile bytes
            self.stats["undecodable"] += 1
            return None, False
        if isinstance(msg, dialect.MAVLink_unknown):
            # No CRC_EXTRA to check it with: a frame of another dialect, or noise that
            # happens to start with a magic byte. Rescanning inside it costs little and
            # cannot swallow a real frame that starts within.
            self.stats["unknown message id"] += 1
            return None, False
        self.stats["received"] += 1
        return msg, True

    def _signature_rejected(self, reason: str) -> None:
        self.stats["signature rejected"] += 1
        self.stats[f"signature rejected: {reason}"] += 1
