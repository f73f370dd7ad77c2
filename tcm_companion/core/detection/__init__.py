"""Detection: objects of any kind behind one interface, several backends.

Every backend (:class:`DetectorBackend`) turns a frame into :class:`Detection` s — bearing
in camera FRD, angular radius through the camera model, a confidence, optionally a label
and the pixels or box they came from — so tracking and the classifier do not care which
one found an object. ``[detection] backend`` picks one (:func:`make_detector`):

- ``colour`` (:class:`ColourDetector`, module :mod:`.colour`): colour segmentation of one
  or several target colours, by default the paper's saturated red ball;
- ``boxes`` (:class:`BoxesDetector`, :mod:`.boxes`): boxes from someone else's detector,
  pushed with the capture time of their frame (replay: ``detections.csv``);
- ``onnx`` (:class:`OnnxDetector`, :mod:`.onnx_yolo`): a YOLOv8-layout ONNX model run by
  OpenCV's DNN module.

``Detector`` is the colour backend's class (its name before there were others).
"""

from __future__ import annotations

from ..camera import CameraModel
from .base import (
    Detection,
    DetectorBackend,
    angular_radius_from_solid_angle,
    cap_solid_angle_sr,
    wraps_around,
)
from .boxes import Box, BoxesDetector, BoxGeometry
from .colour import ColourDetector
from .onnx_yolo import OnnxDetector, OnnxModelError
from .settings import BACKENDS, ColourTarget, DetectionConfig

Detector = ColourDetector


def make_detector(
    camera: CameraModel, config: DetectionConfig, model: bytes | None = None
) -> DetectorBackend:
    """The backend ``config.backend`` names, for ``camera``. ``model``: the bytes of the
    model file the onnx backend runs (the caller reads ``config.onnx_model``; see
    :func:`tcm_companion.io.detector_model.read_detector_model`)."""
    if config.backend == "boxes":
        return BoxesDetector(camera, config)
    if config.backend == "onnx":
        if model is None:
            raise OnnxModelError(
                f"onnx_model {config.onnx_model!r}: the model's bytes were not given "
                "(read the file with tcm_companion.io.detector_model.read_detector_model)"
            )
        return OnnxDetector(camera, config, model)
    return ColourDetector(camera, config)


__all__ = [
    "BACKENDS",
    "Box",
    "BoxGeometry",
    "BoxesDetector",
    "ColourDetector",
    "ColourTarget",
    "Detection",
    "DetectionConfig",
    "Detector",
    "DetectorBackend",
    "OnnxDetector",
    "OnnxModelError",
    "angular_radius_from_solid_angle",
    "cap_solid_angle_sr",
    "make_detector",
    "wraps_around",
]
