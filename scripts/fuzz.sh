#!/usr/bin/env bash
# Coverage-guided fuzzing of matup's readers (fuzz/, docs/experiments/2026-11-28-fuzzed-readers.md).
#
#   scripts/fuzz.sh seeds               remake the seed corpus fuzz/seeds/TARGET from tests/data
#   scripts/fuzz.sh run MINUTES [T...]  fuzz each target (default: all) for MINUTES, one after
#                                       another, from the seeds and fuzz/corpus/TARGET (where
#                                       new inputs go); crashes land in fuzz/artifacts/TARGET,
#                                       each target's last stats lines in fuzz/last-run.txt
#   scripts/fuzz.sh minimize [T...]     shrink each fuzz/corpus/TARGET to the inputs that add coverage
#
# Needs a nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`); `seeds` needs
# target/release/matup (or MATUP) and python3. Fuzzing never runs in CI: tests/fuzz_corpus.rs
# replays the seeds, the corpus and fuzz/regressions there.
set -euo pipefail
cd "$(dirname "$0")/.."
targets_all=(settings discovery dds tga glb gltf image)
# Scratch files of each input on a RAM disk where there is one.
[ -d /dev/shm ] && export TMPDIR=/dev/shm

seeds() {
    local matup=${MATUP:-target/release/matup} work
    work=$(mktemp -d)
    trap 'rm -rf "$work"' RETURN
    for t in "${targets_all[@]}"; do rm -rf "fuzz/seeds/$t"; mkdir -p "fuzz/seeds/$t"; done
    # Three materials of tests/data at 8², each map alone in its folder, written in every format.
    local dds_formats=(dds-bc1 dds-bc2 dds-bc3 dds-bc4 dds-bc5 dds-bc7 dds-rgba8 dds-bgra8 dds-bgrx8
        dds-rgb8 dds-bgr8 dds-r8 dds-rg8 dds-r16 dds-rg16 dds-rgba16 dds-b5g6r5 dds-bgr5a1 dds-bgra4
        dds-rgb10a2 dds-r16f dds-rgba16f dds-r32f dds-rgba32f)
    local other_formats=(png png16 jpg bmp tiff tiff16 tiff-float exr-half exr-float webp webp-lossless)
    for material in ambientcg_Bricks059 ambientcg_Metal053C polyhaven_denim_fabric; do
        "$matup" downsample "tests/data/materials/$material" -o "$work/$material" --factor 32 > /dev/null 2>&1
        for map in "$work/$material"/*.png; do
            local alone="$work/alone-$material-$(basename "$map" .png)"
            mkdir -p "$alone" && cp "$map" "$alone/"
            for format in "${dds_formats[@]}" tga tga-rle "${other_formats[@]}"; do
                local out="$work/out-$(basename "$alone")-$format"
                "$matup" upscale "$alone" -o "$out" --scale 2 --upsampler bilinear --format "$format" \
                    --quiet > /dev/null 2>&1 || continue # a format that does not hold this map
                for file in "$out"/*; do
                    local name
                    name="$material-$format-$(basename "$file")"
                    case "$format:$file" in
                    *:*/preview.png | *:*/run.json) ;;
                    dds*) cp "$file" "fuzz/seeds/dds/$name" ;;
                    tga*) cp "$file" "fuzz/seeds/tga/$name" ;;
                    *) # The image target's first byte picks the extension (fuzz/src/lib.rs).
                        local pick
                        case "${file##*.}" in png) pick=0 ;; jpg) pick=1 ;; bmp) pick=2 ;;
                        tif | tiff) pick=3 ;; exr) pick=4 ;; webp) pick=5 ;; esac
                        { printf "\\$(printf '%03o' "$pick")"; cat "$file"; } > "fuzz/seeds/image/$name" ;;
                    esac
                done
            done
        done
    done
    # Models: a GLB and a .gltf (data URIs, and the t.png / b.bin the target puts beside it),
    # made of the 8² maps of one material.
    python3 - "$work/ambientcg_Bricks059" <<'PY'
import base64, json, struct, sys
folder = sys.argv[1]
png = {name: open(f"{folder}/{name}.png", "rb").read() for name in ("baseColor", "normal")}
# metallicRoughness (with occlusion in R) is RGB; any RGB image will do for the reader, so
# the base colour's stands in for it.
png["orm"] = png["baseColor"]
names = ("baseColor", "normal", "orm")
def model(images, buffers, views):
    return {
        "asset": {"version": "2.0"},
        "images": images,
        "textures": [{"source": i} for i in range(len(images))],
        "materials": [{
            "name": "bricks",
            "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                     "metallicRoughnessTexture": {"index": 2}},
            "normalTexture": {"index": 1},
            "occlusionTexture": {"index": 2},
        }],
        "buffers": buffers,
        "bufferViews": views,
    }
# GLB: the three images in its binary chunk, each in a bufferView.
bin, views = b"", []
for name in names:
    views.append({"buffer": 0, "byteOffset": len(bin), "byteLength": len(png[name])})
    bin += png[name] + b"\0" * (-len(png[name]) % 4)
