#!/usr/bin/env python3
"""Two texel-level tileability signals, scored on a labelled set like the one of
`examples/tileability.rs` (whole materials tileable; crops of half the width at random
offsets, no multiple of 8, not tileable; box-filtered to 64²–1024²; judged at --max-side at
most). Prints each signal's accuracy with the threshold that fits the set best (optimistic).

  python3 docs/experiments/2026-11-25-tileability-detection.py ../shared/materials ../shared/corpus

Needs numpy and Pillow. See docs/experiments/2026-11-25-tileability-detection.md.
"""
import argparse
import os

import numpy as np
from PIL import Image

MAPS = {"baseColor": 3, "normal": 2, "roughness": 1, "metallic": 1, "height": 1}
SIZES = [64, 128, 256, 512, 1024]


def load(folder):
    maps = {}
    for name, channels in MAPS.items():
        path = os.path.join(folder, name + ".png")
        if os.path.exists(path):
            image = np.asarray(Image.open(path))
            scale = 65535.0 if image.dtype == np.uint16 else 255.0
            a = image.astype(np.float32) / scale
            maps[name] = (a if a.ndim == 3 else a[..., None])[..., :channels]
    return maps


def box(a, f):
    h, w, c = a.shape
    return a.reshape(h // f, f, w // f, f, c).mean((1, 3))


def labelled(sets, rng):
    for root in sets:
        for name in sorted(os.listdir(root)):
            folder = os.path.join(root, name)
            if not os.path.isdir(folder):
                continue
            whole = load(folder)
            side = min(whole["baseColor"].shape[:2])
            for size in [s for s in SIZES if s <= side and side % s == 0]:
                yield name, size, True, {k: box(v, side // size) for k, v in whole.items()}
                crop = side // 2
                if size > crop:
                    continue
                for _ in range(2):
                    while True:
                        x, y = rng.integers(1, side - crop, 2)
                        if x % 8 and y % 8:
                            break
                    yield name, size, False, {
                        k: box(v[y : y + crop, x : x + crop], crop // size) for k, v in whole.items()
                    }


def channels(maps, max_side):
    """Each varying channel of every map, zero mean and unit variance, judged at max_side."""
    out = []
    for v in maps.values():
        f = 1
        while min(v.shape[:2]) // f > max_side:
            f *= 2
        v = box(v, f)
        for c in range(v.shape[2]):
            s = v[..., c].std()
            if s > 1e-4:
                out.append((v[..., c] - v[..., c].mean()) / s)
    return np.stack(out, -1)


def patch_novelty(img, rng, rows=4, cols=8):
    """Mean distance from each patch straddling the wrap-around edge to its nearest interior
    patch, over the same for interior patches (each excluding patches that share its rows):
    about 1 when the edge looks like the interior."""
    h, w, _ = img.shape

    def patches(row_ids, xs):
        strip = img[row_ids]
        return np.stack([np.take(strip, np.arange(x, x + cols) % w, axis=1).ravel() for x in xs])

    starts = np.arange(0, h - rows + 1)
    bank = np.concatenate([patches(np.arange(y, y + rows), range(0, w - cols + 1, 2)) for y in starts])
    bank_y = np.repeat(starts, len(range(0, w - cols + 1, 2)))

    def nearest(q, keep):
        b = bank[keep]
        d = (q * q).sum(1)[:, None] + (b * b).sum(1)[None] - 2 * q @ b.T
        return d.min(1)

    half = rows // 2
    clear_of_edge = (bank_y >= half) & (bank_y + rows <= h - half)
    edge = nearest(patches(np.arange(h - half, h + half) % h, range(0, w, max(2, w // 64))), clear_of_edge)
    interior = np.concatenate([
        nearest(patches(np.arange(y, y + rows), range(0, w, max(4, w // 16))),
                clear_of_edge & (np.abs(bank_y - y) >= rows))
        for y in rng.choice(np.arange(half + rows, h - 2 * rows - half), size=min(16, h // 4), replace=False)
    ])
    return edge.mean() / max(interior.mean(), 1e-9)


def lag_profile(img):
    """Rows' mean squared differences: the matrix between every two rows, the lags 1..h/2,
    per lag the mean over the pairs that do not cross the wrap-around edge and over those that
    do, and the median over the larger half of the lags (unrelated rows)."""
    h = img.shape[0]
    r = img.reshape(h, -1).astype(np.float64)
    n = (r * r).mean(1)
    d = n[:, None] + n[None] - 2 * (r @ r.T) / r.shape[1]
    lags = np.arange(1, h // 2 + 1)
    inside = np.array([np.diagonal(d, k).mean() for k in lags])
    across = np.array([np.diagonal(d, h - k).mean() for k in lags])
    return d, lags, inside, across, np.median(inside[len(inside) // 2 :])


def lag_crossing(img, max_lag_fraction=0.25):
    """For lags L up to a quarter of the side: how much more the row pairs L apart that cross
    the wrap-around edge differ than those that do not, over how much less interior pairs
    differ than unrelated rows (0 when the edge is like the interior, 1 when it joins
    unrelated content), weighted by the crossing pairs' count."""
    h = img.shape[0]
    d, lags, inside, across, far = lag_profile(img)
    w = lags * (lags <= max(2, int(h * max_lag_fraction)))
    return (w * (across - inside)).sum() / max((w * np.clip(far - inside, 0, None)).sum(), 1e-9)


def periodic_rule_inputs(img):
    """For the periodicity rule: how strongly the rows repeat at their best lag (at least a
    32nd of the side; 1 = exactly), how much more the pairs at that lag that cross the edge
    differ than those inside (as `lag_crossing`, at that lag alone), and the lag-1 edge's
    `z`: (edge − neighbour median) / (unrelated − neighbour median)."""
    h = img.shape[0]
    d, lags, inside, across, far = lag_profile(img)
    j = np.argmin(np.where(lags >= max(4, h // 32), inside, np.inf))
    neighbours = np.median(np.diagonal(d, 1))
    return (
        1 - inside[j] / far,
        (across[j] - inside[j]) / max(far - inside[j], 1e-9),
        (d[h - 1, 0] - neighbours) / max(far - neighbours, 1e-9),
    )


def periodic_rule(inputs, tileable, sizes):
    """Where the rows repeat (strength > S), tileable when the crossing pairs at the period
    are like the inside ones (≤ C); elsewhere when the lag-1 z ≤ Z; both axes. The best
    (S, C, Z) on the set."""
    def decide(axes, s, c, z):
        return np.array([all((x[1] <= c) if x[0] > s else (x[2] <= z) for x in a) for a in axes])
    grid = [(s, c, z) for s in (0.3, 0.4, 0.5, 0.6, 0.7, 0.8) for c in (0.1, 0.2, 0.3, 0.4, 0.5)
            for z in (0.1, 0.2, 0.3, 0.5, 0.8)]
    best = max(grid, key=lambda p: (decide(inputs, *p) == tileable).mean())
    right = decide(inputs, *best) == tileable
    per_size = ", ".join(
        f"{s}²: {100 * right[sizes == s].mean():.1f}%" for s in SIZES if (sizes == s).any()
    )
    print(f"periodicity rule (S, C, Z) = {best}: {100 * right.mean():.1f}% ({per_size})")


def report(name, scores, tileable, sizes):
    best = max((((scores <= t) == tileable).mean(), t) for t in np.unique(scores))
    t = best[1]
    per_size = ", ".join(
        f"{s}²: {100 * ((scores[sizes == s] <= t) == tileable[sizes == s]).mean():.1f}%"
        for s in SIZES if (sizes == s).any()
    )
    print(f"{name}: tileable when ≤ {t:.3f}: {100 * best[0]:.1f}% ({per_size})")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("sets", nargs="+")
    ap.add_argument("--max-side", type=int, default=128)
    args = ap.parse_args()
    rng = np.random.default_rng(39)
    novelty, crossing, periodic, tileable, sizes = [], [], [], [], []
    for name, size, whole, maps in labelled(args.sets, rng):
        img = channels(maps, args.max_side)
        t = img.transpose(1, 0, 2)
        novelty.append(max(patch_novelty(img, rng), patch_novelty(t, rng)))
        crossing.append(max(lag_crossing(img), lag_crossing(t)))
        periodic.append([periodic_rule_inputs(img), periodic_rule_inputs(t)])
        tileable.append(whole)
        sizes.append(size)
    tileable, sizes = np.array(tileable), np.array(sizes)
    report("patch novelty", np.array(novelty), tileable, sizes)
    report("lag crossing", np.array(crossing), tileable, sizes)
    periodic_rule(periodic, tileable, sizes)


if __name__ == "__main__":
    main()
