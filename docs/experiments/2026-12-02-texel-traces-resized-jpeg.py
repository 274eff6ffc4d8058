#!/usr/bin/env python3
"""Study prototype (docs/experiments/2026-12-02-texel-traces.md, "A JPEG resized after it was
saved"): does a JPEG's block grid survive a resize to half? Each material's base colour, a 512²
crop box-filtered to 256² (linear light), saved as JPEG 75 (Pillow, 4:2:0), then box-filtered to
128² as 8-bit PNG levels, against the same crop box-filtered straight to 128² and against the
JPEG saved at 128² itself. Blockiness at period P: the mean step between neighbouring texels
across the grid's strongest phase over its median phase, the lesser of the two axes (1 where no
grid shows). A JPEG's grid at 128² is period 8; halved, its 8×8 blocks are 4×4.

    python docs/experiments/2026-12-02-texel-traces-resized-jpeg.py ../shared/materials ../shared/corpus
"""
import glob
import io
import os
import sys

import numpy as np
from PIL import Image


def lin(v):
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def srgb(v):
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(np.clip(v, 0, None), 1 / 2.4) - 0.055)


def box(a, f):
    h, w = a.shape[0] // f * f, a.shape[1] // f * f
    return a[:h, :w].reshape(h // f, f, w // f, f, -1).mean(axis=(1, 3))


def levels(linear):
    return np.round(srgb(linear) * 255)


def jpeg(a, quality):
    buffer = io.BytesIO()
    Image.fromarray(a.astype(np.uint8)).save(buffer, "JPEG", quality=quality)
    buffer.seek(0)
    return np.asarray(Image.open(buffer)).astype(float)


def blockiness(img, period):
    y = img.mean(axis=2)
    steps = [np.abs(np.diff(y, axis=1)), np.abs(np.diff(y, axis=0)).T]
    ratios = []
    for d in steps:
        by_phase = np.array([d[:, p::period].mean() for p in range(period)])
        ratios.append(by_phase.max() / max(np.median(by_phase), 1e-9))
    return min(ratios)


def main(sets):
    rows = []
    for s in sets:
        for folder in sorted(glob.glob(os.path.join(s, "*/"))):
            path = os.path.join(folder, "baseColor.png")
            if not os.path.exists(path):
                continue
            a = lin(np.asarray(Image.open(path).convert("RGB")).astype(float)[:512, :512] / 255)
            clean = levels(box(a, 4))
            halved = levels(box(lin(jpeg(levels(box(a, 2)), 75) / 255), 2))
            at_128 = jpeg(clean, 75)
            rows.append((os.path.basename(folder.rstrip("/")), blockiness(clean, 4),
                         blockiness(halved, 4), blockiness(clean, 8), blockiness(at_128, 8)))
    for name, c4, h4, c8, j8 in rows:
        print(f"{name[:32]:32} period 4: clean {c4:.3f}, JPEG 75 halved {h4:.3f} | "
              f"period 8: clean {c8:.3f}, JPEG 75 at 128² {j8:.3f}")
    top4, top8 = max(r[1] for r in rows), max(r[3] for r in rows)
    print(f"{len(rows)} base colours; above every clean one at its period: JPEG 75 halved "
          f"{sum(r[2] > top4 for r in rows)} (clean up to {top4:.3f}), JPEG 75 at 128² "
          f"{sum(r[4] > top8 for r in rows)} (clean up to {top8:.3f})")


if __name__ == "__main__":
    main(sys.argv[1:])
