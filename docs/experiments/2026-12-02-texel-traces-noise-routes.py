#!/usr/bin/env python3
"""Study prototype (docs/experiments/2026-12-02-texel-traces.md, "What the route gains"): with
σ 3 of noise, the degraded route is the better one on 13 of 16 materials, the clean route on
Tiles036 by 1.1 dB. Can a run pick or mix the two from what it sees?

Each material of sweeps/noise_route.toml: its 512² crop, box-filtered ÷4 by `matup downsample`,
with Gaussian noise of σ 3 levels on every 8-bit value (numpy, seed 5), upscaled ×4 with
`--input-quality degraded` and `--input-quality clean`.

- `select`: self-validation one scale down, as `select = "auto"` validates: the noisy input
  box-filtered ÷4 again, noise of σ S drawn anew (the σ read), both routes upscale it ×4 and are
  scored against the noisy input (the noise there costs both alike), PSNR − 10·log10 FLIP.
- `blend K0:K1[:MAPS]`: each map (or MAPS, comma-separated file stems) of the two outputs mixed
  texel by texel, the clean route's weight from the noisy input's local variance (Gaussian
  window of 1.5 texels, the largest over channels, 8-bit levels) over σ²: 0 up to K0, 1 from
  K1, a ramp between; scored against the true 512² crop.

    python docs/experiments/2026-12-02-texel-traces-noise-routes.py select 2.8
    python docs/experiments/2026-12-02-texel-traces-noise-routes.py blend 20:80:normal 20:80 5:20

numpy and Pillow; MATUP (default target/release/matup); work files under /tmp/noise-routes.
"""
import json
import os
import subprocess
import sys

import numpy as np
from PIL import Image

MATUP = os.environ.get("MATUP", "target/release/matup")
WORK = "/tmp/noise-routes"
NOISE = 3.0
SIGMA_READ = 2.8
SWEEP = "sweeps/noise_route.toml"
MATERIALS = [
    line.split('"')[1].replace("../../shared", os.path.abspath("../shared"))
    for line in open(SWEEP)
    if line.strip().startswith('"../../shared')
]
rng = np.random.default_rng(5)


def matup(*args):
    done = subprocess.run([MATUP, *args], capture_output=True, text=True)
    if done.returncode:
        sys.exit(done.stderr[-2000:])
    return done.stdout


def pngs(folder):
    return [f for f in sorted(os.listdir(folder)) if f.endswith(".png") and f != "preview.png"]


def load(path):
    a = np.asarray(Image.open(path)).astype(np.float64)
    return a if a.ndim == 3 else a[..., None]


def save(a, path):
    a = np.clip(np.round(a), 0, 255).astype(np.uint8)
    Image.fromarray(a if a.shape[2] > 1 else a[..., 0]).save(path)


def with_noise(src, dst, sigma):
    os.makedirs(dst, exist_ok=True)
    for f in pngs(src):
        a = load(f"{src}/{f}")
        save(a + rng.normal(0, sigma, a.shape), f"{dst}/{f}")


def prepared(material):
    """The material's work folder, with its truth (512²), noisy input and both routes' outputs."""
    work = f"{WORK}/{os.path.basename(material)}"
    if not os.path.isdir(f"{work}/clean_route"):
        os.makedirs(f"{work}/truth", exist_ok=True)
        for f in pngs(material):
            Image.open(f"{material}/{f}").crop((0, 0, 512, 512)).save(f"{work}/truth/{f}")
        matup("downsample", f"{work}/truth", "-o", f"{work}/lr", "--factor", "4")
        with_noise(f"{work}/lr", f"{work}/noisy", NOISE)
        for route in ["degraded", "clean"]:
            matup("upscale", f"{work}/noisy", "-o", f"{work}/{route}_route", "--input-quality", route)
    return work


def scores(reference, candidate):
    e = json.loads(matup("eval", "--reference", reference, "--candidate", candidate, "--json"))
    psnr, flip = e["render_psnr"], e["render_flip"]
    return psnr, flip, psnr - 10 * np.log10(max(flip, 1e-6))


def gaussian_blur(a, sigma=1.5):
    radius = int(np.ceil(3 * sigma))
    k = np.exp(-np.arange(-radius, radius + 1) ** 2 / (2 * sigma * sigma))
    k /= k.sum()
    a = np.pad(a, radius, mode="wrap")
    a = np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 0, a)
    return np.apply_along_axis(lambda v: np.convolve(v, k, "valid"), 1, a)


def select(sigma_read):
    for material in MATERIALS:
        work = prepared(material)
        lower = f"{work}/lower{sigma_read}"
        if not os.path.isdir(lower):
            matup("downsample", f"{work}/noisy", "-o", f"{work}/lower", "--factor", "4")
            with_noise(f"{work}/lower", lower, sigma_read)
        score = {}
        for route in ["degraded", "clean"]:
            out = f"{lower}_{route}"
            if not os.path.isdir(out):
                matup("upscale", lower, "-o", out, "--input-quality", route)
            score[route] = scores(f"{work}/noisy", out)[2]
        full = {r: scores(f"{work}/truth", f"{work}/{r}_route")[0] for r in ["degraded", "clean"]}
        print(f"{os.path.basename(material):32s} one scale down, clean − degraded: "
              f"{score['clean'] - score['degraded']:+.2f}; at full scale (PSNR): "
              f"{full['clean'] - full['degraded']:+.2f}", flush=True)


def blend(specs):
    for material in MATERIALS:
        work = prepared(material)
        line = f"{os.path.basename(material):32s}"
        for r in ["degraded", "clean"]:
            line += f" {r} {scores(f'{work}/truth', f'{work}/{r}_route')[0]:.2f}"
        for spec in specs:
            k0, k1, *maps = spec.split(":")
            out = f"{work}/blend_{spec.replace(':', '_').replace(',', '+')}"
            os.makedirs(out, exist_ok=True)
            for f in pngs(f"{work}/degraded_route"):
                degraded = load(f"{work}/degraded_route/{f}")
                if maps and f[:-4] not in maps[0].split(","):
                    save(degraded, f"{out}/{f}")
                    continue
                lr = load(f"{work}/noisy/{f}")[..., :3]
                variance = np.max(
                    [gaussian_blur(lr[..., c] ** 2) - gaussian_blur(lr[..., c]) ** 2
                     for c in range(lr.shape[2])], axis=0)
                w = np.clip((variance / SIGMA_READ**2 - float(k0)) / (float(k1) - float(k0)), 0, 1)
                w = np.kron(w, np.ones((4, 4)))[..., None]
                clean = load(f"{work}/clean_route/{f}")
                save(degraded * (1 - w) + clean * w, f"{out}/{f}")
            psnr, flip, _ = scores(f"{work}/truth", out)
            line += f" | {spec}: {psnr:.2f} / {flip:.4f}"
        print(line, flush=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["select"]:
        select(float(sys.argv[2]) if len(sys.argv) > 2 else SIGMA_READ)
    elif sys.argv[1:2] == ["blend"]:
        blend(sys.argv[2:])
    else:
        sys.exit(__doc__)
