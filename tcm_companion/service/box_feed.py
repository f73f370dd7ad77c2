"""Live boxes from another process on the companion: the ``tcm-boxes/1`` datagrams.

Someone else's detector (a YOLO process reading the same camera through a GStreamer tee,
say) sends one UDP datagram per frame it processed to the address ``[daemon] box_feed``
names (``"udp:127.0.0.1:14660"``; off by default). Each datagram is one UTF-8 JSON
object (docs/box-feed.md has the protocol)::

    {"v": 1, "camera": 0, "capture_mono_us": 81234567890,
     "boxes": [{"x_min": 101.5, "y_min": 40.0, "x_max": 130.0, "y_max": 66.0,
                "score": 0.91, "label": "person"}]}

- ``v``: the protocol version, 1;
- ``camera``: the camera's index (0, 1, ...) or its name (``[camera] name``);
- ``capture_mono_us``: the capture time of the frame the boxes were made from, in µs of
  the companion's CLOCK_MONOTONIC (the clock the daemon stamps its frames with:
  :func:`tcm_companion.io.aio.monotonic_us`), an integer;
- ``boxes``: the boxes in that frame, in the ``tcm-scenario/1`` pixel convention of
  :mod:`tcm_companion.core.detection.boxes` (``score`` 0..1, default 1; ``label``
  optional); an empty list says "nothing in this frame".

This module is the pure part (:func:`parse_box_datagram`, no clock, no socket: tests
call it directly) and the thin asyncio edge (:class:`BoxFeedProtocol`,
:func:`open_box_feed`). What a parsed message does — the frame waiting for its boxes,
late and future messages, the feed's health — is
:class:`~tcm_companion.service.live_boxes.LiveBoxes`' (the Companion's ``boxes``).
"""

from __future__ import annotations

import asyncio
import json
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..core.camera import CameraModel
from ..core.detection import Box
from ..core.detection.base import wraps_around
from ..io.transports.bind import bound_datagram_endpoint
from ..io.transports.urls import check_host

#: The protocol's version, the datagram's ``v``.
PROTOCOL_VERSION = 1
#: Larger datagrams are refused unread (``malformed``): 256 boxes fit in about 30 kB.
MAX_DATAGRAM_BYTES = 32_768
#: At most this many boxes per datagram (``malformed`` beyond).
MAX_BOXES = 256
#: Labels longer than this are refused (``malformed``).
MAX_LABEL_CHARS = 64
#: ``capture_mono_us`` must be below this (a CLOCK_MONOTONIC µs count fits an int64);
#: a larger one is refused (``malformed``) before any arithmetic on it.
MAX_CAPTURE_MONO_US = 2**63
#: The name of the feed's input in the daemon's health (STATUSTEXT ``TCM: box feed stale``).
INPUT_NAME = "box feed"


class BoxFeedError(ValueError):
    """A datagram that is not a ``tcm-boxes/1`` message. ``kind`` is the counter it goes
    to (``"malformed"`` or ``"unknown camera"``); the text says what was wrong."""

    def __init__(self, kind: str, text: str) -> None:
        super().__init__(text)
        self.kind = kind


@dataclass(frozen=True)
class BoxMessage:
    """One parsed datagram: the boxes of camera ``camera_id``'s frame captured at
    ``capture_mono_us``; ``refused``: boxes dropped because they leave the image or are
    empty (the rest are kept)."""

    camera_id: int
    capture_mono_us: int
    boxes: tuple[Box, ...]
    refused: int = 0


def parse_feed_url(url: str) -> tuple[str, int] | None:
    """``"udp:HOST:PORT"`` -> ``(host, port)``; ``""`` -> None (no feed). A ValueError
    says what is wrong with anything else."""
    if url == "":
        return None
    m = re.fullmatch(r"udp:(?P<host>[^:\s]+):(?P<port>\d{1,5})", url)
    if m is None:
        raise ValueError(
            f'must be "" (off) or "udp:HOST:PORT" (e.g. "udp:127.0.0.1:14660"), got {url!r}'
        )
    port = int(m["port"])
    if not 1 <= port <= 65535:
        raise ValueError(f"port must be in [1, 65535], got {port}")
    check_host(url, m["host"])  # an address or a host name, not resolved here
    return m["host"], port


