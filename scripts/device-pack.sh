#!/bin/sh
# Packs what the device check needs (scripts/device-bench.sh) into .device/, the folder a call
# of the device machine carries: the CUDA builds (with cuDNN) of `matup`, of the device bench
# and of the GPU's stages bench, built here as docs/cuda.md says (its environment set) and
# compressed, with the repository about 62 of the call's 64 MiB; and the 1K² material the
# bench's rows are made of.
# Usage: scripts/device-pack.sh [MATERIAL]   (default ../shared/materials/ambientcg_Metal053C)
set -eu
material=${1:-../shared/materials/ambientcg_Metal053C}
target=${CARGO_TARGET_DIR:-target}
cargo build --release -p matup-cli --features cudnn --bin matup
executable() { sed -n 's/.*Executable .*(\(.*\)).*/\1/p' | tail -n 1; }
bench=$(cargo bench -p matup-cli --features cudnn --bench device --no-run 2>&1 | executable)
stages=$(cargo bench -p matup-upsamplers --features cudnn --bench gpu_stages --no-run 2>&1 |
    executable)
mkdir -p .device/materials
rm -rf .device/materials/* .device/*.xz
cp -r "$material" .device/materials/
# PTX and debug-free code compress about 5:1.
xz -T0 -6 -c "$target/release/matup" >.device/matup.xz
xz -T0 -6 -c "$bench" >.device/device-bench.xz
xz -T0 -6 -c "$stages" >.device/gpu-stages.xz
git rev-parse --short HEAD >.device/commit
git status --short --untracked-files=no | grep -q . && echo "+ changes" >>.device/commit || true
du -sh .device
