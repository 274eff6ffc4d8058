#!/bin/sh
# Packs what the device check needs (scripts/device-bench.sh) into .device/, the folder a call
# of the device machine carries: the CUDA builds (with cuDNN) of `matup`, of the device bench
# and of the GPU's stages bench, built here as docs/cuda.md says (its environment set) and
# compressed together, with the repository about 54 of the call's 64 MiB; and the 1K² material
# the bench's rows are made of. The device bench runs `matup` and needs no CUDA of its own.
# Usage: scripts/device-pack.sh [MATERIAL]   (default ../shared/materials/ambientcg_Metal053C)
set -eu
material=${1:-../shared/materials/ambientcg_Metal053C}
target=${CARGO_TARGET_DIR:-target}
cargo build --release -p matup-cli --features cudnn --bin matup
executable() { sed -n 's/.*Executable .*(\(.*\)).*/\1/p' | tail -n 1; }
# The device bench only runs `matup`: built without CUDA, where the ordinary build is.
bench=$(cargo bench --target-dir target -p matup-cli --bench device --no-run 2>&1 | executable)
stages=$(cargo bench -p matup-upsamplers --features cudnn --bench gpu_stages --no-run 2>&1 |
    executable)
test -x "$bench" && test -x "$stages" || { echo "device-pack: a bench did not build" >&2; exit 1; }
mkdir -p .device/materials /tmp/device-pack
rm -rf .device/materials/* .device/*.xz /tmp/device-pack/*
cp -r "$material" .device/materials/
cp "$target/release/matup" /tmp/device-pack/matup
cp "$bench" /tmp/device-pack/device-bench
cp "$stages" /tmp/device-pack/gpu-stages
# `matup` and the stages bench hold the same PTX of candle's kernels: one stream, with a
# dictionary larger than all three, stores it once (about 20 MB, where three files took 35).
tar -C /tmp/device-pack -cf - matup device-bench gpu-stages |
    xz -T1 --lzma2=preset=6,dict=256MiB >.device/programs.tar.xz
rm -rf /tmp/device-pack
git rev-parse --short HEAD >.device/commit
git status --short --untracked-files=no | grep -q . && echo "+ changes" >>.device/commit || true
du -sh .device
