#!/usr/bin/env python3
"""Convert a Darknet model (cfg + weights) to ONNX, with numpy and onnx only.

    python3 tools/darknet_to_onnx.py yolov4-tiny.cfg yolov4-tiny.weights out.onnx [WxH]

WxH (multiples of 32, say 320x256) replaces the cfg's network size: a Darknet model runs
at any such size with the same weights, and a smaller one sees close, large objects
whole (tools/setup.sh converts YOLOv4-tiny at 416x416 and 320x256).

Supported: [convolutional] (batch norm folded into the weights; leaky, linear,
logistic, mish activations; groups), [route] (several layers, or `groups`/`group_id`
for a channel slice), [shortcut] (linear), [maxpool] (Darknet's padding: size-1 in all,
size-1 // 2 before), [upsample], [yolo]. The [yolo] heads are decoded in the graph so
the output `detections` is [1, N, 85]: cx, cy, w, h in input pixels, objectness and
80 class scores (all after the logistic). The input `images` is [1, 3, H, W], RGB
scaled to [0, 1], the image resized to the network size (no letterbox).

The weights file is read to its last byte; bytes left over (a cfg that does not match
the weights) are an error.
"""
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper


def parse_cfg(path):
    sections = []
    for raw in open(path, encoding="utf-8"):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        if line.startswith("["):
            sections.append({"type": line.strip("[]").strip()})
        elif "=" in line:
            key, value = line.split("=", 1)
            sections[-1][key.strip()] = value.strip()
    if not sections or sections[0]["type"] not in ("net", "network"):
        raise SystemExit(f"{path}: the first section must be [net]")
    return sections[0], sections[1:]


class Weights:
    def __init__(self, path):
        self.path = path
        self.data = open(path, "rb").read()
        major, minor, _revision = np.frombuffer(self.data[:12], dtype=np.int32)
        seen_bytes = 8 if (major * 10 + minor) >= 2 and major < 1000 else 4
        self.offset = 12 + seen_bytes

    def take(self, count):
        end = self.offset + 4 * count
        if end > len(self.data):
            raise SystemExit(f"{self.path}: ends after {len(self.data)} bytes, the cfg needs more")
        values = np.frombuffer(self.data[self.offset:end], dtype=np.float32).copy()
        self.offset = end
        return values

    def finish(self):
        left = len(self.data) - self.offset
        if left:
            raise SystemExit(f"{self.path}: {left} bytes left after the last layer: cfg and weights do not match")


class Graph:
    def __init__(self):
        self.nodes, self.initialisers, self.count = [], [], 0

    def name(self, stem):
        self.count += 1
        return f"{stem}_{self.count}"

    def const(self, array, stem="c"):
        name = self.name(stem)
        self.initialisers.append(numpy_helper.from_array(np.asarray(array), name))
        return name

    def op(self, kind, inputs, stem=None, **attrs):
        out = self.name(stem or kind.lower())
        self.nodes.append(helper.make_node(kind, inputs, [out], **attrs))
        return out


def activation(g, x, kind):
    if kind == "linear":
        return x
    if kind == "leaky":
        return g.op("LeakyRelu", [x], alpha=0.1)
    if kind == "logistic":
        return g.op("Sigmoid", [x])
    if kind == "mish":
        return g.op("Mul", [x, g.op("Tanh", [g.op("Softplus", [x])])])
    raise SystemExit(f"activation {kind} is not supported")


