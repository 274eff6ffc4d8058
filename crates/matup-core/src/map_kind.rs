//! The kinds of map a material has, and which way a normal map's green channel points.

use std::fmt;
use std::str::FromStr;

use crate::{Error, Result};

/// How a normal map's green channel is oriented.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default, Hash)]
pub enum NormalConvention {
    /// Green points down the image (Y−): matup's default and its internal frame.
    #[default]
    DirectX,
    /// Green points up the image (Y+).
    OpenGl,
}

impl FromStr for NormalConvention {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "directx" | "dx" => Ok(NormalConvention::DirectX),
            "opengl" | "gl" => Ok(NormalConvention::OpenGl),
            _ => Err(Error::Invalid(format!(
                "unknown normal convention '{s}'; use directx or opengl"
            ))),
        }
    }
}

impl fmt::Display for NormalConvention {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            NormalConvention::DirectX => "directx",
            NormalConvention::OpenGl => "opengl",
        })
    }
}

/// The maps a material can have.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum MapKind {
    BaseColor,
    Normal,
    Roughness,
    Metallic,
    Height,
    Anisotropy,
    AnisotropyAngle,
}

impl MapKind {
    pub const ALL: [MapKind; 7] = [
        MapKind::BaseColor,
        MapKind::Normal,
        MapKind::Roughness,
        MapKind::Metallic,
        MapKind::Height,
        MapKind::Anisotropy,
        MapKind::AnisotropyAngle,
    ];

    /// The value a material without this map has in its place (linear): mid grey (sRGB 0.5)
    /// base colour, a flat normal, roughness 0.5 (Blender's default), no metal; none for the
    /// optional maps.
    pub fn stand_in(self) -> Option<&'static [f32]> {
        match self {
            MapKind::BaseColor => Some(&[0.214_041_14; 3]),
            MapKind::Normal => Some(&[0.0, 0.0, 1.0]),
            MapKind::Roughness => Some(&[0.5]),
            MapKind::Metallic => Some(&[0.0]),
            _ => None,
        }
    }

    /// [`MapKind::stand_in`] in words, for messages.
    pub fn stand_in_words(self) -> &'static str {
        match self {
            MapKind::BaseColor => "mid grey (sRGB 0.5)",
            MapKind::Normal => "a flat normal",
            MapKind::Roughness => "roughness 0.5",
            MapKind::Metallic => "no metal",
            _ => "nothing",
        }
    }

    /// A value of channel `channel` of this map as an 8-bit file stores it, in [0, 1] (not
    /// quantised): colour sRGB-encoded (alpha as it is), a normal's component as `(v + 1) / 2`,
    /// other maps as their values. What degradations act on and new structure is measured in.
    pub fn stored(self, channel: usize, v: f32) -> f32 {
        match self {
            MapKind::BaseColor if channel < 3 => crate::color::linear_to_srgb(v),
            MapKind::Normal => 0.5 * (v + 1.0),
            _ => v,
        }
    }

    /// [`MapKind::stored`] undone (a normal still to be renormalised).
    pub fn from_stored(self, channel: usize, v: f32) -> f32 {
        match self {
            MapKind::BaseColor if channel < 3 => crate::color::srgb_to_linear(v),
            MapKind::Normal => 2.0 * v - 1.0,
            _ => v,
        }
    }

    /// The file stem matup writes this map under.
    pub fn file_stem(self) -> &'static str {
        match self {
            MapKind::BaseColor => "baseColor",
            MapKind::Normal => "normal",
            MapKind::Roughness => "roughness",
            MapKind::Metallic => "metallic",
            MapKind::Height => "height",
            MapKind::Anisotropy => "anisotropy",
            MapKind::AnisotropyAngle => "anisotropyAngle",
        }
    }

    /// The kind whose [`MapKind::file_stem`] is `stem`.
    pub fn from_file_stem(stem: &str) -> Option<MapKind> {
        MapKind::ALL
            .into_iter()
            .find(|kind| kind.file_stem() == stem)
    }
}

/// Settings name a map by its file stem (`baseColor`, `normal`, …).
impl serde::Serialize for MapKind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.file_stem())
    }
}

impl<'de> serde::Deserialize<'de> for MapKind {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        let stem = String::deserialize(d)?;
        MapKind::from_file_stem(&stem).ok_or_else(|| {
            let stems: Vec<&str> = MapKind::ALL.iter().map(|k| k.file_stem()).collect();
            serde::de::Error::custom(format!("no map '{stem}'; maps: {}", stems.join(", ")))
        })
    }
}

impl fmt::Display for MapKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            MapKind::BaseColor => "base colour",
            MapKind::Normal => "normal",
            MapKind::Roughness => "roughness",
            MapKind::Metallic => "metallic",
            MapKind::Height => "height",
            MapKind::Anisotropy => "anisotropy",
            MapKind::AnisotropyAngle => "anisotropy direction",
        })
    }
}
