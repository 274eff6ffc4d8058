#!/bin/sh
# Packs what the device check needs (scripts/device-bench.sh) into .device/, the folder a call
# of the device machine carries: the CUDA build (with cuDNN) of `matup`, the device bench and,
# with STAGES=1, the GPU's stages bench, built here as docs/cuda.md says (its environment set)
# and compressed together, with the repository about 54 of the call's 64 MiB; and the 1K²
# material the bench's rows are made of. The device bench runs `matup` and needs no CUDA of
# its own: it is built where the ordinary build is (target/), and the CUDA `matup` in a
# target folder of its own (CARGO_TARGET_DIR, by default target-cuda/), so neither build
# overwrites the other's binary. The stages bench builds in the bench profile with its own
# features, which recompiles every crate and candle's kernels (about 25 minutes on 2 cores):
# hence only when asked.
# Usage: [STAGES=1] scripts/device-pack.sh [MATERIAL]   (default ../shared/materials/ambientcg_Metal053C)
set -eu
material=${1:-../shared/materials/ambientcg_Metal053C}
cuda_target=${CARGO_TARGET_DIR:-target-cuda}
cargo build --release --target-dir "$cuda_target" -p matup-cli --features cudnn --bin matup
executable() { sed -n 's/.*Executable .*(\(.*\)).*/\1/p' | tail -n 1; }
bench=$(cargo bench --target-dir target -p matup-cli --bench device --no-run 2>&1 | executable)
test -x "$bench" || { echo "device-pack: the device bench did not build" >&2; exit 1; }
mkdir -p .device/materials /tmp/device-pack
rm -rf .device/materials/* .device/*.xz /tmp/device-pack/*
cp "$cuda_target/release/matup" /tmp/device-pack/matup
cp "$bench" /tmp/device-pack/device-bench
if [ "${STAGES:-0}" = 1 ]; then
    stages=$(cargo bench --target-dir "$cuda_target" -p matup-upsamplers --features cudnn \
        --bench gpu_stages --no-run 2>&1 | executable)
    test -x "$stages" || { echo "device-pack: the stages bench did not build" >&2; exit 1; }
    cp "$stages" /tmp/device-pack/gpu-stages
fi
cp -r "$material" .device/materials/
# `matup` and the stages bench hold the same PTX of candle's kernels: one stream, with a
# dictionary larger than all three, stores it once (about 20 MB, where three files took 35).
tar -C /tmp/device-pack -cf - . |
    xz -T1 --lzma2=preset=6,dict=256MiB >.device/programs.tar.xz
rm -rf /tmp/device-pack
git rev-parse --short HEAD >.device/commit
git status --short --untracked-files=no | grep -q . && echo "+ changes" >>.device/commit || true
du -sh .device
