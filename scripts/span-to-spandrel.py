"""A SPAN network of matup's (models/span_x4_*.onnx) as a PyTorch state dict that spandrel,
and so ComfyUI's "Load Upscale Model", opens as SPAN.

The ONNX file holds each Conv3XC as the one 3×3 convolution it folds into (`eval_conv`);
spandrel rebuilds that convolution from the training branches on every call. So each branch
is written to fold back to the file's weights exactly: the 1×1 convolutions as identities
padded with zeros, the 3×3 as the file's kernel in the corner of a zero one, the skip as
zero. Products with 1 and sums with 0 are exact, so the network computes what the file
does. The input normalisation (mean 0.4488, 0.4371, 0.4040, range 255) is spandrel's own.

Usage: python scripts/span-to-spandrel.py models/span_x4_materials.onnx OUT.safetensors
(needs onnx, torch, safetensors and spandrel). It checks that spandrel loads the result as a
×4 SPAN whose folded kernels equal the file's.
"""

import re
import sys

import numpy as np
import onnx
import torch
from onnx import numpy_helper
from safetensors.torch import save_file

EXPECTED_MEAN = np.array([0.4488, 0.4371, 0.4040], np.float32)


def onnx_weights(path):
    model = onnx.load(path)
    arrays = {i.name: numpy_helper.to_array(i) for i in model.graph.initializer}
    weights = {}
    for name, array in arrays.items():
        # "w_/block_1/c1_r/eval_conv/Conv__11" -> ("weight", "block_1.c1_r.eval_conv")
        found = re.match(r"([wb])_/(.+)/Conv__\d+$", name)
        if found:
            module = found.group(2).replace("/", ".").replace("upsampler.upsampler.0", "upsampler.0")
            weights[(module, "weight" if found.group(1) == "w" else "bias")] = array
    mean = arrays["memorydata_/Constant_output_0__1"].ravel()
    scale = float(arrays["scalar__4"])
    if not (np.array_equal(mean, EXPECTED_MEAN) and scale == 255.0):
        sys.exit(f"{path}: input normalisation {mean}, ×{scale} is not spandrel's SPAN's")
    return weights


def conv3xc(prefix, weight, bias):
    """Training branches of a Conv3XC (gain 2) that fold exactly into `weight`, `bias`."""
    c_out, c_in = weight.shape[:2]
    w = torch.from_numpy(weight.copy())
    b = torch.from_numpy(bias.copy())
    first = torch.zeros(2 * c_in, c_in, 1, 1)
    first[:c_in, :, 0, 0] = torch.eye(c_in)
    middle = torch.zeros(2 * c_out, 2 * c_in, 3, 3)
    middle[:c_out, :c_in] = w
    middle_bias = torch.zeros(2 * c_out)
    middle_bias[:c_out] = b
    last = torch.zeros(c_out, 2 * c_out, 1, 1)
    last[:, :c_out, 0, 0] = torch.eye(c_out)
    return {
        f"{prefix}.sk.weight": torch.zeros(c_out, c_in, 1, 1),
        f"{prefix}.sk.bias": torch.zeros(c_out),
        f"{prefix}.conv.0.weight": first,
        f"{prefix}.conv.0.bias": torch.zeros(2 * c_in),
        f"{prefix}.conv.1.weight": middle,
        f"{prefix}.conv.1.bias": middle_bias,
        f"{prefix}.conv.2.weight": last,
        f"{prefix}.conv.2.bias": torch.zeros(c_out),
        f"{prefix}.eval_conv.weight": w.clone(),
        f"{prefix}.eval_conv.bias": b.clone(),
    }


def state_dict(weights):
    state = {}
    for (module, kind), array in weights.items():
        if module.endswith(".eval_conv"):
            if kind == "weight":
                prefix = module[: -len(".eval_conv")]
                state.update(conv3xc(prefix, array, weights[(module, "bias")]))
        else:
            state[f"{module}.{kind}"] = torch.from_numpy(array.copy())
    return state


def main():
    source, target = sys.argv[1], sys.argv[2]
    weights = onnx_weights(source)
    state = state_dict(weights)
    save_file({k: v.contiguous() for k, v in state.items()}, target)

    import spandrel
    from safetensors.torch import load_file

    model = spandrel.ModelLoader().load_from_state_dict(load_file(target)).eval()
    assert type(model.model).__name__ == "SPAN" and model.scale == 4, model
    for name, module in model.model.named_modules():
        if type(module).__name__ == "Conv3XC":
            module.update_params()
            want = weights[(f"{name}.eval_conv", "weight")]
            assert np.array_equal(module.eval_conv.weight.detach().numpy(), want), name
            assert np.array_equal(module.eval_conv.bias.detach().numpy(), weights[(f"{name}.eval_conv", "bias")]), name
    print(f"{target}: spandrel loads a ×4 SPAN ({len(state)} tensors); every folded kernel equals {source}'s")


if __name__ == "__main__":
    main()
