"""Tiny ONNX graphs in the YOLOv8 output layout, for the onnx detection backend's tests.

No weights can be downloaded for the tests, so these stand in for a detector: a graph
whose output is fixed boxes (decoding, class filter, NMS), one whose box is computed
from the input image (the letterbox end to end: the box of the red pixels it is fed),
and wrongly shaped ones. Built with the ``onnx`` package (dev extra); OpenCV's DNN module
runs them as it would a real export.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17


def _save(model: onnx.ModelProto, path: Path) -> Path:
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def _input(in_w: int, in_h: int) -> onnx.ValueInfoProto:
    return helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, in_h, in_w])


def constant_model(path: Path, columns: np.ndarray, in_w: int = 64, in_h: int = 64) -> Path:
    """A model whose output is ``columns.T[None]``: ``columns`` is (N, 4 + n_classes), one
    candidate per row (cx, cy, w, h in input pixels, then the class scores). The output
    depends on the input (times zero) so that no runtime folds the graph away."""
    const = np.ascontiguousarray(np.asarray(columns, np.float32).T[None])
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=1),
        helper.make_node("Reshape", ["mean", "shape3"], ["mean3"]),
        helper.make_node("Mul", ["mean3", "zero"], ["nothing"]),
        helper.make_node("Add", ["nothing", "const"], ["output0"]),
    ]
    inits = [
        numpy_helper.from_array(const, "const"),
        numpy_helper.from_array(np.zeros((1, 1, 1), np.float32), "zero"),
        numpy_helper.from_array(np.array([1, 1, 1], np.int64), "shape3"),
    ]
    out = helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(const.shape))
    graph = helper.make_graph(nodes, "constant_yolo", [_input(in_w, in_h)], [out], inits)
    return _save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)]), path)


def red_box_model(path: Path, in_w: int, in_h: int) -> Path:
    """A model that finds the red pixels of its input and outputs one candidate, class 0
    with score 1: the centre and size (input pixels) of the box they fill. Channel 0 of
    the input is red (YOLO models take RGB). The box is the weighted centroid and
    ``√12``·standard deviation along each axis of the weight ``relu(R - 2G)``: 1 on pure
    red, 0 on black, on the letterbox's grey and on anything not strongly red (grass,
    sky, brown dirt), linear in coverage across an edge between red and black (the resize
    blends them), so a red rectangle on black is measured exactly (to a few hundredths
    of a pixel), whatever the letterbox put around it."""
    xs = np.arange(in_w, dtype=np.float32) + 0.5  # continuous pixel centres
    ys = np.arange(in_h, dtype=np.float32) + 0.5
    gx, gy = np.meshgrid(xs, ys)
    kernels = np.stack([np.ones_like(gx), gx, gy, gx * gx, gy * gy])[:, None]  # (5,1,H,W)
    red_minus_green = np.array([1.0, -2.0, 0.0], np.float32).reshape(1, 3, 1, 1)

    def gather(i: int, name: str) -> onnx.NodeProto:
        return helper.make_node("Gather", ["moments", f"i{i}"], [name], axis=0)

    nodes = [
        helper.make_node("Conv", ["images", "red_minus_green"], ["above"]),
        helper.make_node("Relu", ["above"], ["weight"]),
        helper.make_node("Conv", ["weight", "kernels"], ["sums"]),  # (1, 5, 1, 1)
        helper.make_node("Reshape", ["sums", "shape5"], ["moments"]),
        gather(0, "s"),
        gather(1, "sx"),
        gather(2, "sy"),
        gather(3, "sxx"),
        gather(4, "syy"),
        helper.make_node("Div", ["sx", "s"], ["cx"]),
        helper.make_node("Div", ["sy", "s"], ["cy"]),
        helper.make_node("Div", ["sxx", "s"], ["exx"]),
        helper.make_node("Div", ["syy", "s"], ["eyy"]),
        helper.make_node("Mul", ["cx", "cx"], ["cx2"]),
        helper.make_node("Mul", ["cy", "cy"], ["cy2"]),
        helper.make_node("Sub", ["exx", "cx2"], ["varx"]),
        helper.make_node("Sub", ["eyy", "cy2"], ["vary"]),
        helper.make_node("Mul", ["varx", "twelve"], ["w2"]),
        helper.make_node("Mul", ["vary", "twelve"], ["h2"]),
        helper.make_node("Sqrt", ["w2"], ["w"]),
        helper.make_node("Sqrt", ["h2"], ["h"]),
        helper.make_node("Concat", ["cx", "cy", "w", "h", "one"], ["column"], axis=0),
        helper.make_node("Reshape", ["column", "out_shape"], ["output0"]),
    ]
    inits = [
        numpy_helper.from_array(red_minus_green, "red_minus_green"),
        numpy_helper.from_array(kernels.astype(np.float32), "kernels"),
        numpy_helper.from_array(np.array([5], np.int64), "shape5"),
        numpy_helper.from_array(np.array([1.0], np.float32), "one"),
        numpy_helper.from_array(np.array([12.0], np.float32), "twelve"),
        numpy_helper.from_array(np.array([1, 5, 1], np.int64), "out_shape"),
        *(numpy_helper.from_array(np.array([i], np.int64), f"i{i}") for i in range(5)),
    ]
    out = helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 5, 1])
    graph = helper.make_graph(nodes, "red_box_yolo", [_input(in_w, in_h)], [out], inits)
    return _save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)]), path)


def shaped_model(path: Path, shape: tuple[int, ...], in_w: int = 64, in_h: int = 64) -> Path:
    """A model whose output (zeros) has ``shape``: for the layout checks."""
    return constant_model_raw(path, np.zeros(shape, np.float32), in_w, in_h)


def constant_model_raw(path: Path, const: np.ndarray, in_w: int = 64, in_h: int = 64) -> Path:
    """A model whose output is ``const`` as it is (any shape)."""
    const = np.ascontiguousarray(const, dtype=np.float32)
    flat = [1] * const.ndim
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["mean"], keepdims=1),
        helper.make_node("Reshape", ["mean", "shape_n"], ["mean_n"]),
        helper.make_node("Mul", ["mean_n", "zero"], ["nothing"]),
        helper.make_node("Add", ["nothing", "const"], ["output0"]),
    ]
    inits = [
        numpy_helper.from_array(const, "const"),
        numpy_helper.from_array(np.zeros(flat, np.float32), "zero"),
        numpy_helper.from_array(np.array(flat, np.int64), "shape_n"),
    ]
    out = helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(const.shape))
    graph = helper.make_graph(nodes, "shaped", [_input(in_w, in_h)], [out], inits)
    return _save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)]), path)
