// What the maps hold: f32, or f16 where the adapter has `shader-f16` and the engine runs in
// half precision (`gpu_graph.rs` swaps this first line). Sums are f32 either way.
alias Value = f32;

// The GPU engine's kernels (`gpu_graph.rs`): the operations of matup's executor on planar
// `[batch, channels, height, width]` maps of `Value`. Every kernel reads its shape from `p`.
//
// A per-texel chain (`chain`) is a list of u32 words: its length, then each operation as a code
// followed by its arguments (f32 bits):
//   0 sigmoid, 1 SiLU, 2 ReLU, 3 leaky ReLU (slope), 4 clip (low, high),
//   5 PReLU (n, n slopes: one, or one per channel),
//   6 + 2·arith + constant_first: arithmetic with a constant (n, n values), arith 0 add,
//     1 sub, 2 mul, 3 div.

struct Params {
    // Texels per plane side.
    width: u32,
    height: u32,
    // Channels in (the map read) and out (the map written).
    channels_in: u32,
    channels_out: u32,
    // The convolution's kernel size; a resize's or depth-to-space's factor in kernel_w.
    kernel_h: u32,
    kernel_w: u32,
    // Convolutions: 1 where the image repeats past its edges, 0 for zeros. Arithmetic: the
    // operation. Depth-to-space: 1 for CRD order.
    mode: u32,
    // Convolutions: output-channel groups per image. Element-wise kernels: workgroups per row
    // of the dispatch.
    groups: u32,
    // Values in the map written (element-wise kernels).
    count: u32,
    // Convolutions: where the bias starts in `weights`. Channel copies: the first channel
    // written.
    offset: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read> x: array<Value>;
@group(0) @binding(2) var<storage, read> second: array<Value>;
// A convolution's weights `[out, in, kh, kw]`, then its bias from `offset`.
@group(0) @binding(3) var<storage, read> weights: array<f32>;
@group(0) @binding(4) var<storage, read> chain: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<Value>;

fn sigmoid(v: f32) -> f32 {
    // Clamped: exp of a large argument is infinite, which some drivers do not keep.
    return 1.0 / (1.0 + exp(-clamp(v, -80.0, 80.0)));
}

fn arith(a: f32, b: f32, op: u32) -> f32 {
    switch op {
        case 0u: { return a + b; }
        case 1u: { return a - b; }
        case 2u: { return a * b; }
        default: { return a / b; }
    }
}

// One value of a chain argument list of `n` values at `at`: the channel's, or the one for all.
fn per_channel(at: u32, n: u32, channel: u32) -> f32 {
    return bitcast<f32>(chain[at + select(0u, channel, n > 1u)]);
}

fn apply_chain(value: f32, channel: u32) -> f32 {
    var v = value;
    var at = 1u;
    let ops = chain[0];
    for (var k = 0u; k < ops; k++) {
        let code = chain[at];
        if code == 0u {
            v = sigmoid(v);
            at += 1u;
        } else if code == 1u {
            v = v * sigmoid(v);
            at += 1u;
        } else if code == 2u {
            v = max(v, 0.0);
            at += 1u;
        } else if code == 3u {
            let slope = bitcast<f32>(chain[at + 1u]);
            v = select(v, slope * v, v < 0.0);
            at += 2u;
        } else if code == 4u {
            v = clamp(v, bitcast<f32>(chain[at + 1u]), bitcast<f32>(chain[at + 2u]));
            at += 3u;
        } else if code == 5u {
            let n = chain[at + 1u];
            v = select(v, per_channel(at + 2u, n, channel) * v, v < 0.0);
            at += 2u + n;
        } else {
            let n = chain[at + 1u];
            let c = per_channel(at + 2u, n, channel);
            let op = (code - 6u) / 2u;
            if (code - 6u) % 2u == 1u {
                v = arith(c, v, op);
            } else {
                v = arith(v, c, op);
            }
            at += 2u + n;
        }
    }
    return v;
}

// --- Convolution: stride 1, odd kernels up to MAX_K, the size kept. -------------------------
// A workgroup computes an 8×8 block of texels for OUT output channels of one image: each
// invocation one texel's OUT sums. Input channels are taken IN at a time, their patch and
// weights staged in workgroup memory.

const TILE: u32 = 8u;
const OUT: u32 = 8u;
const IN: u32 = 8u;
const MAX_K: u32 = 5u;
const PATCH: u32 = 12u; // TILE + MAX_K - 1
const TAPS: u32 = 25u;  // MAX_K²

var<workgroup> staged: array<f32, 1152>;   // IN · PATCH²
var<workgroup> taps: array<f32, 1600>;    // IN · OUT · TAPS

// `i` along an axis of `n` texels as the padding reads it: wrapped, or -1 outside.
fn source_index(i: i32, n: u32) -> i32 {
    if p.mode == 1u {
        let m = i32(n);
        return ((i % m) + m) % m;
    }
    if i < 0 || i >= i32(n) {
        return -1;
    }
    return i;
}

@compute @workgroup_size(8, 8, 1)
fn conv(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(local_invocation_id) local: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let image = group.z / p.groups;
    let first_out = (group.z % p.groups) * OUT;
    let kh = p.kernel_h;
    let kw = p.kernel_w;
    let ph = TILE + kh - 1u;
    let pw = TILE + kw - 1u;
    let top = i32(group.y * TILE) - i32(kh / 2u);
    let left = i32(group.x * TILE) - i32(kw / 2u);
    let plane = p.width * p.height;
    var sums: array<f32, 8>;
    for (var o = 0u; o < OUT; o++) {
        sums[o] = 0.0;
    }
    for (var first_in = 0u; first_in < p.channels_in; first_in += IN) {
        let patch_values = IN * ph * pw;
        for (var i = lane; i < patch_values; i += 64u) {
            let c = i / (ph * pw);
            let r = i % (ph * pw);
            let py = r / pw;
            let px = r % pw;
            let sy = source_index(top + i32(py), p.height);
            let sx = source_index(left + i32(px), p.width);
            var v = 0.0;
            if first_in + c < p.channels_in && sy >= 0 && sx >= 0 {
                v = f32(x[(image * p.channels_in + first_in + c) * plane + u32(sy) * p.width + u32(sx)]);
            }
            staged[(c * PATCH + py) * PATCH + px] = v;
        }
        let k2 = kh * kw;
        let tap_values = IN * OUT * k2;
        for (var i = lane; i < tap_values; i += 64u) {
            let t = i % k2;
            let o = (i / k2) % OUT;
            let c = i / (k2 * OUT);
            var v = 0.0;
            if first_in + c < p.channels_in && first_out + o < p.channels_out {
                v = weights[((first_out + o) * p.channels_in + first_in + c) * k2 + t];
            }
            taps[(c * OUT + o) * TAPS + t] = v;
        }
        workgroupBarrier();
        let ins = min(IN, p.channels_in - first_in);
        for (var c = 0u; c < ins; c++) {
            for (var ky = 0u; ky < kh; ky++) {
                for (var kx = 0u; kx < kw; kx++) {
                    let v = staged[(c * PATCH + local.y + ky) * PATCH + local.x + kx];
                    let t = c * OUT * TAPS + ky * kw + kx;
                    for (var o = 0u; o < OUT; o++) {
                        sums[o] = fma(v, taps[t + o * TAPS], sums[o]);
                    }
                }
            }
        }
        workgroupBarrier();
    }
    let ox = group.x * TILE + local.x;
    let oy = group.y * TILE + local.y;
    if ox >= p.width || oy >= p.height {
        return;
    }
    for (var o = 0u; o < OUT; o++) {
        let channel = first_out + o;
        if channel < p.channels_out {
            let v = apply_chain(sums[o] + weights[p.offset + channel], channel);
            y[(image * p.channels_out + channel) * plane + oy * p.width + ox] = Value(v);
        }
    }
}

// --- Element-wise kernels: one value an invocation, 256 a workgroup, `groups` a row. ------

fn element(group: vec3<u32>, lane: u32) -> u32 {
    return (group.y * p.groups + group.x) * 256u + lane;
}

// y = chain(x), `channels_in` channels of `width · height` values.
@compute @workgroup_size(256, 1, 1)
fn per_texel(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = element(group, lane);
    if i >= p.count {
        return;
    }
    let channel = (i / (p.width * p.height)) % p.channels_in;
    y[i] = Value(apply_chain(f32(x[i]), channel));
}

// y = x (op) second, maps of one shape.
@compute @workgroup_size(256, 1, 1)
fn arithmetic(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = element(group, lane);
    if i >= p.count {
        return;
    }
    y[i] = Value(arith(f32(x[i]), f32(second[i]), p.mode));
}

// Channels into `factor × factor` texels: x is `[b, c·f², h, w]`, y `[b, c, h·f, w·f]`; DCR
// reads channel (fy·f + fx)·c + k, CRD k·f² + fy·f + fx. `width`, `height` are x's.
@compute @workgroup_size(256, 1, 1)
fn depth_to_space(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = element(group, lane);
    if i >= p.count {
        return;
    }
    let f = p.kernel_w;
    let ow = p.width * f;
    let oh = p.height * f;
    let ox = i % ow;
    let oy = (i / ow) % oh;
    let k = (i / (ow * oh)) % p.channels_out;
    let image = i / (ow * oh * p.channels_out);
    let offset = (oy % f) * f + ox % f;
    let channel = select((offset * p.channels_out) + k, k * f * f + offset, p.mode == 1u);
    y[i] = x[((image * p.channels_in + channel) * p.height + oy / f) * p.width + ox / f];
}

// Nearest resize by an integer factor (`kernel_w`): y[.., oy, ox] = x[.., oy / f, ox / f].
@compute @workgroup_size(256, 1, 1)
fn resize_nearest(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = element(group, lane);
    if i >= p.count {
        return;
    }
    let f = p.kernel_w;
    let ow = p.width * f;
    let oh = p.height * f;
    let ox = i % ow;
    let oy = (i / ow) % oh;
    let plane = i / (ow * oh);
    y[i] = x[(plane * p.height + oy / f) * p.width + ox / f];
}

// A map's channels into a wider map's, from channel `offset` (a concatenation's part): x is
// `[b, channels_in, h, w]`, y `[b, channels_out, h, w]`; `count` is x's values.
@compute @workgroup_size(256, 1, 1)
fn copy_channels(@builtin(workgroup_id) group: vec3<u32>, @builtin(local_invocation_index) lane: u32) {
    let i = element(group, lane);
    if i >= p.count {
        return;
    }
    let plane = p.width * p.height;
    let t = i % plane;
    let c = (i / plane) % p.channels_in;
    let image = i / (plane * p.channels_in);
    y[(image * p.channels_out + p.offset + c) * plane + t] = x[i];
}