images = [{"bufferView": i, "mimeType": "image/png", "name": n} for i, n in enumerate(names)]
text = json.dumps(model(images, [{"byteLength": len(bin)}], views)).encode()
text += b" " * (-len(text) % 4)
chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(bin), b"BIN\0") + bin
open("fuzz/seeds/glb/bricks.glb", "wb").write(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
# .gltf: data URIs; then the files the target puts beside it (t.png, and b.bin as geometry).
uri = lambda b: "data:image/png;base64," + base64.b64encode(b).decode()
images = [{"uri": uri(png[n])} for n in names]
open("fuzz/seeds/gltf/data-uris.gltf", "w").write(json.dumps(model(images, [], [])))
images = [{"uri": "t.png"}, {"uri": uri(png["normal"])}, {"uri": uri(png["orm"])}]
views = [{"buffer": 0, "byteOffset": 0, "byteLength": 64}]
open("fuzz/seeds/gltf/beside.gltf", "w").write(json.dumps(model(images, [{"uri": "b.bin", "byteLength": 64}], views)))
PY
    # Folders as exporters name them: one file name per line.
    local d=fuzz/seeds/discovery
    for material in tests/data/materials/*/; do ls "$material" > "$d/$(basename "$material")"; done
    printf '%s\n' Rock_1K_Color.jpg Rock_1K_NormalGL.jpg Rock_1K_NormalDX.jpg Rock_1K_Roughness.jpg \
        Rock_1K_Displacement.jpg Rock_1K_AmbientOcclusion.jpg Rock.png > "$d/ambientcg"
    printf '%s\n' rock_diff_1k.png rock_nor_gl_1k.exr rock_nor_dx_1k.exr rock_rough_1k.exr \
        rock_arm_1k.png rock_disp_1k.png > "$d/polyhaven"
    printf '%s\n' T_Rock_D.tga T_Rock_N.tga T_Rock_ORDp.tga > "$d/megascans-unreal"
    printf '%s\n' Rock_BaseMap.png Rock_Normal.png Rock_MaskMap.png > "$d/unity-hdrp"
    printf '%s\n' rock01.tga rock01_n.tga rock01_h.tga rock01_s.tga > "$d/game-mod"
    printf '%s\n' Rock_BaseColor.png Rock_Normal.png Rock_OcclusionRoughnessMetallic.png \
        Rock_Height.png Rock_Emissive.png > "$d/substance-unreal"
    printf '%s\n' rock_albedo.png rock_normal.png rock_orm.png rock_gloss.png rock_bump.png \
        preview.jpg > "$d/godot-and-gloss"
    printf '%s\n' Wood_2K_BaseColor.dds Wood_2K_Normal.dds Wood_2K_Roughness.tiff \
        Wood_2K_Metallic.TGA Wood_2K_Height.exr > "$d/mixed-formats"
    # Settings: the shipped configuration files and the documentation's example.
    cp configs/paper.toml fuzz/seeds/settings/paper.toml
    awk '/^```toml/{on=1; next} /^```/{on=0} on' docs/configuration.md > fuzz/seeds/settings/configuration-md.toml
    printf 'scale = 8\ntileable = "auto"\ndevice = "cpu"\n[filter]\nupsampled_maps = "all"\n' \
        > fuzz/seeds/settings/x8.toml
    for t in "${targets_all[@]}"; do echo "$t: $(ls "fuzz/seeds/$t" | wc -l) seeds"; done
}

run() {
    local minutes=$1
    shift
    local targets=("$@")
    [ ${#targets[@]} -eq 0 ] && targets=("${targets_all[@]}")
    : > fuzz/last-run.txt
    for t in "${targets[@]}"; do
        # One worker; a 10 s timeout and a 2 GiB heap limit turn hangs and floods into findings.
        mkdir -p "fuzz/corpus/$t"
        (cd fuzz && cargo +nightly fuzz run --release --debug-assertions "$t" "corpus/$t" "seeds/$t" -- \
            -max_total_time=$((minutes * 60)) -timeout=10 -rss_limit_mb=2048 -print_final_stats=1 \
            2> "../fuzz/$t.log") || echo "$t: finding, see fuzz/$t.log and fuzz/artifacts/$t" >&2
        # Executions, coverage (edges, features), corpus size, and the wall time.
        echo "$t: $(grep -E '^#[0-9]+.*cov:' "fuzz/$t.log" | tail -1 | tr -s ' ') |" \
            "$(grep -E '^Done' "fuzz/$t.log" | tail -1)" | tee -a fuzz/last-run.txt
    done
}

minimize() {
    local targets=("$@")
    [ ${#targets[@]} -eq 0 ] && targets=("${targets_all[@]}")
    for t in "${targets[@]}"; do
        (cd fuzz && cargo +nightly fuzz cmin --release --debug-assertions "$t" "corpus/$t" \
            2> "../fuzz/$t-cmin.log")
        echo "$t: $(ls "fuzz/corpus/$t" | wc -l) inputs"
    done
}

case "${1:-}" in
seeds) seeds ;;
run) shift && run "$@" ;;
minimize) shift && minimize "$@" ;;
*) sed -n '2,12p' "$0" >&2 && exit 2 ;;
esac
