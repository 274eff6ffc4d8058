#!/usr/bin/env bash
# Makes tests/data/materials/: the real materials the tests read, each the 1024² set of that
# name in ../shared box-filtered ×4 to 256² by `matup downsample` (whole, so a tileable set
# stays tileable), with its source.txt. Run from the repository root with ../shared beside it:
#   cargo build --release -p matup-cli && scripts/make-test-data.sh
set -euo pipefail
cd "$(dirname "$0")/.."
shared=../shared
[ -d "$shared/materials" ] || {
    echo "make-test-data: $shared/materials is missing: put the shared material sets beside the repository" >&2
    exit 1
}
matup=target/release/matup
out=tests/data/materials
materials=(ambientcg_Leather025 ambientcg_Metal053C ambientcg_PavingStones092 ambientcg_Tiles012
    ambientcg_Tiles036 ambientcg_WoodFloor040 polyhaven_coast_sand_rocks_02 polyhaven_denim_fabric
    polyhaven_wood_cabinet_worn_long)
corpus=(ambientcg_Bricks059 ambientcg_Metal009 ambientcg_MetalPlates007
    ambientcg_Rock029 ambientcg_Rock035)
make() { # SET NAME
    local from="$shared/$1/$2" to="$out/$2"
    rm -rf "$to"
    "$matup" downsample --factor 4 -o "$to" "$from"
    { cat "$from/source.txt"; echo
      echo "matup's test copy: the 1024² maps above box-filtered ×4 to 256² by \`matup downsample --factor 4\`"
      echo "(scripts/make-test-data.sh, from ../shared/$1/$2)."; } > "$to/source.txt"
}
for m in "${materials[@]}"; do make materials "$m"; done
for m in "${corpus[@]}"; do make corpus "$m"; done
du -sh "$out"
