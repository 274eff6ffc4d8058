"""The joint-refinement study (issue 78): one small network that sees every map of a material
at once and corrects all of them together, after matup's per-map route. A PyTorch prototype,
trained in render space with the loss that tuned matup's network (renders under random lights,
L1, plus the normals' chordal term at 0.5), judged by `matup eval` as the sweeps judge.

Data: `matup sweep` with `view = true` keeps, per material, the truth (512² crop) and the
defaults' ×4 output of its 128² box-filtered input (`outputs/MATERIAL/{truth,matup}/`).
The training sets are the corpus's train sets and the extra CC0 sets at two crop offsets; the
corpus's six val sets choose the checkpoint; the ten shared materials are the test.

The stage: the HR maps (base colour and normal as stored codes, roughness, metallic, height:
9 channels) space-to-depth by 4 to the input's resolution, a few 3×3 convolutions there,
depth-to-space back to a correction of base colour, normal, roughness and metallic, each
4×4 block's mean taken out (so the output box-filters back to the defaults' output, which
box-filters back to the input), added to the defaults' maps. The last convolution starts at
zero, so training starts from today's defaults.

Usage (torch, numpy, pillow; `matup` on PATH for the evaluation):
  python docs/experiments/2026-11-29-joint-refinement.py train --width 64 --depth 4 --steps 3000 \
      --data DIR [DIR...] --out RUN
  python docs/experiments/2026-11-29-joint-refinement.py apply --run RUN --step N --data EVAL_DIR --out OUT
"""

import argparse
import json
import math
import os
import random
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from PIL import Image

MAPS = ("baseColor", "normal", "roughness", "metallic", "height")
# Channels of each map in the network's input; the first four maps are corrected.
CHANNELS = {"baseColor": 3, "normal": 3, "roughness": 1, "metallic": 1, "height": 1}
# What a map not written stands for (matup writes a stand-in only where it differs).
MISSING = {"metallic": 0.0, "height": 0.5, "roughness": 0.5}
CORRECTED = 8  # base colour 3, normal 3, roughness, metallic
LIGHT_DISTANCE, LIGHT_INTENSITY, LOW_ELEVATION = 1.4, 8.0, 0.1
MIN_ALPHA = 1e-3
NORMAL_WEIGHT = 0.5


def read_folder(folder: Path) -> np.ndarray:
    """A material folder's maps as one C×H×W uint8 stack, in MAPS order (codes as stored)."""
    planes, size = [], None
    for name in MAPS:
        path = folder / f"{name}.png"
        if path.exists():
            image = np.asarray(Image.open(path))
            image = image[:, :, None] if image.ndim == 2 else image
            image = image[:, :, : CHANNELS[name]]
            if image.shape[2] < CHANNELS[name]:
                image = np.repeat(image[:, :, :1], CHANNELS[name], axis=2)
            size = image.shape[:2]
            planes.append(image.transpose(2, 0, 1))
        else:
            planes.append(None)
    for i, name in enumerate(MAPS):
        if planes[i] is None:
            planes[i] = np.full((CHANNELS[name], *size), round(MISSING[name] * 255), np.uint8)
    return np.concatenate(planes, 0)


def pairs(roots):
    """(defaults' output, truth) stacks of every material kept under `roots`."""
    found = []
    for root in roots:
        for material in sorted(Path(root, "outputs").iterdir()):
            if (material / "truth").is_dir() and (material / "matup").is_dir():
                found.append((material.name, read_folder(material / "matup"), read_folder(material / "truth")))
    return found


class JointRefinement(torch.nn.Module):
    """Every map at once, at the input's resolution (space-to-depth by `scale`)."""

    def __init__(self, width: int, depth: int, scale: int = 4, projected: bool = True):
        super().__init__()
        self.scale, self.projected = scale, projected
        inputs = sum(CHANNELS.values()) * scale * scale
        layers = [torch.nn.Conv2d(inputs, width, 3, padding=1), torch.nn.ReLU()]
        for _ in range(depth - 2):
            layers += [torch.nn.Conv2d(width, width, 3, padding=1), torch.nn.ReLU()]
        self.body = torch.nn.Sequential(*layers)
        self.last = torch.nn.Conv2d(width, CORRECTED * scale * scale, 3, padding=1)
        torch.nn.init.zeros_(self.last.weight)
        torch.nn.init.zeros_(self.last.bias)

    def forward(self, maps: torch.Tensor) -> torch.Tensor:
        """`maps` N×9×H×W codes in [0, 1] → the corrected first 8 channels."""
        x = F.pixel_unshuffle(maps * 2 - 1, self.scale)
        correction = F.pixel_shuffle(self.last(self.body(x)), self.scale)
        if self.projected:
            # Each block's mean out: the output box-filters back to the defaults' output.
            block_mean = F.avg_pool2d(correction, self.scale)
            correction = correction - F.interpolate(block_mean, scale_factor=self.scale, mode="nearest")
        return (maps[:, :CORRECTED] + correction).clamp(0, 1)


