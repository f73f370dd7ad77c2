"""The ``onnx`` backend: a YOLO-family detector exported to ONNX, run by OpenCV's DNN
module (no other runtime), its boxes measured through the camera model like the
``boxes`` backend's.

The model file is the user's (``[detection] onnx_model``). It must have the YOLOv8
output layout: one tensor ``(1, 4 + n_classes, N)``, each of the N columns a candidate
``cx, cy, w, h`` in input pixels followed by one score per class (no objectness column:
YOLOv5/v7 exports, ``(1, N, 5 + n_classes)``, are refused with a message saying so).
Per frame:

1. **Letterbox** (as Ultralytics does): the frame is resized by ``r = min(in_w / W,
   in_h / H)`` to ``round(W r) × round(H r)`` and centred on a grey (114) canvas of the
   model's input size (``onnx_input_size``), channels RGB, scaled to 0..1.
2. **Decode**: each candidate's class is its best score; candidates below ``min_score``
   or outside ``classes`` are dropped; per-class non-maximum suppression
   (``cv2.dnn.NMSBoxesBatched``, overlap ``onnx_nms_iou``).
3. **Undo the letterbox exactly**: ``x = (x_in - left) · W / round(W r)``, likewise y with
   the top padding and ``H / round(H r)`` (the per-axis scales of the rounded size, not
   ``1 / r``). Pixel coordinates are continuous (``(0, 0)`` the top-left corner) on both
   sides, which is the convention of resizing and of YOLO's boxes. On a full-circle
   panorama, two boxes of one class meeting at the left and right edges with the same
   rows are one object across the seam (``x_min > x_max``).

Pure: the network is loaded once from the model's bytes (the edge reads the file,
:mod:`tcm_companion.io.detector_model`); no IO, no clock. ``onnx_model`` (the file's
path) only names the model in error messages.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..camera import CameraModel
from .base import Detection, DetectorBackend, wraps_around
from .boxes import Box, BoxGeometry, select
from .settings import DetectionConfig

#: The 80 COCO classes of the pretrained YOLOv8 models, in their index order (the names
#: used when ``onnx_class_names`` is empty and the model has 80 classes).
COCO_NAMES: tuple[str, ...] = (
    "person", "bicycle", "car", "motorcycle", "airplane", "bus", "train", "truck", "boat",
    "traffic light", "fire hydrant", "stop sign", "parking meter", "bench", "bird", "cat",
    "dog", "horse", "sheep", "cow", "elephant", "bear", "zebra", "giraffe", "backpack",
    "umbrella", "handbag", "tie", "suitcase", "frisbee", "skis", "snowboard", "sports ball",
    "kite", "baseball bat", "baseball glove", "skateboard", "surfboard", "tennis racket",
    "bottle", "wine glass", "cup", "fork", "knife", "spoon", "bowl", "banana", "apple",
    "sandwich", "orange", "broccoli", "carrot", "hot dog", "pizza", "donut", "cake", "chair",
    "couch", "potted plant", "bed", "dining table", "toilet", "tv", "laptop", "mouse",
    "remote", "keyboard", "cell phone", "microwave", "oven", "toaster", "sink",
    "refrigerator", "book", "clock", "vase", "scissors", "teddy bear", "hair drier",
    "toothbrush",
)  # fmt: skip

#: The grey Ultralytics pads with.
PAD_VALUE = 114
#: A box edge within this of the image's left/right edge meets the panorama's seam (px).
SEAM_PX = 1.0


class OnnxModelError(ValueError):
    """The ONNX model cannot be used (missing, unreadable, or not the YOLOv8 layout)."""


class Letterbox:
    """The resize-and-pad that maps a W×H frame onto the model's input, and its inverse."""

    def __init__(self, width: int, height: int, in_w: int, in_h: int) -> None:
        self.width, self.height, self.in_w, self.in_h = width, height, in_w, in_h
        r = min(in_w / width, in_h / height)
        self.new_w = max(1, min(in_w, round(width * r)))
        self.new_h = max(1, min(in_h, round(height * r)))
        dw, dh = (in_w - self.new_w) / 2.0, (in_h - self.new_h) / 2.0
        self.left, self.top = round(dw - 0.1), round(dh - 0.1)
        self.sx, self.sy = self.new_w / width, self.new_h / height
        self._canvas = np.full((in_h, in_w, 3), PAD_VALUE, np.uint8)

    def apply(self, image_bgr: np.ndarray) -> np.ndarray:
        """The model's input image (in_h, in_w, 3) BGR uint8 (a buffer reused per call)."""
        if (self.new_w, self.new_h) == (self.width, self.height):
            resized = image_bgr
        else:
            resized = cv2.resize(
                image_bgr, (self.new_w, self.new_h), interpolation=cv2.INTER_LINEAR
            )
        self._canvas[self.top : self.top + self.new_h, self.left : self.left + self.new_w] = resized
        return self._canvas

    def to_image(self, x_in: np.ndarray, y_in: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Input-pixel coordinates → frame pixels (continuous, both sides)."""
        return (x_in - self.left) / self.sx, (y_in - self.top) / self.sy


class OnnxDetector(DetectorBackend):
    """YOLOv8-layout ONNX detector through ``cv2.dnn`` (see the module docstring)."""

    backend = "onnx"

    def __init__(self, camera: CameraModel, config: DetectionConfig, model: bytes) -> None:
        """``model``: the bytes of the ONNX file ``config.onnx_model`` names (read by the
        caller; the path only names the model in errors)."""
        super().__init__(camera)
        self.config = config
        where = config.onnx_model
        try:
            self.net = cv2.dnn.readNetFromONNX(np.frombuffer(model, dtype=np.uint8))
        except cv2.error as exc:
            raise OnnxModelError(
                f"onnx_model {where!r}: OpenCV cannot read it as an ONNX model ({_first_line(exc)})"
            ) from None
        in_w, in_h = config.onnx_input_size
        self.letterbox = Letterbox(camera.width, camera.height, in_w, in_h)
        self.geometry = BoxGeometry(camera, config.box_radius)
        self._wrap = wraps_around(camera)
        # One forward pass on a grey frame: the output layout is checked once, here.
        shape = self._forward(np.full((camera.height, camera.width, 3), PAD_VALUE, np.uint8)).shape
        self.n_classes = _check_layout(shape, config.onnx_class_names, where)
        if config.onnx_class_names:
            self.class_names = tuple(config.onnx_class_names)
        elif self.n_classes == len(COCO_NAMES):
            self.class_names = COCO_NAMES
        else:
            self.class_names = tuple(str(i) for i in range(self.n_classes))
        keep = set(config.classes)
        self._class_ok = np.array([not keep or n in keep for n in self.class_names], dtype=bool)

    def detect(self, image_bgr: np.ndarray, frame_time_us: int = 0) -> list[Detection]:
        """The model's boxes in one BGR uint8 frame, highest score first."""
        cam = self.camera
        if image_bgr.shape != (cam.height, cam.width, 3) or image_bgr.dtype != np.uint8:
            raise ValueError(
                f"expected a {cam.width}x{cam.height} BGR uint8 image, got shape "
                f"{image_bgr.shape} dtype {image_bgr.dtype}"
            )
        boxes = self.decode(self._forward(image_bgr))
        dets = [d for d in map(self.geometry.detection, boxes) if d is not None]
        return select(dets, self.config)

    def decode(self, output: np.ndarray) -> list[Box]:
        """Boxes in frame pixels from one output tensor ``(1, 4 + n_classes, N)``."""
        pred = np.asarray(output, dtype=np.float32).reshape(output.shape[1], output.shape[2])
        scores = pred[4:]
        cls = np.argmax(scores, axis=0)
        conf = scores[cls, np.arange(scores.shape[1])]
        keep = (conf >= self.config.min_score) & self._class_ok[cls]
        if not np.any(keep):
            return []
        cx, cy, w, h = (pred[i, keep].astype(np.float64) for i in range(4))
        conf, cls = conf[keep], cls[keep]
        xywh = np.stack([cx - 0.5 * w, cy - 0.5 * h, w, h], axis=1)
        kept = cv2.dnn.NMSBoxesBatched(
            xywh,  # type: ignore[arg-type]  # OpenCV takes an (N, 4) array
            conf.astype(np.float32),
            cls.astype(np.int32),
            self.config.min_score,
            self.config.onnx_nms_iou,
        )
        idx = np.asarray(kept, dtype=np.int64).reshape(-1)
        x0, y0 = self.letterbox.to_image(xywh[idx, 0], xywh[idx, 1])
        x1, y1 = self.letterbox.to_image(xywh[idx, 0] + xywh[idx, 2], xywh[idx, 1] + xywh[idx, 3])
        W, H = float(self.camera.width), float(self.camera.height)
        out = []
        for k, i in enumerate(idx):
            box = Box(
                float(np.clip(x0[k], 0.0, W)),
                float(np.clip(y0[k], 0.0, H)),
                float(np.clip(x1[k], 0.0, W)),
                float(np.clip(y1[k], 0.0, H)),
                float(conf[i]),
                self.class_names[int(cls[i])],
            )
            if box.x_max > box.x_min and box.y_max > box.y_min:
                out.append(box)
        return _merge_seam(out, W) if self._wrap else out

    def _forward(self, image_bgr: np.ndarray) -> np.ndarray:
        lb = self.letterbox
        blob = cv2.dnn.blobFromImage(
            lb.apply(image_bgr), 1.0 / 255.0, (lb.in_w, lb.in_h), swapRB=True, crop=False
        )
        try:
            self.net.setInput(blob)
            out = self.net.forward()
        except cv2.error as exc:
            raise OnnxModelError(
                f"onnx_model {self.config.onnx_model!r}: the forward pass on a "
                f"{lb.in_w}x{lb.in_h} input failed (is onnx_input_size the model's input "
                f"size, width and height?): {_first_line(exc)}"
            ) from None
        return np.asarray(out)


def _check_layout(shape: tuple[int, ...], class_names: tuple[str, ...], where: str) -> int:
    """The number of classes of a YOLOv8 output of this shape; OnnxModelError if it is not
    one."""
    expect = "YOLOv8 layout (1, 4 + classes, N)"
    if len(shape) != 3 or shape[0] != 1:
        raise OnnxModelError(
            f"onnx_model {where!r}: output shape {tuple(shape)}, expected {expect}"
        )
    _, channels, n = shape
    if class_names:
        want = 4 + len(class_names)
        if channels != want:
            hint = (
                " (transposed: (1, N, 4 + classes)? export with Ultralytics' YOLOv8 or later)"
                if n == want
                else " (a YOLOv5/v7 export with an objectness column, 5 + classes?)"
                if channels == want + 1 or n == want + 1
                else ""
            )
            raise OnnxModelError(
                f"onnx_model {where!r}: output shape {tuple(shape)}, expected (1, {want}, N) "
                f"for {len(class_names)} onnx_class_names{hint}"
            )
        return len(class_names)
    if channels < 5 or channels > n:
        raise OnnxModelError(
            f"onnx_model {where!r}: output shape {tuple(shape)} is not the {expect} with more "
            "candidates than channels; give onnx_class_names if the model has that layout"
        )
    return channels - 4


def _merge_seam(boxes: list[Box], width: float) -> list[Box]:
    """On a full panorama: a box at the left edge and one of the same class at the right
    edge, over the same rows (vertical overlap ≥ half the shorter), are one object."""
    left = [b for b in boxes if b.x_min <= SEAM_PX]
    right = [b for b in boxes if b.x_max >= width - SEAM_PX]
    used: set[int] = set()
    merged: list[Box] = []
    for a in right:
        for b in left:
            if id(b) in used or id(a) in used or a is b or a.label != b.label:
                continue
            overlap = min(a.y_max, b.y_max) - max(a.y_min, b.y_min)
            if overlap >= 0.5 * min(a.y_max - a.y_min, b.y_max - b.y_min):
                used.update((id(a), id(b)))
                merged.append(
                    Box(
                        a.x_min,
                        min(a.y_min, b.y_min),
                        b.x_max,
                        max(a.y_max, b.y_max),
                        max(a.score, b.score),
                        a.label,
                    )
                )
    return [b for b in boxes if id(b) not in used] + merged


def _first_line(exc: BaseException) -> str:
    lines = [s.strip() for s in str(exc).strip().splitlines() if s.strip()]
    return lines[-1] if lines else type(exc).__name__
