"""What the Python package costs over the CLI, and a PyTorch network as the callable over the
same network inside matup, side by side on one material (median of the repeats, runs
alternated so both see the same machine).

1. `matup upscale MATERIAL -o OUT` (the CLI) against `matup.upscale_folder(MATERIAL, OUT)`,
   both of the same build, with the defaults.
2. `upsampler="onnx:span_x4_ch48"` against stock SPAN as a PyTorch module through
   spandrel (scripts/span-to-spandrel.py's export of the same file), as the callable, tiled
   as the ONNX network's sidecar says (256-texel tiles, 22 of context, 4 a call); the maps of
   the two are compared too.

Usage: python docs/experiments/2026-11-28-python-package-overhead.py MATERIAL CLI SPAN.safetensors [REPEATS [REPEATS_2]]
(REPEATS for the first comparison, REPEATS_2 for the second, default the same; needs the matup
package, torch and spandrel).
"""

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import spandrel
import torch
from safetensors.torch import load_file

import matup

material, cli, weights = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 3
repeats_2 = int(sys.argv[5]) if len(sys.argv) > 5 else repeats
print(f"{material.name}, {os.cpu_count()} cores, torch {torch.__version__} "
      f"({torch.get_num_threads()} threads), matup {matup.__version__}")


def timed(run):
    with tempfile.TemporaryDirectory() as work:
        out = Path(work, "out")
        start = time.perf_counter()
        run(out)
        seconds = time.perf_counter() - start
        maps = {p.name: matup.read_image(p) for p in out.glob("*.png") if p.name != "preview.png"}
        return seconds, maps


def side_by_side(name_a, run_a, name_b, run_b, repeats):
    times = {name_a: [], name_b: []}
    maps = {}
    for _ in range(repeats):
        for name, run in ((name_a, run_a), (name_b, run_b)):
            seconds, maps[name] = timed(run)
            times[name].append(seconds)
    a, b = (statistics.median(times[n]) for n in (name_a, name_b))
    print(f"  {name_a:<44} {a:8.2f} s (median of {repeats}: {', '.join(f'{t:.2f}' for t in times[name_a])})")
    print(f"  {name_b:<44} {b:8.2f} s (median of {repeats}: {', '.join(f'{t:.2f}' for t in times[name_b])})")
    print(f"  ratio {b / a:.3f}")
    a_maps, b_maps = maps[name_a], maps[name_b]
    worst = max(int(np.abs(a_maps[k].astype(int) - b_maps[k].astype(int)).max()) for k in a_maps)
    print(f"  largest difference between their maps: {worst} level(s)")


print("1. the package against the CLI, defaults")
side_by_side(
    "CLI: matup upscale",
    lambda out: subprocess.run([cli, "upscale", material, "-o", out, "--quiet"], check=True),
    "Python: matup.upscale_folder",
    lambda out: matup.upscale_folder(material, out, progress=False),
    repeats,
)

model = spandrel.ModelLoader().load_from_state_dict(load_file(weights)).eval()


def span(batch):
    with torch.no_grad():
        y = model(torch.from_numpy(batch).permute(0, 3, 1, 2))
        return y.clamp(0, 1).permute(0, 2, 3, 1).numpy()


network = matup.Network(span, scale=4, tile=256, overlap=22, batch=4, name="span_torch")
print("2. stock SPAN inside matup against the same network as a PyTorch callable")
side_by_side(
    "onnx:span_x4_ch48 (matup's executor)",
    lambda out: matup.upscale_folder(material, out, upsampler="onnx:span_x4_ch48", progress=False),
    "PyTorch SPAN (spandrel) as the callable",
    lambda out: matup.upscale_folder(material, out, upsampler=network, progress=False),
    repeats_2,
)