def srgb_to_linear(c):
    return torch.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c):
    c = c.clamp(min=0)
    return torch.where(c <= 0.0031308, c * 12.92, 1.055 * c.clamp(min=1e-8) ** (1 / 2.4) - 0.055)


def render(maps: torch.Tensor, lights: torch.Tensor) -> torch.Tensor:
    """Display-space GGX renders (matup's `ggx`, METHOD.md's display transform) of N×8×H×W
    codes under N×L point lights (positions): N×L×3×H×W."""
    n_, _, h, w = maps.shape
    base = srgb_to_linear(maps[:, 0:3])
    normal = F.normalize(maps[:, 3:6] * 2 - 1, dim=1)
    alpha = (maps[:, 6:7] ** 2).clamp(MIN_ALPHA, 1)
    metal = maps[:, 7:8]
    ys = (torch.arange(h) + 0.5) / h * 2 - 1
    xs = (torch.arange(w) + 0.5) / w * 2 - 1
    pos = torch.stack([xs[None, :].expand(h, w), ys[:, None].expand(h, w), torch.zeros(h, w)])
    out = []
    view = torch.tensor([0.0, 0.0, 1.0]).view(1, 3, 1, 1)
    for li in range(lights.shape[1]):
        to_light = lights[:, li].view(n_, 3, 1, 1) - pos[None]
        l = F.normalize(to_light, dim=1)
        hv = F.normalize(l + view, dim=1)
        nol = (normal * l).sum(1, keepdim=True).clamp(min=0)
        nov = normal[:, 2:3].clamp(min=0)
        noh_raw = (normal * hv).sum(1, keepdim=True)
        loh_raw = (l * hv).sum(1, keepdim=True)
        chi = ((noh_raw > 0) & (loh_raw > 0)).float()
        noh, loh = noh_raw.clamp(0, 1), loh_raw.clamp(0, 1)
        a2 = alpha * alpha
        d = a2 / (math.pi * (noh * noh * (a2 - 1) + 1) ** 2).clamp(min=1e-7)
        gv = (nov * nov * (1 - a2) + a2).sqrt()
        gl = (nol * nol * (1 - a2) + a2).sqrt()
        vis = 0.5 / (nol * gv + nov * gl).clamp(min=1e-7)
        schlick = (1 - loh) ** 5
        f0 = 0.04 * (1 - metal) + metal * base
        fresnel = f0 * (1 - schlick) + schlick
        radiance = LIGHT_INTENSITY * nol * ((1 - metal) * base / math.pi + chi * d * vis * fresnel)
        out.append(linear_to_srgb(radiance / (1 + radiance)))
    return torch.stack(out, 1)


def random_lights(n: int, count: int) -> torch.Tensor:
    """`count` random upper-hemisphere point lights a crop, lifted off grazing as matup's are."""
    d = F.normalize(torch.randn(n, count, 3), dim=2)
    d[..., 2] = d[..., 2].abs()
    low = d[..., 2] < LOW_ELEVATION
    d[..., 2] = torch.where(low, d[..., 2].clamp(min=0).sqrt(), d[..., 2])
    return F.normalize(d, dim=2) * LIGHT_DISTANCE


def loss_of(pred: torch.Tensor, truth: torch.Tensor, lights: int) -> torch.Tensor:
    """matup learn's loss: L1 of the renders over colour and lights, plus the normals' chordal
    distance at NORMAL_WEIGHT."""
    light_set = random_lights(pred.shape[0], lights)
    renders = (render(pred, light_set) - render(truth, light_set)).abs().mean()
    n_pred = F.normalize(pred[:, 3:6] * 2 - 1, dim=1)
    n_true = F.normalize(truth[:, 3:6] * 2 - 1, dim=1)
    return renders + NORMAL_WEIGHT * (n_pred - n_true).norm(dim=1).mean()