def _number(value: object, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise BoxFeedError("malformed", f"{where} must be a number, got {_short(value)}")
    try:
        x = float(value)
    except OverflowError:  # an integer of hundreds of digits
        x = math.inf
    if not math.isfinite(x):
        raise BoxFeedError("malformed", f"{where} must be finite, got {_short(value)}")
    return x


def _box(item: object, i: int, camera: CameraModel) -> Box | None:
    """One item of ``boxes``; None when it is well formed but not a box in the image."""
    where = f"boxes[{i}]"
    if not isinstance(item, dict):
        raise BoxFeedError("malformed", f"{where} must be an object, got {item!r:.40}")
    coords = []
    for key in ("x_min", "y_min", "x_max", "y_max"):
        if key not in item:
            raise BoxFeedError("malformed", f"{where} has no {key}")
        coords.append(_number(item[key], f"{where}.{key}"))
    score = _number(item.get("score", 1.0), f"{where}.score")
    if not 0.0 <= score <= 1.0:
        raise BoxFeedError("malformed", f"{where}.score must be in [0, 1], got {score:g}")
    label = item.get("label", "")
    if not isinstance(label, str) or len(label) > MAX_LABEL_CHARS:
        raise BoxFeedError(
            "malformed", f"{where}.label must be a string of at most {MAX_LABEL_CHARS} characters"
        )
    x0, y0, x1, y1 = coords
    return box_in_image(Box(x0, y0, x1, y1, score, label), camera)


def box_in_image(box: Box, camera: CameraModel) -> Box | None:
    """``box`` if it is a box in ``camera``'s image (``tcm-scenario/1`` pixels: inside
    ``[0, width] × [0, height]``, not empty; ``x_min > x_max`` only across a full
    panorama's seam), else None."""
    x0, y0, x1, y1 = box.x_min, box.y_min, box.x_max, box.y_max
    w, h = camera.width, camera.height
    inside = 0.0 <= min(x0, x1) and max(x0, x1) <= w and 0.0 <= y0 < y1 <= h
    across = x0 < x1 or (x0 > x1 and wraps_around(camera))
    return box if inside and across else None


def parse_box_datagram(
    data: bytes, cameras: Sequence[CameraModel], names: Sequence[str]
) -> BoxMessage:
    """The message in one datagram, for the daemon's ``cameras`` (their models, to check
    the boxes against the image) called ``names``. Raises :class:`BoxFeedError` for
    anything that is not a message of this protocol; unknown keys are ignored (a later
    minor addition must not break this reader)."""
    if len(data) > MAX_DATAGRAM_BYTES:
        raise BoxFeedError("malformed", f"{len(data)} bytes, more than {MAX_DATAGRAM_BYTES}")
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=_no_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise BoxFeedError("malformed", f"not UTF-8 JSON: {exc}") from None
    except ValueError as exc:  # NaN / Infinity
        raise BoxFeedError("malformed", str(exc)) from None
    if not isinstance(doc, dict):
        raise BoxFeedError("malformed", f"not a JSON object: {type(doc).__name__}")
    v = doc.get("v")
    if v != PROTOCOL_VERSION or isinstance(v, bool):
        raise BoxFeedError("malformed", f"v must be {PROTOCOL_VERSION}, got {v!r}")
    cam = doc.get("camera")
    if isinstance(cam, bool) or not isinstance(cam, int | str):
        raise BoxFeedError("malformed", f"camera must be an index or a name, got {cam!r:.40}")
    if isinstance(cam, str):
        if cam not in names:
            raise BoxFeedError("unknown camera", f"camera {cam!r:.40} is not one of {list(names)}")
        camera_id = list(names).index(cam)
    else:
        if not 0 <= cam < len(cameras):
            raise BoxFeedError(
                "unknown camera", f"camera {_short(cam)} is not in 0..{len(cameras) - 1}"
            )
        camera_id = cam
    t = doc.get("capture_mono_us")
    if isinstance(t, bool) or not isinstance(t, int) or not 0 <= t < MAX_CAPTURE_MONO_US:
        raise BoxFeedError(
            "malformed",
            f"capture_mono_us must be a non-negative integer (µs) below 2^63, got {_short(t)}",
        )
    items = doc.get("boxes")
    if not isinstance(items, list):
        raise BoxFeedError("malformed", f"boxes must be a list, got {items!r:.40}")
    if len(items) > MAX_BOXES:
        raise BoxFeedError("malformed", f"{len(items)} boxes, more than {MAX_BOXES}")
    model = cameras[camera_id]
    parsed = [_box(item, i, model) for i, item in enumerate(items)]
    boxes = tuple(b for b in parsed if b is not None)
    return BoxMessage(camera_id, t, boxes, len(parsed) - len(boxes))


def _short(value: object) -> str:
    """``repr(value)`` cut to 40 characters (a hostile datagram's values go into the log)."""
    text = repr(value)
    return text if len(text) <= 40 else f"{text[:37]}..."


def _no_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number here")


def encode_box_message(camera: int | str, capture_mono_us: int, boxes: Sequence[Box]) -> bytes:
    """A ``tcm-boxes/1`` datagram (what a feeder sends; the tests and the example
    feeder use it)."""
    doc = {
        "v": PROTOCOL_VERSION,
        "camera": camera,
        "capture_mono_us": int(capture_mono_us),
        "boxes": [
            {
                "x_min": b.x_min,
                "y_min": b.y_min,
                "x_max": b.x_max,
                "y_max": b.y_max,
                "score": b.score,
                **({"label": b.label} if b.label else {}),
            }
            for b in boxes
        ],
    }
    return json.dumps(doc, separators=(",", ":")).encode()


# -- the asyncio edge ------------------------------------------------------------------------
class BoxFeedProtocol(asyncio.DatagramProtocol):
    """Hands every datagram to ``on_datagram(data)`` on the event loop's thread."""

    def __init__(self, on_datagram: Callable[[bytes], None]) -> None:
        self.on_datagram = on_datagram
        self.errors = 0

    def datagram_received(self, data: bytes, addr: object) -> None:
        self.on_datagram(data)

    def error_received(self, exc: Exception) -> None:
        self.errors += 1  # e.g. an ICMP error; the socket carries on


async def open_box_feed(
    url: str, on_datagram: Callable[[bytes], None]
) -> tuple[asyncio.DatagramTransport, BoxFeedProtocol]:
    """Listen on ``url`` (``"udp:HOST:PORT"``) for the feed; an OSError names the address."""
    address = parse_feed_url(url)
    if address is None:
        raise ValueError("no box feed address")
    # Bound here, so that a port in use is named with its holder (bound_udp_socket).
    return await bound_datagram_endpoint(
        lambda: BoxFeedProtocol(on_datagram), *address, f"[daemon] box_feed {url}"
    )
