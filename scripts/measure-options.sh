# Sourced by the scripts that measure matup's outputs (whole-seams.sh, block-edges.sh): reads
# their options into `down`, `scale`, `upsampler` and `config` (matup's flags for a TOML
# configuration), whose defaults the script sets first, and leaves the material folders in
# `materials`; sets `matup` (the binary, $MATUP or the release build) and `work`, a scratch
# folder removed on exit. `--down` is refused where the script gave it no default.
read_measure_options() {
    while [ $# -gt 0 ]; do
        case $1 in
        --down)
            [ -n "${down-}" ] || { echo "--down: not an option of this script" >&2; exit 2; }
            down=$2; shift 2 ;;
        --scale) scale=$2; shift 2 ;;
        --upsampler) upsampler=$2; shift 2 ;;
        --config) config=(--config "$2"); shift 2 ;;
        *) break ;;
        esac
    done
    materials=("$@")
    matup=${MATUP:-target/release/matup}
    work=$(mktemp -d)
    trap 'rm -rf "$work"' EXIT
}
