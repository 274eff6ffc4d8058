#!/bin/sh
# Link-time stand-ins for the CUDA libraries that candle's `cuda` feature links (through cudarc's
# `dynamic-linking`): libcuda (the driver's), libcublas, libcublasLt, libcurand and, for the
# `cudnn` feature, libcudnn. With them
# `cargo build --features cuda` links on a machine without the NVIDIA driver or the (large) cuBLAS
# wheels; at run time the loader takes the real libraries by their sonames. No crate makes such
# stubs; each is one empty function per name cudarc declares, which is all a link needs.
# Usage: scripts/cuda-link-stubs.sh DIR   (DIR: where the link looks, e.g. $CUDA_HOME/lib)
set -eu
out=$1
# cudarc's sources are where cargo unpacks them once the workspace's crates are fetched.
cargo fetch --manifest-path "$(dirname "$0")/../Cargo.toml"
cudarc=$(ls -d "${CARGO_HOME:-$HOME/.cargo}"/registry/src/*/cudarc-0.19.* | tail -n 1)
stub() { # NAME SONAME BINDINGS
    test -f "$3" || { echo "cuda-link-stubs: $3 not found" >&2; exit 1; }
    grep -o 'pub unsafe fn [A-Za-z0-9_]*(' "$3" | sed 's/pub unsafe fn //; s/(//' | sort -u |
        awk '{ print "void " $1 "(void) {}" }' >"$out/$1-stub.c"
    cc -shared -fPIC -Wl,-soname,"$2" -o "$out/lib$1.so" "$out/$1-stub.c"
    rm "$out/$1-stub.c"
}
stub cuda libcuda.so.1 "$cudarc/src/driver/sys/mod.rs"
stub cublas libcublas.so.13 "$cudarc/src/cublas/sys/mod.rs"
stub cublasLt libcublasLt.so.13 "$cudarc/src/cublaslt/sys/mod.rs"
stub curand libcurand.so.10 "$cudarc/src/curand/sys/mod.rs"
stub cudnn libcudnn.so.9 "$cudarc/src/cudnn/sys/mod.rs" # the `cudnn` feature's
