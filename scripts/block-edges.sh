#!/usr/bin/env bash
# The texel grid of outputs as users make them: each material box-filtered ÷SCALE into 8-bit
# files (`matup downsample`), upscaled ×SCALE wrapped (`matup upscale --tileable`), and the base
# colour's block-edge ratio read by `matup eval` (steps across the input's texel edges over
# steps inside a texel). `--upsampler SPEC` runs another upsampler (another network),
# `--config FILE` the settings of a TOML configuration. Prints one row per material.
#   scripts/block-edges.sh [--scale S] [--upsampler SPEC] [--config FILE] MATERIAL_FOLDER...
#   (×16 by default; needs jq)
set -euo pipefail
scale=16 upsampler=auto config=()
source "$(dirname "$0")/measure-options.sh"
read_measure_options "$@"
echo "| material (÷$scale → ×$scale) | base colour's block-edge ratio |"
echo "|---|---|"
for m in "${materials[@]}"; do
    name=$(basename "$m")
    "$matup" downsample "$m" -o "$work/$name.lr" --factor "$scale" >/dev/null 2>&1
    "$matup" upscale "$work/$name.lr" -o "$work/$name.out" --scale "$scale" --tileable \
        --upsampler "$upsampler" "${config[@]}" --quiet >/dev/null
    "$matup" eval --candidate "$work/$name.out" --scale "$scale" --json |
        jq -r --arg name "$name" '"| \($name) | \(.map_block_edges.baseColor * 100 | round / 100) |"'
done
