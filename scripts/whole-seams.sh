#!/usr/bin/env bash
# Seams of whole (tileable) materials as users see them: each material box-filtered ÷DOWN,
# upscaled ×SCALE with the defaults, and each output map's wrap-around seam compared, at the
# phase of the input's texel grid, with the true material's at the same size. Prints one row
# per material: the worst map's seam over max(1, the truth's), and each map's pair with its parts.
# `--upsampler SPEC` runs the defaults with another upsampler (another network), `--config FILE`
# with the settings of a TOML configuration.
#   scripts/whole-seams.sh [--down D] [--scale S] [--upsampler SPEC] [--config FILE] MATERIAL_FOLDER...
#   (÷8, ×4; needs jq)
set -euo pipefail
down=8 scale=4 upsampler=auto config=()
source "$(dirname "$0")/measure-options.sh"
read_measure_options "$@"
echo "| material | worst map: seam / max(1, truth's) | each map: output (truth) = wrap / interior step, ‰ (truth's) |"
echo "|---|---|---|"
for m in "${materials[@]}"; do
    name=$(basename "$m")
    "$matup" downsample "$m" -o "$work/$name.lr" --factor "$down" >/dev/null 2>&1
    # The truth at the output's size.
    truth=$m
    if [ "$down" -gt "$scale" ]; then
        truth=$work/$name.truth
        "$matup" downsample "$m" -o "$truth" --factor $((down / scale)) >/dev/null 2>&1
    fi
    "$matup" upscale "$work/$name.lr" -o "$work/$name.out" --scale "$scale" \
        --upsampler "$upsampler" "${config[@]}" --quiet >/dev/null
    "$matup" eval --reference "$truth" --candidate "$work/$name.out" --scale "$scale" \
        --lights 1 --json >"$work/$name.json"
    # Each map: its seam (the truth's), and the two parts of each in thousandths, the
    # wrap-around step / the mean interior step at the grid's phase.
    jq -r --arg name "$name" '
        def r2: . * 100 | round / 100;
        def r1: . * 10 | round / 10;
        def parts: "\(.wrap * 1000 | r1)/\(.interior * 1000 | r1)";
        [.map_seams | to_entries[] | {k: .key, o: .value}] as $o
        | .reference_map_seams as $r
        | .map_seam_steps as $os | .reference_map_seam_steps as $rs
        | ($o | map(.o / ([1, $r[.k]] | max)) | max) as $worst
        | "| \($name) | \($worst | r2) | "
          + ($o | map("\(.k) \(.o | r2) (\($r[.k] | r2)) = \($os[.k] | parts) (\($rs[.k] | parts))")
             | join(", "))
          + " |"' "$work/$name.json"
done
