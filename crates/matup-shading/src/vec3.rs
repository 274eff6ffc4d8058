//! The few 3-vector operations the shading models need, with METHOD.md's clamps.

pub type V3 = [f32; 3];

#[inline]
pub fn dot(a: V3, b: V3) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[inline]
pub fn scale(a: V3, s: f32) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

#[inline]
pub fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a + s·b`.
#[inline]
pub fn add_scaled(a: V3, b: V3, s: f32) -> V3 {
    [a[0] + s * b[0], a[1] + s * b[1], a[2] + s * b[2]]
}

/// Floor of squared lengths, so lengths and their gradients stay finite.
pub const TINY_LENGTH2: f32 = 1e-20;

/// Unit vector and length (`sqrt(max(|v|², 1e-20))`).
#[inline]
pub fn normalize(v: V3) -> (V3, f32) {
    let len = dot(v, v).max(TINY_LENGTH2).sqrt();
    (scale(v, 1.0 / len), len)
}

/// Gradient with respect to `v` of a function of `v / |v|`, given its gradient `g` with
/// respect to the unit vector `u = v / len`: `(g − u (u·g)) / len`.
#[inline]
pub fn normalize_backward(g: V3, u: V3, len: f32) -> V3 {
    scale(add_scaled(g, u, -dot(u, g)), 1.0 / len)
}

/// Dot products are clamped to [1e-8, 0.9999] (METHOD.md).
pub const DOT_MIN: f32 = 1e-8;
pub const DOT_MAX: f32 = 0.9999;
/// Denominators are floored here.
pub const DENOMINATOR_MIN: f32 = 1e-8;

/// A clamped cosine and whether it was left unclamped (1) or clamped (0, no gradient).
#[inline]
pub fn clamp_dot(x: f32) -> (f32, f32) {
    if x < DOT_MIN {
        (DOT_MIN, 0.0)
    } else if x > DOT_MAX {
        (DOT_MAX, 0.0)
    } else {
        (x, 1.0)
    }
}

/// The half vector of `l` and the view direction.
#[inline]
pub fn half_vector(l: V3) -> V3 {
    normalize(add(l, matup_core::shading::VIEW)).0
}
