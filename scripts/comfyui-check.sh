#!/usr/bin/env bash
# A real ComfyUI running matup's nodes, by hand: ComfyUI is not on a package registry, so this
# stays out of CI. Starts ComfyUI headless on the CPU with this repository in custom_nodes (as a
# clone there would be, under the name matup-nodes),
# posts comfyui/example_workflow_api.json to its /prompt API, waits for the run, and checks
# the images ComfyUI saved against matup.upscale on the same maps.
#
# Usage: scripts/comfyui-check.sh COMFYUI_DIR PYTHON [PORT]
#   COMFYUI_DIR  a checkout of github.com/Comfy-Org/ComfyUI
#   PYTHON       a Python with ComfyUI's requirements and the matup package installed
set -euo pipefail
repo=$(cd "$(dirname "$0")/.." && pwd)
comfy=$(realpath "$1")
python=$2
port=${3:-8188}
ln -sfn "$repo" "$comfy/custom_nodes/matup-nodes"
for map in baseColor normal roughness; do
    cp "$repo/samples/victorian_wood/$map.png" "$comfy/input/victorian_wood_$map.png"
done
out=$(mktemp -d)
"$python" "$comfy/main.py" --cpu --listen 127.0.0.1 --port "$port" --output-directory "$out" \
    --disable-auto-launch >"$out/comfyui.log" 2>&1 &
server=$!
trap 'kill $server 2>/dev/null || true' EXIT
"$python" - "$port" "$repo" "$out" <<'PY'
import json, sys, time, urllib.request
from pathlib import Path

import numpy as np
import matup

port, repo, out = sys.argv[1], Path(sys.argv[2]), Path(sys.argv[3])
url = f"http://127.0.0.1:{port}"
for _ in range(240):
    try:
        urllib.request.urlopen(f"{url}/system_stats", timeout=2)
        break
    except OSError:
        time.sleep(0.5)
else:
    sys.exit(f"ComfyUI did not start: see {out}/comfyui.log")
info = json.load(urllib.request.urlopen(f"{url}/object_info/MatupUpscaleMaterial"))
print("ComfyUI knows", ", ".join(info), "with inputs",
      ", ".join(info["MatupUpscaleMaterial"]["input"]["optional"]))
workflow = json.loads((repo / "comfyui/example_workflow_api.json").read_text())
request = urllib.request.Request(f"{url}/prompt", json.dumps({"prompt": workflow}).encode(),
                                 {"Content-Type": "application/json"})
prompt = json.load(urllib.request.urlopen(request))["prompt_id"]
start = time.time()
while True:
    history = json.load(urllib.request.urlopen(f"{url}/history/{prompt}"))
    if prompt in history and history[prompt].get("status", {}).get("completed"):
        break
    if prompt in history and history[prompt].get("status", {}).get("status_str") == "error":
        sys.exit(json.dumps(history[prompt]["status"], indent=1))
    if time.time() - start > 600:
        sys.exit("the workflow did not finish in 10 minutes")
    time.sleep(1)
print(f"workflow finished in {time.time() - start:.1f} s")
# What the node computes, from the same files as ComfyUI loads them (8-bit codes as floats,
# the node's 16-bit codes, SaveImage's truncation to 8 bits).
sample = repo / "samples/victorian_wood"
maps = {"base_color": matup.read_image(sample / "baseColor.png"),
        "normal": matup.read_image(sample / "normal.png"),
        "roughness": matup.read_image(sample / "roughness.png")[:, :, 0]}
codes = {k: v.astype(np.uint16) * 257 for k, v in maps.items()}
want = matup.upscale(codes, scale=4, progress=False)
saved = history[prompt]["outputs"]
for node, role in (("5", "base_color"), ("6", "normal"), ("7", "roughness")):
    image = saved[node]["images"][0]
    path = out / image["subfolder"] / image["filename"]
    got = matup.read_image(path)
    expected = want[role].astype(np.float32) / 65535.0
    if expected.ndim == 2:
        expected = np.repeat(expected[:, :, None], 3, axis=2)
    expected = np.clip(expected * 255.0, 0, 255).astype(np.uint8)
    diff = np.abs(got[:, :, :3].astype(int) - expected.astype(int))
    print(f"{role}: {path.name} {got.shape[1]}×{got.shape[0]}, largest difference from "
          f"matup.upscale {diff.max()} level(s)")
    assert got.shape[:2] == (512, 512) and diff.max() <= 1, role
print("ComfyUI ran matup's nodes and saved what matup.upscale gives")
PY
