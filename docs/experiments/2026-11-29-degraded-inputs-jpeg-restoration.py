"""What a JPEG input's maps lose, and two ways to get some of it back without a network (issue 76).

Each material's truth (a 512² crop) is box-filtered to 128² by `matup downsample`, each map
saved as a JPEG of quality 75 (4:2:0; grey maps as grey JPEGs) by Pillow, and decoded again.
The route for degraded maps (`matup upscale --input-quality degraded`) runs ×4 on the decode;
the clean route on the clean 128² maps. `matup eval` (16 held-out lights) judges:

- `out`: the degraded route as it ships (the degraded network, unprojected);
- `consistent`: `out` projected onto the JPEG's quantisation intervals: its box-filtered maps'
  8×8 DCT coefficients (luma, and 4:2:0 chroma) clamped to the interval each coefficient was
  quantised from, the change spread back by bilinear upsampling, three rounds, as matup's
  back-projection spreads its own. The true LR maps lie in those intervals.
- `swap-KIND`: `out` with one map taken from the clean route: what the JPEG costs that map;
- `integrable-after`: `out`'s normals with three quarters of their curl taken out (a height
  field's normals have none: Frankot–Chellappa, the map mirrored);
- `integrable-before`: the same done to the decoded LR normals, then the degraded route.

It also scores, against the true 128² maps, a JPEG decoded by total variation within its
intervals (as jpeg2png does), a cleaned estimate a projection could trust.

Data: `matup sweep` with `view = true` keeps each material's truth crop in
`OUT/outputs/MATERIAL/truth/`: sweeps/input_quality.toml with `crop_at = 0`, `view = true`,
no `degrade` and `baselines = []` (the shared 10 and the val 6, 512² crops).

Usage (numpy, pillow, jpeglib; `matup` on PATH):
  python docs/experiments/2026-11-29-degraded-inputs-jpeg-restoration.py SWEEP_OUTPUTS WORK
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import jpeglib
import numpy as np
from PIL import Image

GREY = {"roughness", "metallic", "height"}
SWAPPED = ["baseColor", "normal", "roughness"]
ROUNDS = 3


def dct_matrix():
    u, x = np.meshgrid(np.arange(8), np.arange(8), indexing="ij")
    m = np.sqrt(2 / 8) * np.cos((2 * x + 1) * u * np.pi / 16)
    m[0] = np.sqrt(1 / 8)
    return m


DCT = dct_matrix()


def blocks(plane):
    h, w = plane.shape
    return plane.reshape(h // 8, 8, w // 8, 8).transpose(0, 2, 1, 3)


def unblocks(b):
    return b.transpose(0, 2, 1, 3).reshape(b.shape[0] * 8, b.shape[1] * 8)


def within_intervals(plane, coeffs, q):
    """`plane` (0–255) with each block's DCT coefficients clamped to their quantisation intervals."""
    c = np.clip(DCT @ blocks(plane - 128.0) @ DCT.T, (coeffs - 0.5) * q, (coeffs + 0.5) * q)
    return unblocks(DCT.T @ c @ DCT) + 128.0


def to_ycc(rgb):
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    return (0.299 * r + 0.587 * g + 0.114 * b,
            -0.168736 * r - 0.331264 * g + 0.5 * b + 128,
            0.5 * r - 0.418688 * g - 0.081312 * b + 128)


def to_rgb(y, cb, cr):
    return np.stack([y + 1.402 * (cr - 128),
                     y - 0.344136 * (cb - 128) - 0.714136 * (cr - 128),
                     y + 1.772 * (cb - 128)], -1)


def nearest_consistent(lr, jpeg):
    """The LR map (0–255) with its coefficients moved into the JPEG's intervals."""
    table = lambda k: jpeg.qt[jpeg.quant_tbl_no[k]]
    if lr.ndim == 2:
        return within_intervals(lr, jpeg.Y, table(0))
    y, cb, cr = to_ycc(lr)
    out = [within_intervals(y, jpeg.Y, table(0))]
    for k, (plane, coeffs) in enumerate([(cb, jpeg.Cb), (cr, jpeg.Cr)], 1):
        h, w = plane.shape
        half = plane.reshape(h // 2, 2, w // 2, 2).mean((1, 3))
        moved = within_intervals(half, coeffs, table(k)) - half
        out.append(plane + np.repeat(np.repeat(moved, 2, 0), 2, 1))
    return to_rgb(*out)


def srgb_to_linear(v):
    v = v / 255.0
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(v):
    v = np.clip(v, 0, 1)
    return 255.0 * np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1 / 2.4) - 0.055)


def box(a, f=4):
    h, w = a.shape[:2]
    return a.reshape(h // f, f, w // f, f, *a.shape[2:]).mean((1, 3))


def box_as_matup(kind, hr):
    """What `matup downsample` makes of an HR map: colour averaged linear, normals renormalised."""
    if kind == "baseColor":
        return linear_to_srgb(box(srgb_to_linear(hr)))
    if kind == "normal":
        n = box(hr / 127.5 - 1.0)
        return (n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6) + 1.0) * 127.5
    return box(hr)


