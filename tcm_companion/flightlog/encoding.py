"""How the flight log's items become MCAP messages (in the writer thread): images as
JPEG/PNG in Foxglove's ``CompressedImage``, circles as ``ImageAnnotations``, documents as
strict JSON, and the protobuf schemas the channels declare."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from google.protobuf.timestamp_pb2 import Timestamp

from . import topics
from .settings import LoggingConfig
from .stats import KIND_FRAME, KIND_JSON, KIND_MAVLINK
from .topics import ANNOTATIONS_SCHEMA, IMAGE_SCHEMA


def _file_descriptor_set(message_class: Any) -> bytes:
    """The message's .proto file and its dependencies, as MCAP's protobuf schema data."""
    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(fd: Any) -> None:
        if fd.name in seen:
            return
        seen.add(fd.name)
        for dep in fd.dependencies:
            add(dep)
        fd.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


_PROTO_SCHEMAS: dict[str, bytes] = {}


def proto_schema(name: str) -> bytes:
    if name not in _PROTO_SCHEMAS:
        cls = CompressedImage if name == IMAGE_SCHEMA else ImageAnnotations
        _PROTO_SCHEMAS[name] = _file_descriptor_set(cls)
    return _PROTO_SCHEMAS[name]


def timestamp(ns: int) -> Timestamp:
    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


_RED = (1.0, 0.15, 0.15)
_GREEN = (0.1, 0.85, 0.2)
_GREY = (0.6, 0.6, 0.6)


def _label_rgb(label: str) -> tuple[float, float, float]:
    if label.startswith("moving"):
        return _RED
    if label.startswith("stationary"):
        return _GREEN
    return _GREY


def annotations_message(ts_ns: int, circles: tuple[tuple[float, float, float, str], ...]) -> bytes:
    ts = timestamp(ts_ns)
    msg = ImageAnnotations()
    if "timestamp" in ImageAnnotations.DESCRIPTOR.fields_by_name:  # schemas >= 0.4
        msg.timestamp.CopyFrom(ts)
    for u, v, r, label in circles:
        u, v, r, label = float(u), float(v), float(r), str(label)
        rgb = _label_rgb(label)
        msg.circles.append(
            CircleAnnotation(
                timestamp=ts,
                position=Point2(x=u, y=v),
                diameter=2.0 * r,
                thickness=2.0,
                fill_color=Color(r=rgb[0], g=rgb[1], b=rgb[2], a=0.0),
                outline_color=Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0),
            )
        )
        msg.texts.append(
            TextAnnotation(
                timestamp=ts,
                position=Point2(x=u - r, y=max(v - r - 3.0, 10.0)),
                text=label,
                font_size=11.0,
                text_color=Color(r=rgb[0], g=rgb[1], b=rgb[2], a=1.0),
                background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
            )
        )
    return msg.SerializeToString()


def jsonable(x: Any) -> Any:
    """``x`` with numpy scalars/arrays made plain and NaN/±inf made null (strict JSON)."""
    if x is None or isinstance(x, str | bool | int):
        return x
    if isinstance(x, float):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple | set | frozenset):
        return [jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return jsonable(x.item())
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, bytes | bytearray):
        return x.hex()
    return str(x)


def metadata_value(v: Any) -> str:
    return v if isinstance(v, str) else json.dumps(jsonable(v), sort_keys=True)


def encode_item(
    item: tuple[Any, ...], config: LoggingConfig, wall_minus_mono_ns: int
) -> tuple[str, str, int, bytes]:
    """(topic, channel kind, t_us, payload) of a queued item (``t_us`` µs on the
    companion's monotonic clock; ``wall_minus_mono_ns`` makes it a wall-clock stamp)."""
    kind = item[0]
    if kind == KIND_MAVLINK:
        _, direction, t_us, data = item
        return topics.MAVLINK[direction], "mavlink", t_us, data
    if kind == KIND_JSON:
        _, topic, t_us, doc = item
        text = json.dumps(jsonable(doc), separators=(",", ":"), allow_nan=False)
        return str(topic), "json", t_us, text.encode()
    _, camera_id, t_us, obj = item
    camera_id = int(camera_id)
    ts_ns = int(t_us) * 1000 + wall_minus_mono_ns
    if kind == KIND_FRAME:
        msg = CompressedImage(
            timestamp=timestamp(ts_ns),
            frame_id=topics.camera_frame_id(camera_id),
            data=encode_image(obj, config),
            format=config.image_format,
        )
        return topics.camera_image(camera_id), IMAGE_SCHEMA, t_us, msg.SerializeToString()
    payload = annotations_message(ts_ns, tuple(obj))
    return topics.camera_annotations(camera_id), ANNOTATIONS_SCHEMA, t_us, payload


def encode_image(image: np.ndarray, config: LoggingConfig) -> bytes:
    """JPEG (``jpeg_quality``) or PNG bytes of a BGR/grey uint8 image."""
    img = np.ascontiguousarray(image)
    if img.dtype != np.uint8:
        raise ValueError(f"image dtype {img.dtype}, expected uint8")
    if config.image_format == "jpeg":
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality])
    else:
        ok, buf = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"cv2.imencode failed for a {img.shape} image")
    return buf.tobytes()
