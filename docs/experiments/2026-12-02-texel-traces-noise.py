#!/usr/bin/env python3
"""Study prototype (docs/experiments/2026-12-02-texel-traces.md, "Noise"): can noise be told from
a texture's grain map by map, and can it be told material by material?

Each material's base colour, normal, roughness, metallic and height maps: a 512² crop
box-filtered ÷4 (base colour in linear light) as 8-bit levels ("box128"), or a 256² crop
("crop256"); clean and with Gaussian noise of σ 1–4 levels. Each map's flattest tenth of 16×16
patches on a grid (Immerkær's kernel, the median channel) gives: σ, the half-scale ratio (white
noise 0.5), the share of clipped texels, the median patch's σ over the flattest's (spread), the
kurtosis of the kernel's responses, the correlation of the channels' responses, and the
greatest correlation with another map's. (matup reads a patch at every texel, not on a grid.)

1. Per map: a logistic regression on those features (fitted on the train materials, threshold
   at the highest-scoring clean train map) against σ 3 of noise.
2. Per material (four maps at least): every map's σ at least T (T/2 where clipped) and at
   least three maps white (ratio ≤ R); then, as matup reads it, white a band (0.35 ≤ ratio ≤
   0.9) and one map a witness (clipped, or spread ≤ 1.5 with 0.35 ≤ ratio ≤ 0.7); with all five
   maps, the four without height, and four without metallic.

    python docs/experiments/2026-12-02-texel-traces-noise.py ../shared/materials ../shared/corpus ../corpus-extra-built
"""
import glob
import itertools
import os
import sys

import numpy as np
from PIL import Image
from scipy.signal import convolve2d

K = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], float)
GAIN = np.sqrt(np.pi / 2) / 6
P = 16
MAPS = {"baseColor": 3, "normal": 2, "roughness": 1, "metallic": 1, "height": 1}
VAL = {"ambientcg_Road006", "ambientcg_Rock035", "ambientcg_Ground079L", "ambientcg_Fabric045",
       "ambientcg_Wood092", "ambientcg_Metal027"}


def lin(v):
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def srgb(v):
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * np.power(np.clip(v, 0, None), 1 / 2.4) - 0.055)


def load(folder, cut):
    out = {}
    for stem, channels in MAPS.items():
        path = next((p for p in (os.path.join(folder, f"{stem}.{e}") for e in ("png", "jpg"))
                     if os.path.exists(p)), None)
        if path is None:
            continue
        a = np.asarray(Image.open(path).convert("RGB")).astype(float) / 255
        if cut == "crop256":
            a = a[:256, :256]
        else:
            a = a[:512, :512]
            h, w = a.shape[0] // 4 * 4, a.shape[1] // 4 * 4
            a = a[:h, :w]
            a = lin(a) if stem == "baseColor" else a
            a = a.reshape(h // 4, 4, w // 4, 4, 3).mean(axis=(1, 3))
            a = srgb(a) if stem == "baseColor" else a
        out[stem] = np.round(a * 255)[:, :, :channels]
    return out


def half(a):
    h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
    return a[:h, :w].reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3))


