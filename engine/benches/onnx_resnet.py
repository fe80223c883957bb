"""The policy's ResNet-18 image encoder as an ONNX graph, run by ONNX Runtime on one thread: the yardstick of
`cargo bench -p mars-engine` and, in `tests/onnx_peer.rs`, a second implementation that must agree with ours.

The graph is built with the `onnx` package from the very weights the engine reads (a safetensors file written by
candle's VarMap, names as in mars_policy::nn::resnet); nothing is exported from our code. GroupNorm is spelled
as InstanceNormalization over the groups followed by the per-channel scale and shift, which every ONNX Runtime
supports (GroupNormalization changed meaning between opsets 18 and 21).

    python onnx_resnet.py --weights W.safetensors --net-width 16 --head ssm:32 --height 96 --width 96 \
        --image img.f32 [--expect out.f32] [--iters 200]

`--image`: the image as raw little-endian f32, [H, W, 3] (the engine's layout); `--expect`: the engine's output
(raw f32) to compare with. Prints one JSON line: median and p10/p90 latency (ms), output length, max |ORT − expect|.
"""

import argparse
import json
import time

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper
from safetensors.numpy import load_file


class Graph:
    def __init__(self, weights):
        self.w, self.nodes, self.inits, self.n = weights, [], [], 0

    def name(self, base):
        self.n += 1
        return f"{base}_{self.n}"

    def const(self, array, base):
        name = self.name(base)
        self.inits.append(numpy_helper.from_array(np.asarray(array), name))
        return name

    def op(self, kind, inputs, **attrs):
        out = self.name(kind.lower())
        self.nodes.append(helper.make_node(kind, inputs, [out], **attrs))
        return out

    def conv(self, x, prefix, stride):
        weight = self.w[f"{prefix}.weight"]
        k = weight.shape[-1]
        return self.op("Conv", [x, self.const(weight, prefix)], kernel_shape=[k, k], strides=[stride, stride],
                       pads=[k // 2] * 4)

    def group_norm(self, x, prefix, relu):
        gamma, beta = self.w[f"{prefix}.weight"], self.w[f"{prefix}.bias"]
        c = gamma.shape[0]
        g = max(c // 16, 1)
        grouped = self.op("Reshape", [x, self.const(np.array([0, g, -1], np.int64), "shape")])
        normed = self.op("InstanceNormalization", [grouped, self.const(np.ones(g, np.float32), "one"),
                                                    self.const(np.zeros(g, np.float32), "zero")], epsilon=1e-5)
        shaped = self.op("Reshape", [normed, self.shape_of(x)])
        y = self.op("Add", [self.op("Mul", [shaped, self.const(gamma.reshape(c, 1, 1), "gamma")]),
                            self.const(beta.reshape(c, 1, 1), "beta")])
        return self.op("Relu", [y]) if relu else y

    def shape_of(self, x):
        return self.op("Shape", [x])


def build(weights, net_width, head, height, width):
    g = Graph(weights)
    x = g.group_norm(g.conv("image", "stem", 2), "stem_norm", relu=True)
    x = g.op("MaxPool", [x], kernel_shape=[3, 3], strides=[2, 2], pads=[1, 1, 1, 1])
    channels = net_width
    for stage, mult in enumerate([1, 2, 4, 8]):
        out = net_width * mult
        for block in range(2):
            stride = 2 if stage > 0 and block == 0 else 1
            p = f"layer{stage + 1}.{block}"
            y = g.group_norm(g.conv(x, f"{p}.conv1", stride), f"{p}.norm1", relu=True)
            y = g.group_norm(g.conv(y, f"{p}.conv2", 1), f"{p}.norm2", relu=False)
            skip = x
            if stride != 1 or channels != out:
                skip = g.group_norm(g.conv(x, f"{p}.down.conv", stride), f"{p}.down.norm", relu=False)
            x = g.op("Relu", [g.op("Add", [y, skip])])
            channels = out
    if head.startswith("ssm:"):
        k = int(head[4:])
        fh, fw = height, width
        for _ in range(5):  # stem, pool, and three strided stages
            fh, fw = (fh - 1) // 2 + 1, (fw - 1) // 2 + 1
        maps = g.conv(x, "head.keypoints", 1)
        logits = g.op("Reshape", [maps, g.const(np.array([1, k, fh * fw], np.int64), "shape")])
        p = g.op("Softmax", [logits], axis=-1)
        at = lambda i, n: -1.0 + 2.0 * i / (n - 1) if n > 1 else 0.0  # noqa: E731
        coords = np.array([[at(q % fw, fw), at(q // fw, fh)] for q in range(fh * fw)], np.float32)
        xy = g.op("MatMul", [p, g.const(coords, "coords")])  # [1, K, 2]
        out = g.op("Reshape", [g.op("Transpose", [xy], perm=[0, 2, 1]), g.const(np.array([1, 2 * k], np.int64), "s")])
        out_dim = 2 * k
    else:
        out = g.op("Flatten", [g.op("GlobalAveragePool", [x])])
        out_dim = 8 * net_width
    graph = helper.make_graph(
        g.nodes, "mars_resnet18",
        [helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, height, width])],
        [helper.make_tensor_value_info(out, TensorProto.FLOAT, [1, out_dim])],
        g.inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    onnx.checker.check_model(model)
    return model


def main():
    a = argparse.ArgumentParser()
    a.add_argument("--weights", required=True)
    a.add_argument("--net-width", type=int, required=True)
    a.add_argument("--head", required=True, help="ssm:<keypoints> or avg")
    a.add_argument("--height", type=int, required=True)
    a.add_argument("--width", type=int, required=True)
    a.add_argument("--image", required=True)
    a.add_argument("--expect")
    a.add_argument("--iters", type=int, default=1)
    args = a.parse_args()
    model = build(load_file(args.weights), args.net_width, args.head, args.height, args.width)
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    sess = ort.InferenceSession(model.SerializeToString(), opts, providers=["CPUExecutionProvider"])
    hwc = np.fromfile(args.image, dtype="<f4").reshape(args.height, args.width, 3)
    feed = {"image": np.ascontiguousarray(hwc.transpose(2, 0, 1)[None])}
    out = sess.run(None, feed)[0].reshape(-1)
    times = []
    for _ in range(max(args.iters, 1) + min(args.iters, 10)):  # the first few are warm-up
        t = time.perf_counter()
        sess.run(None, feed)
        times.append((time.perf_counter() - t) * 1e3)
    times = sorted(times[min(args.iters, 10):])
    result = {
        "ort_version": ort.__version__,
        "median_ms": times[len(times) // 2],
        "p10_ms": times[len(times) // 10],
        "p90_ms": times[len(times) * 9 // 10],
        "out_len": int(out.size),
    }
    if args.expect:
        want = np.fromfile(args.expect, dtype="<f4")
        result["max_abs_diff"] = float(np.max(np.abs(out - want))) if want.size == out.size else None
    print(json.dumps(result))


if __name__ == "__main__":
    main()
