#!/usr/bin/env bash
# The Python package's PyTorch tests: a torch module as matup's network, and the ComfyUI
# nodes called as ComfyUI calls them (torch tensors, a spandrel model as UPSCALE_MODEL).
# PyPI's torch for Linux brings NVIDIA's libraries (about 4 GB installed), so these run here
# and not in .ci/run. Usage: scripts/python-torch-tests.sh [VENV] (default target/torch-venv).
set -euo pipefail
cd "$(dirname "$0")/.."
venv=$(realpath -m "${1:-target/torch-venv}")
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install --quiet maturin pytest numpy torch spandrel
(cd crates/matup-python && VIRTUAL_ENV="$venv" "$venv/bin/maturin" develop --quiet)
"$venv/bin/python" -m pytest crates/matup-python/tests/test_torch.py -v