def bilinear_up(a, f):
    """×f, texel centres at half texels, edges clamped."""
    def taps(n):
        x = np.clip((np.arange(n * f) + 0.5) / f - 0.5, 0, n - 1)
        x0 = np.floor(x).astype(int)
        return x0, np.minimum(x0 + 1, n - 1), x - x0
    (y0, y1, ty), (x0, x1, tx) = taps(a.shape[0]), taps(a.shape[1])
    ty = ty.reshape(-1, 1, *([1] * (a.ndim - 2)))
    tx = tx.reshape(1, -1, *([1] * (a.ndim - 2)))
    rows = a[y0] * (1 - ty) + a[y1] * ty
    return rows[:, x0] * (1 - tx) + rows[:, x1] * tx


def tv_decode(path, iters=30, step=0.5, eps=1.0):
    """The JPEG decoded by total variation within its intervals (projected gradient steps)."""
    jpeg = jpeglib.read_dct(path)

    def plane(coeffs, q):
        x = unblocks(DCT.T @ (coeffs * q) @ DCT) + 128.0
        for _ in range(iters):
            dx = np.diff(x, axis=1, append=x[:, -1:])
            dy = np.diff(x, axis=0, append=x[-1:, :])
            norm = np.sqrt(dx * dx + dy * dy + eps * eps)
            px, py = dx / norm, dy / norm
            px[:, -1] = 0
            py[-1, :] = 0
            div = px - np.pad(px, ((0, 0), (1, 0)))[:, :-1] + py - np.pad(py, ((1, 0), (0, 0)))[:-1]
            x = within_intervals(x + step * div, coeffs, q)
        return x

    table = lambda k: jpeg.qt[jpeg.quant_tbl_no[k]]
    y = plane(jpeg.Y, table(0))
    if jpeg.Cb is None:
        return y
    cb, cr = plane(jpeg.Cb, table(1)), plane(jpeg.Cr, table(2))
    if cb.shape != y.shape:
        cb, cr = bilinear_up(cb, 2), bilinear_up(cr, 2)
    return np.clip(to_rgb(y, cb, cr), 0, 255)


def integrable(normal, keep=0.25):
    """Stored normals (0–255) with `1 - keep` of their curl taken out: the gradient field of
    the least-squares height of their slopes (Frankot–Chellappa, over the map mirrored)."""
    n = normal / 127.5 - 1.0
    z = np.maximum(n[..., 2], 0.05)
    p, q = -n[..., 0] / z, -n[..., 1] / z
    h, w = p.shape
    # Mirrored, a slope across the mirror changes sign: the field stays a gradient.
    p4 = np.block([[p, -p[:, ::-1]], [p[::-1], -p[::-1, ::-1]]])
    q4 = np.block([[q, q[:, ::-1]], [-q[::-1], -q[::-1, ::-1]]])
    du = np.exp(2j * np.pi * np.fft.fftfreq(2 * w))[None, :] - 1
    dv = np.exp(2j * np.pi * np.fft.fftfreq(2 * h))[:, None] - 1
    power = np.abs(du) ** 2 + np.abs(dv) ** 2
    power[0, 0] = 1
    height = (np.conj(du) * np.fft.fft2(p4) + np.conj(dv) * np.fft.fft2(q4)) / power
    height[0, 0] = 0
    gp = np.real(np.fft.ifft2(du * height))[:h, :w]
    gq = np.real(np.fft.ifft2(dv * height))[:h, :w]
    gp += p.mean() - gp.mean()
    gq += q.mean() - gq.mean()
    g = np.stack([-gp, -gq, np.ones_like(gp)], -1)
    g = (g / np.linalg.norm(g, axis=-1, keepdims=True) + 1.0) * 127.5
    return g + keep * (normal - g)


def load(path, kind):
    im = Image.open(path)
    a = np.asarray(im).astype(np.float64) / (257.0 if im.mode.startswith("I") else 1.0)
    return (a if a.ndim == 2 else a[..., 0]) if kind in GREY else a[..., :3]


def save(a, path, like):
    if like.mode.startswith("I"):
        Image.fromarray(np.round(np.clip(a, 0, 255) * 257).astype(np.uint16)).save(path)
    else:
        Image.fromarray(np.round(np.clip(a, 0, 255)).astype(np.uint8)).save(path)


def pngs(folder):
    return sorted(p.stem for p in Path(folder).glob("*.png"))


