"""The detector's model file, read at the edge: the core is given its bytes.

``[detection] onnx_model`` names a file; whoever builds a pipeline from the configuration
(the daemon, replay, eval, the benches) reads it here once and hands the bytes to
:class:`~tcm_companion.core.pipeline.Pipeline` (``detector_model``), so the detector in
the core opens no file.
"""

from __future__ import annotations

from pathlib import Path

from ..core.detection import DetectionConfig, OnnxModelError


def read_detector_model(config: DetectionConfig) -> bytes | None:
    """The bytes of the model file ``config`` names, or None when its backend needs none.

    Raises :class:`~tcm_companion.core.detection.OnnxModelError` (one line naming the
    file) when the file is missing or cannot be read."""
    if config.backend != "onnx":
        return None
    path = Path(config.onnx_model)
    if not path.is_file():
        raise OnnxModelError(f"onnx_model {str(path)!r}: no such file")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise OnnxModelError(
            f"onnx_model {str(path)!r}: OpenCV cannot read it as an ONNX model "
            f"({exc.strerror or type(exc).__name__})"
        ) from None