def batch_of(samples, size: int, crop: int):
    inputs, truths = [], []
    for _ in range(size):
        _, up, truth = random.choice(samples)
        h, w = up.shape[1:]
        y = random.randrange(0, (h - crop) // 4 + 1) * 4
        x = random.randrange(0, (w - crop) // 4 + 1) * 4
        inputs.append(up[:, y : y + crop, x : x + crop])
        truths.append(truth[:CORRECTED, y : y + crop, x : x + crop])
    to = lambda a: torch.from_numpy(np.stack(a)).float() / 255.0  # noqa: E731
    return to(inputs), to(truths)


def train(args):
    torch.manual_seed(args.seed)
    random.seed(args.seed)
    torch.set_num_threads(args.threads)
    samples = pairs(args.data)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(vars(args)))
    model = JointRefinement(args.width, args.depth, projected=not args.unprojected)
    optimiser = torch.optim.Adam(model.parameters(), lr=args.lr)
    start = 0
    checkpoint = out / "last.pt"
    if checkpoint.exists():
        state = torch.load(checkpoint)
        model.load_state_dict(state["model"])
        optimiser.load_state_dict(state["optimiser"])
        torch.set_rng_state(state["torch_rng"])
        random.setstate(state["random"])
        start = state["step"]
    log = open(out / "train.csv", "a")
    t0 = time.time()
    for step in range(start, args.steps):
        inputs, truths = batch_of(samples, args.batch, args.crop)
        loss = loss_of(model(inputs), truths, args.lights)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        log.write(f"{step + 1},{loss.item():.6f},{time.time() - t0:.1f}\n")
        if (step + 1) % args.every == 0 or step + 1 == args.steps:
            log.flush()
            torch.save(model.state_dict(), out / f"step{step + 1}.pt")
            state = {"model": model.state_dict(), "optimiser": optimiser.state_dict(),
                     "torch_rng": torch.get_rng_state(), "random": random.getstate(), "step": step + 1}
            torch.save(state, out / "last.tmp")
            os.replace(out / "last.tmp", checkpoint)


def apply(args):
    """Each material of `--data` refined: its defaults' folder copied with the four maps
    corrected, in OUT/MATERIAL/; the seconds each took."""
    config = json.loads(Path(args.run, "config.json").read_text())
    model = JointRefinement(config["width"], config["depth"], projected=not config.get("unprojected"))
    model.load_state_dict(torch.load(Path(args.run, f"step{args.step}.pt")))
    model.eval()
    torch.set_num_threads(args.threads)
    times = {}
    for root in args.data:
        for material in sorted(Path(root, "outputs").iterdir()):
            source = material / "matup"
            if not source.is_dir():
                continue
            up = read_folder(source)
            start = time.perf_counter()
            with torch.no_grad():
                x = torch.from_numpy(up[None]).float() / 255.0
                y = model(x)[0].numpy()
            times[material.name] = time.perf_counter() - start
            codes = np.round(y * 255).astype(np.uint8)
            target = Path(args.out, material.name)
            target.mkdir(parents=True, exist_ok=True)
            for name in os.listdir(source):
                (target / name).write_bytes((source / name).read_bytes())
            offset = 0
            for name in MAPS[:4]:
                c = CHANNELS[name]
                plane = codes[offset : offset + c].transpose(1, 2, 0)
                offset += c
                if not (source / f"{name}.png").exists():
                    continue  # a map the material lacks keeps its stand-in
                Image.fromarray(plane[:, :, 0] if c == 1 else plane).save(target / f"{name}.png")
    Path(args.out, "seconds.json").write_text(json.dumps(times))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("command", choices=["train", "apply"])
    parser.add_argument("--data", nargs="+", required=True)
    parser.add_argument("--out", required=True)
    parser.add_argument("--run")
    parser.add_argument("--step", type=int)
    parser.add_argument("--width", type=int, default=64)
    parser.add_argument("--depth", type=int, default=4)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--every", type=int, default=500)
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--crop", type=int, default=128)
    parser.add_argument("--lights", type=int, default=8)
    parser.add_argument("--lr", type=float, default=2e-4)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--unprojected", action="store_true", help="keep the blocks' means")
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    train(args) if args.command == "train" else apply(args)


if __name__ == "__main__":
    main()
