#!/usr/bin/env python3
"""Another engine's time for matup's network, for comparison with candle's on the same GPU.

A GPU machine with PyTorch has cuDNN, but seldom onnxruntime's CUDA build (onnxruntime-gpu,
a separate package of several hundred MB). PyTorch runs the same cuDNN convolutions that
provider would, so this interprets the shipped ONNX graph (its few
operators) as PyTorch operations and times the SR stage's network work of a 1K² material:
eight 1K² images (four maps, two self-ensemble passes) ×4, whole, in one batch. First it checks
the interpretation against onnxruntime's CPU build on a small input.

Usage: python3 scripts/torch-network-time.py [MODEL.onnx] [SIDE]
       (default models/span_x4_materials.onnx, 1024)
"""
import statistics
import sys
import time

import numpy as np
import onnx
import torch
import torch.nn.functional as F
from onnx import numpy_helper

model_path = sys.argv[1] if len(sys.argv) > 1 else "models/span_x4_materials.onnx"
side = int(sys.argv[2]) if len(sys.argv) > 2 else 1024
graph = onnx.load(model_path).graph


def attributes(node):
    return {a.name: onnx.helper.get_attribute_value(a) for a in node.attribute}


def depth_to_space(x, block, mode):
    b, c, h, w = x.shape
    if mode == b"CRD":
        return F.pixel_shuffle(x, block)
    x = x.reshape(b, block, block, c // (block * block), h, w)
    return x.permute(0, 3, 4, 1, 5, 2).reshape(b, c // (block * block), h * block, w * block)


# Where each value is last read, so that it is let go after (all of a 1K² batch's would not fit).
last_read = {name: k for k, node in enumerate(graph.node) for name in node.input}


def run(x, constants):
    values = dict(constants)
    values[graph.input[0].name] = x
    for k, node in enumerate(graph.node):
        a = attributes(node)
        ins = [values[i] if i else None for i in node.input]
        op = node.op_type
        if op == "Conv":
            pads = a.get("pads", [0, 0, 0, 0])
            assert pads[0] == pads[2] and pads[1] == pads[3], "asymmetric padding"
            out = F.conv2d(ins[0], ins[1], ins[2] if len(ins) > 2 else None,
                           stride=a.get("strides", 1), padding=(pads[0], pads[1]),
                           dilation=a.get("dilations", 1), groups=a.get("group", 1))
        elif op == "Add":
            out = ins[0] + ins[1]
        elif op == "Sub":
            out = ins[0] - ins[1]
        elif op == "Mul":
            out = ins[0] * ins[1]
        elif op == "Sigmoid":
            out = torch.sigmoid(ins[0])
        elif op == "Identity":
            out = ins[0]
        elif op == "Concat":
            out = torch.cat(ins, dim=a["axis"])
        elif op == "Clip":
            lo = ins[1].item() if len(ins) > 1 and ins[1] is not None else None
            hi = ins[2].item() if len(ins) > 2 and ins[2] is not None else None
            out = torch.clamp(ins[0], lo, hi)
        elif op == "DepthToSpace":
            out = depth_to_space(ins[0], a["blocksize"], a.get("mode", b"DCR"))
        else:
            raise SystemExit(f"operator {op} is not interpreted here")
        values[node.output[0]] = out
        for name in node.input:
            if last_read.get(name) == k and name != graph.output[0].name:
                values.pop(name, None)
    return values[graph.output[0].name]


def constants_on(device, dtype):
    out = {}
    for t in graph.initializer:
        v = torch.from_numpy(numpy_helper.to_array(t).copy()).to(device)
        out[t.name] = v.to(dtype) if v.is_floating_point() else v
    return out


# The interpretation, checked against onnxruntime's CPU build.
rng = np.random.default_rng(0)
small = rng.uniform(0.2, 0.8, (2, 3, 48, 48)).astype(np.float32)
try:
    import onnxruntime

    print("onnxruntime", onnxruntime.__version__, "providers:", onnxruntime.get_available_providers())
    session = onnxruntime.InferenceSession(model_path, providers=["CPUExecutionProvider"])
    reference = session.run(None, {graph.input[0].name: small})[0]
    mine = run(torch.from_numpy(small), constants_on("cpu", torch.float32)).numpy()
    print(f"PyTorch interpretation vs onnxruntime CPU, 48² input: max |diff| {np.abs(mine - reference).max():.2e}")
except Exception as e:  # a failed check is reported, and the timings still run
    print("interpretation not checked:", repr(e))

# On a machine without a GPU (a check of this script) the timings run on the CPU.
device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
gpu = device.type == "cuda"
print(torch.cuda.get_device_name(device) if gpu else "CPU", "torch", torch.__version__,
      "cuDNN", torch.backends.cudnn.version())
sync = torch.cuda.synchronize if gpu else (lambda: None)
torch.backends.cudnn.benchmark = True
images = torch.from_numpy(rng.uniform(0.25, 0.75, (8, 3, side, side)).astype(np.float32)).to(device)


def median_seconds(f, runs=5):
    f()
    sync()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        f()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


reference_f32 = None
print(f"| variant ({side}² ×8, ×4) | network s | max |diff| to f32 (8-bit levels) |")
print("|---|---|---|")
for name, dtype, tf32, channels_last in [
    ("f32", torch.float32, False, False),
    ("f32, channels-last", torch.float32, False, True),
    ("tf32", torch.float32, True, False),
    ("f16, channels-last", torch.float16, False, True),
]:
    torch.backends.cuda.matmul.allow_tf32 = tf32
    torch.backends.cudnn.allow_tf32 = tf32
    constants = constants_on(device, dtype)
    x = images.to(dtype)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
        constants = {k: v.contiguous(memory_format=torch.channels_last) if v.dim() == 4 else v
                     for k, v in constants.items()}
    out = {}

    def call():
        with torch.no_grad():
            out["y"] = run(x, constants)

    try:
        seconds = median_seconds(call)
    except Exception as e:  # one variant failing leaves the others' numbers
        print(f"| {name} | failed: {e!r} | |")
        continue
    y = out["y"].float()
    if reference_f32 is None:
        reference_f32 = y
        diff = 0.0
    else:
        diff = (y - reference_f32).abs().max().item() * 255
    print(f"| {name} | {seconds:.3f} | {diff:.2f} |")
    del out, constants, x
    if gpu:
        torch.cuda.empty_cache()

download = median_seconds(lambda: reference_f32.cpu())
print(f"download of the eight f32 outputs ({reference_f32.numel() * 4 / 1e9:.2f} GB): {download:.3f} s")