def convert(cfg_path, weights_path, out_path, size=None):
    net, layers = parse_cfg(cfg_path)
    if size:
        try:
            w, h = (int(v) for v in size.lower().split("x"))
        except ValueError:
            raise SystemExit(f"size {size!r} is not WxH")
        if w <= 0 or h <= 0 or w % 32 or h % 32:
            raise SystemExit(f"size {size}: width and height must be positive multiples of 32")
        net["width"], net["height"] = str(w), str(h)
    width, height, channels = int(net["width"]), int(net["height"]), int(net.get("channels", 3))
    weights = Weights(weights_path)
    g = Graph()
    outputs = []  # per layer: (tensor name, channels, height, width)
    current = ("images", channels, height, width)
    heads = []
    for index, layer in enumerate(layers):
        kind = layer["type"]
        x, c, h, w = current
        if kind == "convolutional":
            filters, size = int(layer["filters"]), int(layer["size"])
            stride, groups = int(layer.get("stride", 1)), int(layer.get("groups", 1))
            pad = size // 2 if int(layer.get("pad", 0)) else int(layer.get("padding", 0))
            biases = weights.take(filters)
            if int(layer.get("batch_normalize", 0)):
                scales, mean, variance = weights.take(filters), weights.take(filters), weights.take(filters)
            kernel = weights.take(filters * (c // groups) * size * size).reshape(filters, c // groups, size, size)
            if int(layer.get("batch_normalize", 0)):
                # Darknet normalises with (x - mean) / (sqrt(var) + 1e-6).
                factor = scales / (np.sqrt(variance) + 1e-6)
                kernel = kernel * factor[:, None, None, None]
                biases = biases - mean * factor
            y = g.op("Conv", [x, g.const(kernel.astype(np.float32), "w"), g.const(biases.astype(np.float32), "b")],
                     kernel_shape=[size, size], strides=[stride, stride], pads=[pad] * 4, group=groups)
            y = activation(g, y, layer.get("activation", "logistic"))
            h, w = (h + 2 * pad - size) // stride + 1, (w + 2 * pad - size) // stride + 1
            current = (y, filters, h, w)
        elif kind == "route":
            sources = [int(v) for v in layer["layers"].split(",")]
            sources = [outputs[index + s] if s < 0 else outputs[s] for s in sources]
            groups, group_id = int(layer.get("groups", 1)), int(layer.get("group_id", 0))
            if groups > 1:
                if len(sources) != 1:
                    raise SystemExit(f"layer {index}: route groups with several layers is not supported")
                name, sc, sh, sw = sources[0]
                part = sc // groups
                y = g.op("Slice", [name, g.const(np.array([group_id * part], np.int64)),
                                   g.const(np.array([(group_id + 1) * part], np.int64)),
                                   g.const(np.array([1], np.int64))])
                current = (y, part, sh, sw)
            elif len(sources) == 1:
                current = sources[0]
            else:
                y = g.op("Concat", [s[0] for s in sources], axis=1)
                current = (y, sum(s[1] for s in sources), sources[0][2], sources[0][3])
        elif kind == "shortcut":
            other = outputs[index + int(layer["from"])] if int(layer["from"]) < 0 else outputs[int(layer["from"])]
            y = activation(g, g.op("Add", [x, other[0]]), layer.get("activation", "linear"))
            current = (y, c, h, w)
        elif kind == "maxpool":
            size, stride = int(layer["size"]), int(layer.get("stride", 1))
            padding = int(layer.get("padding", size - 1))
            before = padding // 2
            out_h, out_w = (h + padding - size) // stride + 1, (w + padding - size) // stride + 1
            after_h = (out_h - 1) * stride + size - h - before
            after_w = (out_w - 1) * stride + size - w - before
            y = g.op("MaxPool", [x], kernel_shape=[size, size], strides=[stride, stride],
                     pads=[before, before, max(after_h, 0), max(after_w, 0)])
            current = (y, c, out_h, out_w)
        elif kind == "upsample":
            stride = int(layer.get("stride", 2))
            y = g.op("Resize", [x, "", g.const(np.array([1, 1, stride, stride], np.float32))], mode="nearest")
            current = (y, c, h * stride, w * stride)
        elif kind == "yolo":
            heads.append(decode_yolo(g, layer, x, c, h, w, width, height))
        else:
            raise SystemExit(f"layer {index}: [{kind}] is not supported")
        outputs.append(current)
    weights.finish()
    if not heads:
        raise SystemExit(f"{cfg_path}: no [yolo] layer")
    detections = g.op("Concat", heads, stem="detections", axis=1)
    g.nodes.append(helper.make_node("Identity", [detections], ["detections"]))
    graph = helper.make_graph(
        g.nodes, "darknet",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, channels, height, width])],
        [helper.make_tensor_value_info("detections", TensorProto.FLOAT, [1, None, None])],
        g.initialisers)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)], producer_name="dopslam")
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, out_path)


def decode_yolo(g, layer, x, c, h, w, net_w, net_h):
    """[1, A*(5+C), H, W] raw -> [1, A*H*W, 5+C] decoded (cx, cy, w, h in pixels)."""
    mask = [int(v) for v in layer["mask"].split(",")]
    anchors = np.array([float(v) for v in layer["anchors"].split(",")], np.float32).reshape(-1, 2)[mask]
    classes = int(layer["classes"])
    scale = float(layer.get("scale_x_y", 1.0))
    per = 5 + classes
    n = len(mask)
    if c != n * per:
        raise SystemExit(f"[yolo] expects {n * per} channels, got {c}")
    raw = g.op("Reshape", [x, g.const(np.array([1, n, per, h, w], np.int64))])
    raw = g.op("Transpose", [raw], perm=[0, 1, 3, 4, 2])
    raw = g.op("Reshape", [raw, g.const(np.array([1, n * h * w, per], np.int64))])
    sig = g.op("Sigmoid", [raw])

    def part(tensor, start, end):
        return g.op("Slice", [tensor, g.const(np.array([start], np.int64)), g.const(np.array([end], np.int64)),
                              g.const(np.array([2], np.int64))])

    gy, gx = np.meshgrid(np.arange(h, dtype=np.float32), np.arange(w, dtype=np.float32), indexing="ij")
    grid = np.stack([gx, gy], -1).reshape(1, 1, h * w, 2).repeat(n, 1).reshape(1, n * h * w, 2)
    cell = np.array([net_w / w, net_h / h], np.float32)
    # cx = (sigmoid(tx) * s - (s - 1) / 2 + grid_x) * stride.
    xy = g.op("Mul", [part(sig, 0, 2), g.const(np.float32(scale) * cell)])
    xy = g.op("Add", [xy, g.const(((grid - (scale - 1) / 2) * cell).astype(np.float32))])
    sizes = np.repeat(anchors[:, None, :], h * w, 1).reshape(1, n * h * w, 2).astype(np.float32)
    wh = g.op("Mul", [g.op("Exp", [part(raw, 2, 4)]), g.const(sizes)])
    return g.op("Concat", [xy, wh, part(sig, 4, per)], axis=2)


if __name__ == "__main__":
    if len(sys.argv) not in (4, 5):
        raise SystemExit(__doc__)
    convert(*sys.argv[1:])
    print(f"wrote {sys.argv[3]}")
