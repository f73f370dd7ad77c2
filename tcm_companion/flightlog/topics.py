"""The flight log's topics: every topic name, its encoding and schema, in one table.

Like openpilot's ``cereal/services.py``: whoever writes or reads a flight log (the daemon,
:mod:`.writer`, process replay, :mod:`tcm_companion.logtools`) names topics through this
module, never with a string of its own. ``docs/logging.md`` lists the same table (a test
keeps the two in agreement).

Per-camera topics are templates with ``{camera}``: :func:`camera_image` and
:func:`camera_annotations` fill them in, :func:`camera_of` reads the camera id back.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass
from typing import Literal

# Protobuf schemas of the camera topics (foxglove-schemas-protobuf).
IMAGE_SCHEMA = "foxglove.CompressedImage"
ANNOTATIONS_SCHEMA = "foxglove.ImageAnnotations"

MAVLINK_IN = "/mavlink/in"
MAVLINK_OUT = "/mavlink/out"
RESULT = "/tcm/result"
HEALTH = "/tcm/health"
EVENT = "/tcm/event"
PARAM = "/tcm/param"
BOXES = "/tcm/boxes"

CAMERA_IMAGE = "/camera{camera}/image"
CAMERA_ANNOTATIONS = "/camera{camera}/annotations"

#: ``log_mavlink``'s direction -> its topic.
MAVLINK: dict[str, str] = {"in": MAVLINK_IN, "out": MAVLINK_OUT}

Encoding = Literal["protobuf", "json", "mavlink"]


@dataclass(frozen=True)
class Topic:
    """One topic (or per-camera template) of the flight log."""

    name: str  # the topic, or a template with {camera}
    encoding: Encoding  # MCAP message encoding
    schema: str  # protobuf schema name; "" for raw MAVLink; the topic itself for JSON
    what: str


TOPICS: tuple[Topic, ...] = (
    Topic(CAMERA_IMAGE, "protobuf", IMAGE_SCHEMA, "every frame the camera delivered"),
    Topic(CAMERA_ANNOTATIONS, "protobuf", ANNOTATIONS_SCHEMA, "a circle and label per object"),
    Topic(MAVLINK_IN, "mavlink", "", "the bytes read from the autopilot link"),
    Topic(MAVLINK_OUT, "mavlink", "", "the bytes written to the autopilot link"),
    Topic(RESULT, "json", RESULT, "per processed frame: objects as sent, timings, latency"),
    Topic(HEALTH, "json", HEALTH, "once a second: rates, latency, flags, inputs, log counters"),
    Topic(EVENT, "json", EVENT, "input state changes"),
    Topic(PARAM, "json", PARAM, "parameter changes from the ground station"),
    Topic(BOXES, "json", BOXES, "every box-feed datagram as received (UTF-8 ones)"),
)

#: The ``frame_id`` of a camera's images and annotations.
CAMERA_FRAME_ID = "camera{camera}"


@functools.cache
def _template_re(template: str) -> re.Pattern[str]:
    return re.compile("^" + re.escape(template).replace(r"\{camera\}", r"(\d+)") + "$")


def camera_image(camera_id: int) -> str:
    """``/camera{N}/image``."""
    return CAMERA_IMAGE.format(camera=int(camera_id))


def camera_annotations(camera_id: int) -> str:
    """``/camera{N}/annotations``."""
    return CAMERA_ANNOTATIONS.format(camera=int(camera_id))


def camera_frame_id(camera_id: int) -> str:
    """``camera{N}``."""
    return CAMERA_FRAME_ID.format(camera=int(camera_id))


def camera_of(name: str, template: str = CAMERA_IMAGE) -> int | None:
    """The camera id in ``name`` filled in from ``template`` (a per-camera topic, or
    :data:`CAMERA_FRAME_ID`); None when ``name`` is not of that template."""
    m = _template_re(template).match(name)
    return int(m.group(1)) if m else None


def spec(topic: str) -> Topic | None:
    """The table's entry for a topic (per-camera ones included), or None."""
    for t in TOPICS:
        if t.name == topic or ("{camera}" in t.name and camera_of(topic, t.name) is not None):
            return t
    return None
