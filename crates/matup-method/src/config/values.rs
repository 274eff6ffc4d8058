//! The named values of the settings (an activation, a residual base, a size, a backend…) and
//! their string forms, which read and print the same in TOML, on the CLI and in messages.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Deserializer, Serialize, Serializer};

use matup_core::resample::Kernel;
use matup_core::{Error, Result};

/// Settings with a parameter or aliases (`leaky-relu:0.1`, a kernel's name as a residual base)
/// parse and print by hand; serde goes through those (and their messages), so values read the
/// same in TOML as on the CLI.
macro_rules! serde_through_strings {
    ($($t:ty),*) => {$(
        impl Serialize for $t {
            fn serialize<S: Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
                as_string::serialize(self, s)
            }
        }
        impl<'de> Deserialize<'de> for $t {
            fn deserialize<D: Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
                as_string::deserialize(d)
            }
        }
    )*};
}

/// Settings that are plain names take their string forms from serde (kebab-case), the same
/// in TOML, on the CLI and in messages: an unknown name is refused with the names known.
macro_rules! strings_through_serde {
    ($($t:ty: $what:literal),*) => {$(
        serde_plain::derive_display_from_serialize!($t);
        serde_plain::derive_fromstr_from_deserialize!(
            $t,
            |e| -> Error { Error::Invalid(format!("{}: {e}", $what)) }
        );
    )*};
}

/// The same as a field attribute (`#[serde(with = "as_string")]`), for matup-core's types,
/// which this crate may not implement serde's traits for.
pub(super) mod as_string {
    use std::fmt::Display;
    use std::str::FromStr;

    use serde::{Deserialize, Deserializer, Serializer};

    pub fn serialize<T: Display, S: Serializer>(
        value: &T,
        s: S,
    ) -> std::result::Result<S::Ok, S::Error> {
        s.collect_str(value)
    }

    pub fn deserialize<'de, T, D>(d: D) -> std::result::Result<T, D::Error>
    where
        T: FromStr,
        T::Err: Display,
        D: Deserializer<'de>,
    {
        String::deserialize(d)?
            .parse()
            .map_err(serde::de::Error::custom)
    }
}

serde_through_strings!(Activation, Interpolation, ResidualBase, Chroma, TargetSize);
strings_through_serde!(
    Schedule: "schedule",
    Chain: "chain",
    TargetKind: "targets",
    Selection: "selection",
    Backend: "backend",
    InputQuality: "input quality"
);

/// The hidden layers' nonlinearity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Activation {
    LeakyRelu(f32),
    Relu,
    Gelu,
    Silu,
}

impl FromStr for Activation {
    type Err = Error;
    /// `leaky-relu` (slope 0.01), `leaky-relu:SLOPE`, `relu`, `gelu`, `silu`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "leaky-relu" => Ok(Activation::LeakyRelu(0.01)),
            "relu" => Ok(Activation::Relu),
            "gelu" => Ok(Activation::Gelu),
            "silu" => Ok(Activation::Silu),
            _ => s
                .strip_prefix("leaky-relu:")
                .and_then(|v| v.parse::<f32>().ok())
                // A negative slope is not a leaky ReLU (and the dense layers' backward reads
                // the sign of the pre-activation from the output's, true only for slope ≥ 0).
                .filter(|slope| slope.is_finite() && *slope >= 0.0)
                .map(Activation::LeakyRelu)
                .ok_or_else(|| {
                    Error::Invalid(format!(
                        "unknown activation '{s}'; use leaky-relu, leaky-relu:SLOPE (SLOPE ≥ 0), relu, gelu or silu"
                    ))
                }),
        }
    }
}

impl fmt::Display for Activation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Activation::LeakyRelu(s) if *s == 0.01 => f.write_str("leaky-relu"),
            Activation::LeakyRelu(s) => write!(f, "leaky-relu:{s}"),
            Activation::Relu => f.write_str("relu"),
            Activation::Gelu => f.write_str("gelu"),
            Activation::Silu => f.write_str("silu"),
        }
    }
}

/// Learning-rate schedule over the run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Schedule {
    /// The paper's: the same rate throughout.
    Constant,
    /// Cosine decay from the rate to 0 over all steps.
    Cosine,
}

/// How ×16 (and ×8) is reached.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Chain {
    /// Run the whole method again on the ×4 result (sharper; the default).
    TwoLevel,
    /// Apply the trained ×4 filter again to its own output.
    Single,
}

/// An interpolation kernel named in a configuration: `bilinear`, `bicubic`, `lanczos3`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Interpolation(pub Kernel);

impl FromStr for Interpolation {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "bilinear" => Ok(Interpolation(Kernel::Bilinear)),
            "bicubic" => Ok(Interpolation(Kernel::Bicubic { a: -0.5 })),
            "lanczos3" => Ok(Interpolation(Kernel::Lanczos3)),
            _ => Err(Error::Invalid(format!(
                "unknown interpolation '{s}'; use bilinear, bicubic or lanczos3"
            ))),
        }
    }
}

impl fmt::Display for Interpolation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.0.fmt(f)
    }
}

/// An output size asked for instead of a scale: `4096` or `4K` (a square's side; K is 1024
/// texels), or `4096x2048`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TargetSize {
    pub width: usize,
    /// `None`: the side of a square.
    pub height: Option<usize>,
}

