#!/bin/bash
# The GPU check of the default path, in one call of the device machine (about 5 minutes, at
# most 8): it builds nothing. It unpacks what scripts/device-pack.sh left in .device/, finds
# the CUDA 13 and cuDNN 9 libraries of the machine's PyTorch, runs the main job on the GPU
# (which also lets the driver compile candle's PTX once), then the device bench's rows and
# the GPU's stages bench (if packed), then the same network's time in another engine (PyTorch's cuDNN:
# scripts/torch-network-time.py), and prints their tables. Copies of their output land in $OUT.
# Run as: device run `bash scripts/device-bench.sh`, carrying .device.
# Settings: ROWS (default main,1k,4k,library), CPU_ROWS (main,1k), VARIANTS (network options
# tried on the 1K² row, `;` between them; default TF32, the one lower precision within reach).
set -euo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-/tmp/device-out}
mkdir -p "$out" /tmp/device
echo "commit $(cat .device/commit)"
xz -dc .device/programs.tar.xz | tar -C /tmp/device -xf -
chmod +x /tmp/device/*
read -r lib cudnn < <(python3 -c 'import glob, os, nvidia
roots = list(nvidia.__path__)
cuda = [os.path.join(r, "cu13", "lib") for r in roots if os.path.isdir(os.path.join(r, "cu13", "lib"))]
cudnn = [os.path.dirname(f) for r in roots for f in glob.glob(os.path.join(r, "**", "libcudnn.so.9"), recursive=True)]
print(cuda[0], cudnn[0])')
export LD_LIBRARY_PATH=$lib:$cudnn:${LD_LIBRARY_PATH:-}
if ldd /tmp/device/matup | grep "not found"; then echo "libraries missing from $lib"; exit 1; fi
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
echo "$(nproc) CPU cores"
start=$(date +%s%N)
/tmp/device/matup upscale samples/victorian_wood -o /tmp/device/smoke --device cuda --quiet
echo "main job, first run (the driver compiles the PTX): $((($(date +%s%N) - start) / 1000000)) ms"
MATUP_BIN=/tmp/device/matup MATUP_REPO=$PWD \
    MATUP_BENCH_MATERIAL=$(ls -d .device/materials/* | head -n 1) \
    MATUP_BENCH_ROWS=${ROWS:-main,1k,4k,library} MATUP_BENCH_CPU_ROWS=${CPU_ROWS:-main,1k} \
    MATUP_BENCH_GPU_VARIANTS=${VARIANTS:-precision=tf32} \
    /tmp/device/device-bench --bench 2>&1 | tee "$out/bench.txt"
# The SR stage's parts: the network alone, the outputs' download, the host's blending (where
# the pack holds the stages bench: STAGES=1 scripts/device-pack.sh).
if [ -x /tmp/device/gpu-stages ]; then
    /tmp/device/gpu-stages --bench 2>&1 | tee "$out/gpu-stages.txt" || echo "gpu-stages failed"
fi
# Another engine on the same network and GPU: PyTorch's cuDNN, as onnxruntime's CUDA provider.
python3 scripts/torch-network-time.py 2>&1 | tee "$out/torch.txt" || true
