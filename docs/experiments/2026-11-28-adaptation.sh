#!/usr/bin/env bash
# Per-material adaptation, measured with `matup learn` (docs/experiments/2026-11-28-adaptation.md).
# For each material: its top-left CROP² is the truth, and the truth box-filtered ÷4 is the
# input a user would bring. The shipped network is fine-tuned on that input alone: its
# crops box-filtered ÷4 once more, upsampled back to the input (the run's own degradation).
# The truth is never trained on. `matup learn` validates on the truth at iteration 0 (the
# shipped network: today's defaults) and at the end (the adapted network), both as
# `matup upscale`'s defaults run them, rendered under held-out lights.
#
# Usage: docs/experiments/2026-11-28-adaptation.sh VARIANT ITERATIONS LEARNING_RATE PATCH EVERY [EXTRA_TOML] -- MATERIAL...
#   VARIANT names the output folder runs/adapt/VARIANT; the truth is validated every EVERY
#   steps (the curve); EXTRA_TOML is appended to the learn config (for example
#   'normal_weight = 0.5'); CROP (env, default 512) is the truth's side.
# Prints one line per material: its validation render PSNR / FLIP at each validated step,
# and the seconds its steps took (validation not counted). Needs target/release/matup (or MATUP) and the matup Python package (PYTHON).
set -euo pipefail
variant=$1 iterations=$2 rate=$3 patch=$4 every=$5
extra=${6:-}
shift 6 || shift $#
[ "${1:-}" = "--" ] && shift
matup=${MATUP:-target/release/matup}
python=${PYTHON:-python3}
crop=${CROP:-512}
out=runs/adapt/$variant
mkdir -p "$out"
for material in "$@"; do
    name=$(basename "$material")
    data=runs/adapt/data-$crop/$name work=$out/$name
    mkdir -p "$work"
    if [ ! -d "$data/corpus/input" ]; then
        rm -rf "$data"
        "$python" - "$material" "$data/truth" "$crop" <<'PY'
import sys, matup
m = matup.read_material(sys.argv[1])
side = int(sys.argv[3])
for name, array in m.files.items():
    m.files[name] = array[:side, :side]
matup.write_material(m, sys.argv[2])
PY
        "$matup" downsample "$data/truth" -o "$data/corpus/input" --factor 4 2> /dev/null
    fi
    cat > "$work/learn.toml" <<TOML
base_model = "$PWD/models/span_x4_materials.onnx"
corpus = "$PWD/$data/corpus"
train = ["input"]
val = ["$PWD/$data/truth"]
scale = 4
iterations = $iterations
batch = 3
patch = $patch
lights = 8
learning_rate = $rate
loss = "l11"
checkpoint_every = 25
validate_every = $every
val_crop = $crop
val_lights = 16
seed = 1
$extra
TOML
    "$matup" learn "$work/learn.toml" -o "$work/run" > "$work/learn.log" 2>&1
    "$python" - "$work/run" "$name" <<'PY'
import csv, sys
from pathlib import Path
run, name = Path(sys.argv[1]), sys.argv[2]
rows = [r for r in csv.DictReader((run / "val.csv").open()) if r["material"] != "mean"]
steps = sum(float(r["seconds"]) for r in csv.DictReader((run / "train.csv").open()))
curve = " ".join(f"{r['iteration']}:{float(r['render_psnr']):.3f}/{float(r['render_flip']):.4f}" for r in rows)
print(name, curve, f"steps {steps:.1f} s", flush=True)
PY
done