impl FromStr for TargetSize {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        let side = |t: &str| -> Option<usize> {
            let t = t.trim();
            let n = match t.strip_suffix(['K', 'k']) {
                Some(k) => k.parse::<usize>().ok()?.checked_mul(1024)?,
                None => t.parse().ok()?,
            };
            (n > 0).then_some(n)
        };
        let parsed = match s.split_once(['x', '×']) {
            Some((w, h)) => side(w).zip(side(h)).map(|(w, h)| TargetSize {
                width: w,
                height: Some(h),
            }),
            None => side(s).map(|w| TargetSize {
                width: w,
                height: None,
            }),
        };
        parsed.ok_or_else(|| {
            Error::Invalid(format!("size '{s}': give texels as 4096, 4K or 4096x2048"))
        })
    }
}

impl fmt::Display for TargetSize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.height {
            Some(h) => write!(f, "{}x{h}", self.width),
            None => write!(f, "{}", self.width),
        }
    }
}

/// What the filter's residual is added to (and what the prior pulls toward).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ResidualBase {
    /// The LR maps upsampled by a classical kernel (the paper's: bilinear).
    Kernel(Kernel),
    /// Each LR map upsampled on its own by the run's RGB upsampler, as a picture (base colour
    /// sRGB-encoded, normals as colours, grey maps as grey images), then decoded.
    Upsampler,
}

impl FromStr for ResidualBase {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "upsampler" => Ok(ResidualBase::Upsampler),
            _ => match s.parse::<Interpolation>() {
                Ok(Interpolation(k)) => Ok(ResidualBase::Kernel(k)),
                Err(_) => Err(Error::Invalid(format!(
                    "unknown residual base '{s}'; use bilinear, bicubic, lanczos3 or upsampler"
                ))),
            },
        }
    }
}

impl fmt::Display for ResidualBase {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ResidualBase::Kernel(k) => k.fmt(f),
            ResidualBase::Upsampler => f.write_str("upsampler"),
        }
    }
}

/// Where the per-map path's base colour takes its chroma from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Chroma {
    /// The run's RGB upsampler, as it upsamples the colour.
    Upsampler,
    /// A classical kernel on the LR base colour, with the upsampler's luma carried over (a
    /// network may sharpen brightness but then adds no hue of its own).
    Kernel(Kernel),
}

impl FromStr for Chroma {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.parse::<ResidualBase>() {
            Ok(ResidualBase::Upsampler) => Ok(Chroma::Upsampler),
            Ok(ResidualBase::Kernel(k)) => Ok(Chroma::Kernel(k)),
            Err(_) => Err(Error::Invalid(format!(
                "unknown base colour chroma '{s}'; use upsampler, bilinear, bicubic or lanczos3"
            ))),
        }
    }
}

impl fmt::Display for Chroma {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Chroma::Kernel(k) => ResidualBase::Kernel(*k).fmt(f),
            Chroma::Upsampler => ResidualBase::Upsampler.fmt(f),
        }
    }
}

/// The renders the filter is trained to reproduce.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TargetKind {
    /// The paper's: each LR render upsampled by the RGB upsampler S, `S(r_ω)`.
    Direct,
    /// Detail transfer: `R_ω(M_base) + S(r_ω) − B(r_ω)`, the renders of the residual base
    /// plus what S adds to each render beyond B, the base's own upsampler (its kernel, or S
    /// itself for a per-map `upsampler` base, whose targets are then its own renders).
    /// Unlike `S(r_ω)` these are unbiased where S adds nothing: shading is nonlinear, so an
    /// interpolated render is not the render of the interpolated maps.
    Detail,
}

/// Whether a run chooses its settings by validating candidates one scale down.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Selection {
    /// Run the configuration as given.
    Off,
    /// Score the candidate settings on the LR material downsampled once more (where the LR
    /// material is the truth) and run the best.
    Auto,
    /// As `Auto`, with only the upsampler as candidates: the configured one and each of
    /// `Config::select_upsamplers`, the settings otherwise as given.
    Upsampler,
}

/// What the input maps are taken to be: as their files were stored, or as the run is told.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum InputQuality {
    /// Map by map: JPEG where the map was stored as a JPEG (by its file or its texels),
    /// degraded where in another lossy format (lossy WebP, BC1–BC5 blocks: `Material::lossy`,
    /// or BC blocks in its texels), dithered or posterised to few levels, or under one noise
    /// with every map (`matup_core::texel_trace`), clean otherwise.
    Auto,
    /// Clean maps: the material network, its output back-projected onto the input.
    Clean,
    /// Degraded maps: the network trained on degraded inputs, its output not back-projected
    /// (projection would put the input's blocks and noise back).
    Degraded,
    /// JPEG maps: the network trained on JPEG inputs, its base colour projected onto the
    /// input's low frequencies alone (a JPEG keeps its regions' colours), the other maps not.
    Jpeg,
}

/// How training steps are computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backend {
    /// `fused` on the CPU, `tensor` on any other device.
    Auto,
    /// matup's own CPU code: the render loss with each model's hand-derived gradient.
    Fused,
    /// candle tensor operations on any device, differentiated by candle's autograd (the
    /// shading model needs a tensor form).
    Tensor,
}

impl Backend {
    /// The backend `auto` stands for, on the CPU or not.
    pub fn resolve(self, on_cpu: bool) -> Backend {
        match self {
            Backend::Auto if on_cpu => Backend::Fused,
            Backend::Auto => Backend::Tensor,
            other => other,
        }
    }
}
