"""Small ONNX descriptor models built with the ``onnx`` helper API, and NumPy twins of their graphs.

Two architectures in the shape of the public ones: a convolution + ReLU, then either
GeM pooling (Radenovic 2019, as CosPlace and EigenPlaces aggregate) or a NetVLAD-style
aggregation (Arandjelovic 2016: soft assignment by a 1x1 convolution, residuals to
cluster centres), then a linear projection. The weights are drawn from a seeded
generator, so a model's bytes are the same on every machine.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np

Aggregation = Literal["gem", "netvlad"]


def weights(seed: int = 0, channels: int = 3, features: int = 8, clusters: int = 4, out: int = 16,
            aggregation: Aggregation = "gem") -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    w = {
        "conv_w": rng.normal(0, 0.5, (features, channels, 3, 3)).astype(np.float32),
        "conv_b": rng.normal(0, 0.1, features).astype(np.float32),
    }
    if aggregation == "netvlad":
        w["assign_w"] = rng.normal(0, 1.0, (clusters, features, 1, 1)).astype(np.float32)
        w["centres"] = rng.normal(0, 0.5, (clusters, features)).astype(np.float32)
        width = clusters * features
    else:
        width = features
    w["proj"] = rng.normal(0, 1.0, (width, out)).astype(np.float32)
    return w


def build_model(path: Path, seed: int = 0, channels: int = 3, aggregation: Aggregation = "gem",
                height: int | str = "H", width: int | str = "W", batch: int | str = "N",
                layout: Literal["nchw", "nhwc"] = "nchw", nan: bool = False) -> Path:
    """Write an ONNX model (opset 17) taking (N, C, H, W) float32, giving ``descriptor`` (N, D).
    String dimensions are dynamic. ``nan``: the output is multiplied by NaN (for refusals)."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    w = weights(seed, channels, aggregation=aggregation)
    inits = [numpy_helper.from_array(v, k) for k, v in w.items()]
    const = {"p": 3.0, "inv_p": 1 / 3.0, "eps": 1e-6, "nan": float("nan")}
    inits += [numpy_helper.from_array(np.array(v, np.float32), k) for k, v in const.items()]
    nodes = []
    first = "image"
    if layout == "nhwc":
        nodes.append(helper.make_node("Transpose", ["image"], ["nchw"], perm=[0, 3, 1, 2]))
        first = "nchw"
    nodes += [helper.make_node("Conv", [first, "conv_w", "conv_b"], ["conv"], pads=[1, 1, 1, 1]),
              helper.make_node("Relu", ["conv"], ["feat"])]
    if aggregation == "gem":
        nodes += [helper.make_node("Max", ["feat", "eps"], ["clamped"]),
                  helper.make_node("Pow", ["clamped", "p"], ["cubed"]),
                  helper.make_node("GlobalAveragePool", ["cubed"], ["pooled"]),
                  helper.make_node("Pow", ["pooled", "inv_p"], ["gem"]),
                  helper.make_node("Flatten", ["gem"], ["aggregated"], axis=1)]
    else:
        inits += [numpy_helper.from_array(np.array(s, np.int64), k) for k, s in
                  (("flat3", [0, 0, -1]), ("flat2", [0, -1]), ("ax2", [2]), ("ax1", [1]))]
        nodes += [helper.make_node("Conv", ["feat", "assign_w"], ["logits"]),
                  helper.make_node("Softmax", ["logits"], ["soft"], axis=1),
                  helper.make_node("Reshape", ["soft", "flat3"], ["a"]),         # (N, K, HW)
                  helper.make_node("Reshape", ["feat", "flat3"], ["x"]),         # (N, F, HW)
                  helper.make_node("Transpose", ["x"], ["xt"], perm=[0, 2, 1]),  # (N, HW, F)
                  helper.make_node("MatMul", ["a", "xt"], ["ax"]),               # (N, K, F)
                  helper.make_node("ReduceSum", ["a", "ax2"], ["mass"], keepdims=1),  # (N, K, 1)
                  helper.make_node("Mul", ["mass", "centres"], ["shift"]),
                  helper.make_node("Sub", ["ax", "shift"], ["vlad"]),
                  helper.make_node("Reshape", ["vlad", "flat2"], ["aggregated"])]
    last = "descriptor_raw" if nan else "descriptor"
    nodes.append(helper.make_node("MatMul", ["aggregated", "proj"], [last]))
    if nan:
        nodes.append(helper.make_node("Mul", [last, "nan"], ["descriptor"]))
    dims = [batch, channels, height, width] if layout == "nchw" else [batch, height, width, channels]
    graph = helper.make_graph(
        nodes, "tiny_descriptor",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, dims)],
        [helper.make_tensor_value_info("descriptor", TensorProto.FLOAT, [batch, w["proj"].shape[1]])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="slamfront-tests")
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, str(path))
    return path


def reference(tensor: np.ndarray, seed: int = 0, aggregation: Aggregation = "gem") -> np.ndarray:
    """The graph of :func:`build_model` in NumPy (float64), for an (N, C, H, W) input."""
    x = tensor.astype(np.float64)
    w = {k: v.astype(np.float64) for k, v in weights(seed, x.shape[1], aggregation=aggregation).items()}
    n, _, h, wd = x.shape
    padded = np.pad(x, ((0, 0), (0, 0), (1, 1), (1, 1)))
    conv = np.zeros((n, w["conv_w"].shape[0], h, wd))
    for i in range(3):
        for j in range(3):
            conv += np.einsum("ncyx,oc->noyx", padded[:, :, i:i + h, j:j + wd], w["conv_w"][:, :, i, j])
    feat = np.maximum(conv + w["conv_b"][None, :, None, None], 0)
    if aggregation == "gem":
        aggregated = np.mean(np.maximum(feat, 1e-6) ** 3, axis=(2, 3)) ** (1 / 3)
    else:
        logits = np.einsum("nfyx,kf->nkyx", feat, w["assign_w"][:, :, 0, 0]).reshape(n, -1, h * wd)
        soft = np.exp(logits - logits.max(axis=1, keepdims=True))
        soft /= soft.sum(axis=1, keepdims=True)
        flat = feat.reshape(n, -1, h * wd)
        vlad = soft @ flat.transpose(0, 2, 1) - soft.sum(axis=2, keepdims=True) * w["centres"][None]
        aggregated = vlad.reshape(n, -1)
    return aggregated @ w["proj"]