def prepare(truth, d):
    """The clean LR maps, their JPEGs and the JPEGs' decodes."""
    subprocess.run(["matup", "downsample", truth, "-o", d / "lr", "--factor", "4"],
                   check=True, capture_output=True)
    for sub in ("jpg", "decoded"):
        (d / sub).mkdir(exist_ok=True)
    for kind in pngs(d / "lr"):
        a = np.clip(np.round(load(d / "lr" / f"{kind}.png", kind)), 0, 255).astype(np.uint8)
        Image.fromarray(a).save(d / "jpg" / f"{kind}.jpg", quality=75, subsampling=2)
        Image.open(d / "jpg" / f"{kind}.jpg").save(d / "decoded" / f"{kind}.png")


def made_consistent(d):
    (d / "consistent").mkdir(exist_ok=True)
    for kind in pngs(d / "lr"):
        like = Image.open(d / "out" / f"{kind}.png")
        hr = load(d / "out" / f"{kind}.png", kind)
        jpeg = jpeglib.read_dct(str(d / "jpg" / f"{kind}.jpg"))
        for _ in range(ROUNDS):
            lr = box_as_matup(kind, hr)
            hr = np.clip(hr + bilinear_up(nearest_consistent(lr, jpeg) - lr, 4), 0, 255)
        save(hr, d / "consistent" / f"{kind}.png", like)


def with_normal(d, src, name, normal):
    out = d / name
    out.mkdir(exist_ok=True)
    for k in pngs(d / "lr"):
        (out / f"{k}.png").write_bytes((d / src / f"{k}.png").read_bytes())
    save(normal, out / "normal.png", Image.open(d / src / "normal.png"))
    return out


def swapped(d, kind):
    out = d / f"swap-{kind}"
    out.mkdir(exist_ok=True)
    for k in pngs(d / "lr"):
        src = d / ("clean" if k == kind else "out") / f"{k}.png"
        (out / f"{k}.png").write_bytes(src.read_bytes())
    return out.name


def rmse(a, b):
    return float(np.sqrt(((a - b) ** 2).mean()))


def main(sweep_outputs, work):
    work = Path(work)
    scores, lr_errors = {}, {}
    for truth in sorted(Path(sweep_outputs).glob("*/truth")):
        name = truth.parent.name
        d = work / name
        d.mkdir(parents=True, exist_ok=True)
        if not (d / "decoded").exists():
            prepare(truth, d)
        for src, out, quality in [("decoded", "out", "degraded"), ("lr", "clean", "clean")]:
            if not (d / out).exists():
                subprocess.run(["matup", "upscale", d / src, "-o", d / out, "--no-tileable",
                                "--quiet", "--input-quality", quality], check=True)
        made_consistent(d)
        with_normal(d, "out", "integrable-after",
                    integrable(load(d / "out" / "normal.png", "normal")))
        before = with_normal(d, "decoded", "integrable-before-in",
                             integrable(load(d / "decoded" / "normal.png", "normal")))
        if not (d / "integrable-before").exists():
            subprocess.run(["matup", "upscale", before, "-o", d / "integrable-before",
                            "--no-tileable", "--quiet", "--input-quality", "degraded"], check=True)
        variants = ["out", "consistent", "integrable-after", "integrable-before", "clean"]
        variants += [swapped(d, k) for k in SWAPPED]
        for v in variants:
            judged = subprocess.run(["matup", "eval", "--reference", truth, "--candidate", d / v,
                                     "--scale", "4", "--json"], check=True, capture_output=True)
            scores.setdefault(v, {})[name] = json.loads(judged.stdout)["render_psnr"]
        for kind in SWAPPED:
            true_lr = load(d / "lr" / f"{kind}.png", kind)
            out_lr = box_as_matup(kind, load(d / "out" / f"{kind}.png", kind))
            jpeg = jpeglib.read_dct(str(d / "jpg" / f"{kind}.jpg"))
            lr_errors.setdefault(kind, []).append([
                rmse(load(d / "decoded" / f"{kind}.png", kind), true_lr),
                rmse(tv_decode(str(d / "jpg" / f"{kind}.jpg")), true_lr),
                rmse(out_lr, true_lr),
                rmse(nearest_consistent(out_lr, jpeg), true_lr),
            ])
    base = scores["out"]
    print("| variant | render PSNR, mean | against `out` | ahead on | worst |")
    print("|---|---|---|---|---|")
    for v, s in scores.items():
        gains = [s[m] - base[m] for m in base]
        print(f"| {v} | {np.mean(list(s.values())):.3f} dB | {np.mean(gains):+.3f} dB "
              f"| {sum(g > 0 for g in gains)} of {len(gains)} | {min(gains):+.3f} dB |")
    print("\n| map | JPEG decode | decoded by TV | `out` box-filtered | that, consistent |")
    print("|---|---|---|---|---|")
    for kind, rows in lr_errors.items():
        m = np.mean(rows, axis=0)
        print(f"| {kind} | " + " | ".join(f"{v:.2f}" for v in m) + " |")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(*sys.argv[1:])
