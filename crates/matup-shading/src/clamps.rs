//! METHOD.md's numerical clamps shared by the shading models: clamped cosines, floored
//! denominators and lengths. Vector arithmetic is glam's; what glam does not have is the
//! floored normalisation (glam's `normalize` returns NaN or a zero vector near 0, where the
//! method needs a finite length and gradient) and its backward pass.

use glam::Vec3;

/// Floor of squared lengths, so lengths and their gradients stay finite.
pub const TINY_LENGTH2: f32 = 1e-20;

/// Dot products are clamped to [1e-8, 0.9999] (METHOD.md).
pub const DOT_MIN: f32 = 1e-8;
pub const DOT_MAX: f32 = 0.9999;
/// Denominators are floored here.
pub const DENOMINATOR_MIN: f32 = 1e-8;

/// The view direction as a glam vector.
pub const VIEW: Vec3 = Vec3::from_array(matup_core::shading::VIEW);

/// Unit vector and length (`sqrt(max(|v|², 1e-20))`).
#[inline]
pub fn normalize(v: Vec3) -> (Vec3, f32) {
    let len = v.length_squared().max(TINY_LENGTH2).sqrt();
    (v * len.recip(), len)
}

/// Gradient with respect to `v` of a function of `v / |v|`, given its gradient `g` with
/// respect to the unit vector `u = v / len`: `(g − u (u·g)) / len`.
#[inline]
pub fn normalize_backward(g: Vec3, u: Vec3, len: f32) -> Vec3 {
    (g - u * u.dot(g)) * len.recip()
}

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
pub fn half_vector(l: Vec3) -> Vec3 {
    normalize(l + VIEW).0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalize_floors_the_length() {
        let (u, len) = normalize(Vec3::new(3.0, 0.0, 4.0));
        assert_eq!(len, 5.0);
        assert!((u - Vec3::new(0.6, 0.0, 0.8)).length() < 1e-7);
        let (u, len) = normalize(Vec3::ZERO);
        assert!((len - 1e-10).abs() < 1e-15);
        assert_eq!(u, Vec3::ZERO, "a zero vector stays finite");
    }

    #[test]
    fn normalize_backward_matches_finite_differences() {
        let v = Vec3::new(0.3, -0.2, 0.9);
        let g = Vec3::new(0.7, 0.1, -0.4);
        let (u, len) = normalize(v);
        let analytic = normalize_backward(g, u, len);
        let f = |v: Vec3| g.dot(normalize(v).0);
        let h = 1e-3;
        for (axis, want) in [Vec3::X, Vec3::Y, Vec3::Z]
            .into_iter()
            .zip(analytic.to_array())
        {
            let numeric = (f(v + axis * h) - f(v - axis * h)) / (2.0 * h);
            assert!((numeric - want).abs() < 1e-3, "{numeric} vs {want}");
        }
    }
}
