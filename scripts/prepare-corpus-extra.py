#!/usr/bin/env python3
"""Convert the assembled extra corpus (../shared/corpus-extra, its README) to the corpus' layout.

Usage: prepare-corpus-extra.py ASSEMBLED OUT

ASSEMBLED is the folder `assemble.py --out` wrote (each material's files as its repository stores
them); OUT receives one folder per material in the layout of ../shared/corpus: baseColor.png
(sRGB), normal.png (DirectX, Y-), roughness.png, metallic.png (all 0 where the set has none) and
height.png where the set has one, all 8-bit, all at one size. What each file is comes from the
material's source.txt in ../shared/corpus-extra (its `role:` and `normal convention:` lines), not from the file names.

- Maps of different sizes (a 512² ARM beside a 1024² colour map) are box-filtered to the smallest,
  so that every map of a training pair describes the same surface.
- OpenGL normals get G flipped. Where source.txt says the convention is unknown, it is measured
  against the height map's slope (as ../shared/corpus did); a set with neither is dropped.
- A set whose metalness is unknown although it is metal (ambientcg_Metal050A: its ARM's B was
  written 0 by the project that packed it) is dropped: its metallic map would be wrong truth.
- ARM maps: R ambient occlusion (not used), G roughness, B metalness (Poly Haven's packing).

Needs numpy and Pillow. Runs ../shared/corpus-guard/guard.py on OUT at the end.
"""
import os, re, subprocess, sys

import numpy as np
from PIL import Image

# Sets whose metalness the repository lost: metal with an all-0 metalness channel.
UNKNOWN_METALNESS = {"ambientcg_Metal050A"}
# ../shared beside the checkout: each material's source.txt says what its files are.
SHARED = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "shared")
FILE = re.compile(r"^\s+(\S[^:]*):\s+.*\brole:\s*(.+)$")


def roles(text):
    """(file name, role) for each file line of a source.txt."""
    return [m.groups() for m in map(FILE.match, text.splitlines()) if m]


def load(path, mode):
    return np.asarray(Image.open(path).convert(mode), dtype=np.float64) / 255.0


def box_to(a, size):
    """Box-filters `a` (an integer factor smaller) to `size`²."""
    f = a.shape[0] // size
    if f == 1:
        return a
    shape = (size, f, size, f) + a.shape[2:]
    return a[: size * f, : size * f].reshape(shape).mean(axis=(1, 3))


def slope_sign(normal, height):
    """corr(G − 0.5, dh/drow): negative for DirectX normals, positive for OpenGL."""
    dh = np.gradient(height, axis=0).ravel()
    g = normal[..., 1].ravel() - 0.5
    return float(np.corrcoef(g, dh)[0, 1])


def convert(src, out):
    name = os.path.basename(src)
    text = open(os.path.join(SHARED, "corpus-extra", name, "source.txt"), encoding="utf-8").read()
    convention = re.search(r"^normal convention:\s*(.+)$", text, re.M).group(1)
    files = {}
    for file, role in roles(text):
        files.setdefault(role.strip(), file)
    pick = lambda *keys: next((files[k] for k in keys if k in files), None)
    colour = pick("base colour")
    normal_dx, normal_gl = pick("normal (DirectX)"), pick("normal (OpenGL)")
    normal_any = pick("normal")
    arm = pick("packed AO (R) / roughness (G) / metalness (B), Poly Haven ARM",
               "packed AO (R) / roughness (G) / B = 0, packed by the project")
    rough, metal, height = pick("roughness"), pick("metalness"), pick("displacement (height)")
    if name in UNKNOWN_METALNESS:
        return f"dropped: {name}: a metal whose metalness the repository lost"
    if colour is None or (normal_dx or normal_gl or normal_any) is None or (rough or arm) is None:
        return f"dropped: {name}: lacks a base colour, normal or roughness map"

    maps = {"baseColor": load(os.path.join(src, colour), "RGB")}
    if arm and not rough:
        packed = load(os.path.join(src, arm), "RGB")
        maps["roughness"] = packed[..., 1]
        # Poly Haven's ARM holds metalness in B; a project's own packing wrote B = 0.
        if files.get("packed AO (R) / roughness (G) / metalness (B), Poly Haven ARM") == arm:
            maps["metallic"] = packed[..., 2]
    else:
        maps["roughness"] = load(os.path.join(src, rough), "L")
    if metal:
        maps["metallic"] = load(os.path.join(src, metal), "L")
    if height:
        maps["height"] = load(os.path.join(src, height), "L")

    how = ""
    if normal_dx:
        normal, how = load(os.path.join(src, normal_dx), "RGB"), "DirectX file, unchanged"
    else:
        path = normal_gl or normal_any
        normal = load(os.path.join(src, path), "RGB")
        if "unknown" in convention:
            if "height" not in maps or maps["height"].shape != normal.shape[:2]:
                return f"dropped: {name}: normal convention unknown and no height to test it"
            sign = slope_sign(normal, maps["height"])
            gl = sign > 0
            how = f"convention measured: corr(G, dh/drow) = {sign:+.2f}, " + (
                "OpenGL, G flipped" if gl else "DirectX, unchanged")
        else:
            gl, how = True, "OpenGL (source.txt), G flipped"
        if gl:
            normal = normal.copy()
            normal[..., 1] = 1.0 - normal[..., 1]
    maps["normal"] = normal
    if "metallic" not in maps:
        maps["metallic"] = np.zeros(maps["roughness"].shape)

    size = min(min(m.shape[:2]) for m in maps.values())
    if any(m.shape[0] != m.shape[1] or m.shape[0] % size for m in maps.values()):
        return f"dropped: {name}: maps not square multiples of {size}"
    os.makedirs(os.path.join(out, name), exist_ok=True)
    for key, a in maps.items():
        a = box_to(a, size)
        if key == "normal":
            # Averaged normals shorten: renormalise about the stored centre.
            v = 2.0 * a - 1.0
            v /= np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-6)
            a = (v + 1.0) / 2.0
        img = Image.fromarray(np.clip(np.rint(a * 255.0), 0, 255).astype(np.uint8))
        path = os.path.join(out, name, key + ".png")
        img.save(path + ".part.png")
        os.replace(path + ".part.png", path)
    with open(os.path.join(out, name, "source.txt"), "w", encoding="utf-8") as f:
        f.write(text)
        f.write(f"\nconverted by matup's scripts/prepare-corpus-extra.py: {size}² "
                f"(box-filtered where larger); normals: {how}; "
                f"maps: {', '.join(sorted(maps))}\n")
    return f"{name}: {size}², {how}"


def main():
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    src, out = sys.argv[1:]
    os.makedirs(out, exist_ok=True)
    for m in sorted(os.listdir(src)):
        if os.path.isfile(os.path.join(SHARED, "corpus-extra", m, "source.txt")):
            print(convert(os.path.join(src, m), out))
    guard = os.path.join(SHARED, "corpus-guard", "guard.py")
    sys.exit(subprocess.run([sys.executable, guard, out]).returncode)


if __name__ == "__main__":
    main()