def read_map(v):
    """The flattest tenth of each channel's patches; the median channel's readings, and the
    patches and responses for the joint features."""
    fine = [convolve2d(v[:, :, c], K, mode="valid") for c in range(v.shape[2])]
    coarse = [convolve2d(half(v[:, :, c]), K, mode="valid") for c in range(v.shape[2])]
    n, m = fine[0].shape[0] // P, fine[0].shape[1] // P
    per = []
    for c in range(v.shape[2]):
        patches = []
        for y, x in itertools.product(range(n), range(m)):
            sl = (slice(y * P, y * P + P), slice(x * P, x * P + P))
            hs = (slice(y * P // 2, y * P // 2 + P // 2), slice(x * P // 2, x * P // 2 + P // 2))
            tex = v[y * P:y * P + P + 2, x * P:x * P + P + 2, c]
            s = np.mean(np.abs(fine[c][sl])) * GAIN
            patches.append((s, np.mean(np.abs(coarse[c][hs])) * GAIN / max(s, 1e-6),
                            np.mean((tex <= 0) | (tex >= 255)), sl))
        patches.sort(key=lambda p: p[0])
        flat = patches[:max(4, len(patches) // 10)]
        sigma = np.median([p[0] for p in flat])
        per.append((sigma, np.median([p[1] for p in flat]), np.median([p[2] for p in flat]),
                    [p[3] for p in flat], patches[len(patches) // 2][0] / max(sigma, 1e-6)))
    per.sort(key=lambda p: p[0])
    sigma, ratio, clip, flat, spread = per[len(per) // 2]
    pooled = np.concatenate([(r[sl] / (np.std(r[sl]) + 1e-9)).ravel() for sl in flat for r in fine])
    kurt = np.mean(pooled ** 4) / max(np.mean(pooled ** 2) ** 2, 1e-12)
    corr = [np.corrcoef(fine[a][sl].ravel(), fine[b][sl].ravel())[0, 1]
            for sl in flat for a in range(len(fine)) for b in range(a + 1, len(fine))
            if fine[a][sl].std() > 0 and fine[b][sl].std() > 0]
    return dict(sigma=sigma, ratio=ratio, clip=clip, spread=spread, kurt=np.log(max(kurt, 1.0)),
                chan=float(np.median(corr)) if corr else 0.0), np.mean(fine, axis=0), flat


def read_material(maps):
    read = {k: read_map(v) for k, v in maps.items()}
    out = {}
    for k, (f, mean, flat) in read.items():
        cross = []
        for o, (_, other, _) in read.items():
            if o == k or other.shape != mean.shape:
                continue
            c = [abs(np.corrcoef(mean[sl].ravel(), other[sl].ravel())[0, 1]) for sl in flat
                 if mean[sl].std() > 0 and other[sl].std() > 0]
            cross.append(np.median(c) if c else 0.0)
        out[k] = dict(f, cross=max(cross) if cross else 0.0)
    return out


def noisy_material(maps, rule, kinds, as_matup):
    T, R = rule
    ms = [r for k, r in maps.items() if k in kinds]
    if len(ms) < 4 or any(r["sigma"] < (T / 2 if r["clip"] >= 0.1 else T) for r in ms):
        return False
    if not as_matup:
        return sum(r["ratio"] <= R for r in ms) >= 3
    white = sum(0.35 <= r["ratio"] <= R for r in ms)
    witness = any(r["clip"] >= 0.1 or (r["spread"] <= 1.5 and 0.35 <= r["ratio"] <= 0.7) for r in ms)
    return white >= 3 and witness


def main(sets):
    rng = np.random.default_rng(0)
    rows = {}
    for s in sets:
        for folder in sorted(glob.glob(os.path.join(s, "*/"))):
            name = os.path.basename(folder.rstrip("/"))
            for cut in ("box128", "crop256"):
                clean = load(folder, cut)
                if "baseColor" not in clean:
                    continue
                for sd in (0, 1, 2, 3, 4):
                    maps = clean if sd == 0 else {
                        k: np.clip(np.round(v + rng.normal(0, sd, v.shape)), 0, 255) for k, v in clean.items()}
                    rows[(name, cut, sd)] = read_material(maps)
            print(name, file=sys.stderr)
    test = lambda name: name in VAL or any(os.path.exists(os.path.join(s, name)) and "materials" in s for s in sets)
    # 1. Per map: logistic regression, clean against σ 3.
    feats = ["sigma", "ratio", "kurt", "chan", "cross"]
    def data(held_out):
        X, y, who = [], [], []
        for (name, cut, sd), maps in rows.items():
            if cut != "box128" or sd not in (0, 3) or test(name) != held_out:
                continue
            for k, r in maps.items():
                X.append([np.log(max(r["sigma"], 0.05))] + [r[f] for f in feats[1:]])
                y.append(sd == 3)
                who.append((name, k))
        return np.array(X), np.array(y, float), who
    Xtr, ytr, _ = data(False)
    Xte, yte, _ = data(True)
    mu, sd = Xtr.mean(0), Xtr.std(0) + 1e-9
    A = np.c_[(Xtr - mu) / sd, np.ones(len(Xtr))]
    w = np.zeros(A.shape[1])
    for _ in range(3000):
        p = 1 / (1 + np.exp(-A @ w))
        w -= 0.5 * (A.T @ (p - ytr) / len(ytr) + 1e-3 * np.r_[w[:-1], 0])
    score = lambda X: np.c_[(X - mu) / sd, np.ones(len(X))] @ w
    thr = score(Xtr)[ytr == 0].max()
    for label, X, y in (("train", Xtr, ytr), ("held out", Xte, yte)):
        s = score(X)
        print(f"per map, {label}: σ 3 found in {int(((s > thr) & (y == 1)).sum())} of {int(y.sum())} maps, "
              f"clean read in {int(((s > thr) & (y == 0)).sum())} of {int((y == 0).sum())}")
    # 2. Per material: the floor under every map.
    sets = ((tuple(MAPS), "5 maps"), (tuple(MAPS)[:4], "no height"),
            (("baseColor", "normal", "roughness", "height"), "no metallic"))
    for (kinds, label), as_matup in itertools.product(sets, (False, True)):
        for cut in ("box128", "crop256"):
            for rule in itertools.product((2.0, 2.2, 2.4), (0.8, 0.9, 1.0)):
                counts = [sum(noisy_material(m, rule, kinds, as_matup) for (n, c, s), m in rows.items()
                              if c == cut and s == sd) for sd in (0, 1, 2, 3, 4)]
                total = sum(1 for (n, c, s) in rows if c == cut and s == 0)
                how = "band and witness" if as_matup else "≤ R"
                print(f"per material, {label}, white {how}, {cut}, T {rule[0]} R {rule[1]}: clean, "
                      "σ 1–4 read in " + ", ".join(str(x) for x in counts) + f" of {total}")


if __name__ == "__main__":
    main(sys.argv[1:])
