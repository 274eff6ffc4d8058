//! What a shading model shades: the parameters of one texel ([`Svbrdf`], also the layout of
//! their gradients), a texel with its position, and the view direction. Below both the
//! models ([`crate::shading`]) and their tensor forms ([`crate::tensor_shading`]).

/// The view direction: the camera is orthographic and looks down −z.
pub const VIEW: [f32; 3] = [0.0, 0.0, 1.0];

/// The differentiable parameters of one texel, and (with the same layout) a gradient with
/// respect to them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Svbrdf {
    /// Linear base colour.
    pub base_color: [f32; 3],
    pub metallic: f32,
    /// Tangent-space normal in the geometry frame (y grows with the row index). Shading models
    /// normalise it themselves, so it need not be unit length.
    pub normal: [f32; 3],
    /// GGX roughness `alpha = r²` (r: perceptual roughness).
    pub alpha: f32,
    /// Anisotropy strength in [−1, 1] (0: isotropic); only anisotropic models read it.
    pub anisotropy: f32,
    /// Tangent direction, radians from +x, in the tangent plane; only anisotropic models read it.
    pub anisotropy_angle: f32,
}

impl Svbrdf {
    /// Number of parameters.
    pub const LEN: usize = 10;
    /// Parameter names, in [`Svbrdf::to_array`] order.
    pub const NAMES: [&'static str; Self::LEN] = [
        "base_color.r",
        "base_color.g",
        "base_color.b",
        "metallic",
        "normal.x",
        "normal.y",
        "normal.z",
        "alpha",
        "anisotropy",
        "anisotropy_angle",
    ];

    pub fn to_array(&self) -> [f32; Self::LEN] {
        let [r, g, b] = self.base_color;
        let [nx, ny, nz] = self.normal;
        [
            r,
            g,
            b,
            self.metallic,
            nx,
            ny,
            nz,
            self.alpha,
            self.anisotropy,
            self.anisotropy_angle,
        ]
    }

    pub fn from_array(a: [f32; Self::LEN]) -> Self {
        Svbrdf {
            base_color: [a[0], a[1], a[2]],
            metallic: a[3],
            normal: [a[4], a[5], a[6]],
            alpha: a[7],
            anisotropy: a[8],
            anisotropy_angle: a[9],
        }
    }

    /// `self += scale * other`, parameter-wise.
    #[inline]
    pub fn add_scaled(&mut self, other: &Svbrdf, scale: f32) {
        for c in 0..3 {
            self.base_color[c] += scale * other.base_color[c];
            self.normal[c] += scale * other.normal[c];
        }
        self.metallic += scale * other.metallic;
        self.alpha += scale * other.alpha;
        self.anisotropy += scale * other.anisotropy;
        self.anisotropy_angle += scale * other.anisotropy_angle;
    }
}

/// A texel to shade: its parameters and its position on the material's square (x, y in
/// [−1, 1], z the displacement).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Texel {
    pub params: Svbrdf,
    pub position: [f32; 3],
}
