//! A material's layout: for every file, what each of its channels holds and how it stores
//! it. Loading discovers the layout and reads the maps through it; saving writes every file
//! back through the same table, so a file comes back with the channels it had, each meaning
//! what it meant.
//!
//! Packed files (glTF `metallicRoughness`, Unreal's `OcclusionRoughnessMetallic`, Unity's
//! `MaskMap`, …) are rows of [`PACKINGS`], not code paths; the sources of each convention are
//! in `docs/materials.md`.

use std::f32::consts::TAU;
use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use candle_core::Tensor;

use crate::color::{linear_to_srgb, linear_to_srgb_tensor, srgb_to_linear};
use crate::file_format::FileFormat;
use crate::map_kind::{MapKind, NormalConvention};
use crate::{Error, Result};

/// How a channel's values are stored in its file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stored {
    /// The value itself (data: roughness, metallic, occlusion, masks; colour in float files).
    Linear,
    /// Colour, sRGB-encoded (8/16-bit colour files).
    Srgb,
    /// A normal's component `v` as `(v + 1) / 2`, green pointing as the convention says.
    Normal(NormalConvention),
    /// `1 − v`: roughness stored as gloss or smoothness.
    Inverted,
    /// An angle in radians stored in turns (anisotropy directions).
    Turns,
}

impl Stored {
    /// The value of component `component` from its stored value `v`. Normals come out as
    /// components in matup's (DirectX) frame, still to be renormalised.
    #[inline]
    pub fn decode(self, component: usize, v: f32) -> f32 {
        match self {
            Stored::Linear => v,
            Stored::Srgb => srgb_to_linear(v),
            Stored::Normal(convention) => flip(convention, component, 2.0 * v - 1.0),
            Stored::Inverted => 1.0 - v,
            Stored::Turns => v * TAU,
        }
    }

    /// The stored value of component `component`'s value `v`: the inverse of
    /// [`Stored::decode`].
    #[inline]
    pub fn encode(self, component: usize, v: f32) -> f32 {
        match self {
            Stored::Linear => v,
            Stored::Srgb => linear_to_srgb(v),
            Stored::Normal(convention) => 0.5 * (flip(convention, component, v) + 1.0),
            Stored::Inverted => 1.0 - v,
            Stored::Turns => (v / TAU).rem_euclid(1.0),
        }
    }

    /// [`Stored::encode`] of every value of `t`, on its device.
    pub fn encode_tensor(self, component: usize, t: &Tensor) -> candle_core::Result<Tensor> {
        match self {
            Stored::Linear => Ok(t.clone()),
            Stored::Srgb => linear_to_srgb_tensor(t),
            Stored::Normal(convention) => {
                let sign = if flip(convention, component, 1.0) < 0.0 {
                    -0.5
                } else {
                    0.5
                };
                t.affine(sign, 0.5)
            }
            Stored::Inverted => t.affine(-1.0, 1.0),
            Stored::Turns => {
                let turns = (t / TAU as f64)?;
                &turns - turns.floor()?
            }
        }
    }

    /// How a map of `kind` is stored in matup's own layout, in a float (`float`) or integer
    /// file: colour sRGB-encoded in integer files, normals in `convention`, directions in
    /// turns, everything else as it is.
    pub fn of(kind: MapKind, float: bool, convention: NormalConvention) -> Stored {
        match kind {
            MapKind::BaseColor if !float => Stored::Srgb,
            MapKind::Normal => Stored::Normal(convention),
            MapKind::AnisotropyAngle => Stored::Turns,
            _ => Stored::Linear,
        }
    }
}

/// A normal's green component negated where the convention points it up the image.
#[inline]
fn flip(convention: NormalConvention, component: usize, v: f32) -> f32 {
    if component == 1 && convention == NormalConvention::OpenGl {
        -v
    } else {
        v
    }
}

impl fmt::Display for Stored {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Stored::Linear => f.write_str("linear"),
            Stored::Srgb => f.write_str("sRGB"),
            Stored::Normal(c) => write!(f, "normal, {c}"),
            Stored::Inverted => f.write_str("1 − value"),
            Stored::Turns => f.write_str("turns"),
        }
    }
}

/// What one channel of a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Holds {
    /// Component `.1` of a map matup renders with (0 of a grey map; 0–2 of colour, normals).
    Map(MapKind, usize),
    /// The alpha channel kept with a map's file.
    Alpha(MapKind),
    /// Channel `.1` of the material's carried map `.0` (an index into
    /// [`crate::material::Carried::extras`]).
    Carried(usize, usize),
    /// The alpha channel of carried map `.0`.
    CarriedAlpha(usize),
}

/// One channel of a file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Channel {
    pub holds: Holds,
    pub stored: Stored,
}

/// A file of a material and what each of its channels holds, in the file's channel order.
/// The first file of a layout that holds a map is where it is read from; a later file that
/// holds it too (the same normal map in the other convention) is written from it.
#[derive(Clone, Debug, PartialEq)]
pub struct FileLayout {
    pub path: PathBuf,
    pub format: FileFormat,
    pub channels: Vec<Channel>,
    /// How the file was recognised, for the run's report: "name", "glTF 2.0
    /// metallicRoughness", "--roughness".
    pub recognised_as: String,
}

/// The letters of a file's channels, for messages: R, G, B, A (grey: L, grey + alpha: L, A).
pub fn channel_letter(channels: usize, index: usize) -> &'static str {
    match channels {
        1 | 2 => ["L", "A"][index],
        _ => ["R", "G", "B", "A"][index],
    }
}

impl FileLayout {
    /// The channels that hold component `component` of `kind`, by index.
    pub fn channels_of(&self, kind: MapKind) -> impl Iterator<Item = (usize, &Channel)> {
        (self.channels.iter().enumerate())
            .filter(move |(_, c)| matches!(c.holds, Holds::Map(k, _) if k == kind))
    }

    /// Whether the file holds any of `kind`.
    pub fn holds(&self, kind: MapKind) -> bool {
        self.channels_of(kind).next().is_some()
    }

    /// "roughness ← x_MaskMap.png A (1 − value: Unity HDRP mask map)".
    pub fn describe(&self, kind: MapKind) -> Option<String> {
        let n = self.channels.len();
        let mut letters = Vec::new();
        let mut stored = None;
        let mut seen = Vec::new();
        for (i, channel) in self.channels_of(kind) {
            if let Holds::Map(_, component) = channel.holds {
                // A grey value stored in R, G and B is read from R.
                if !seen.contains(&component) {
                    seen.push(component);
                    letters.push(channel_letter(n, i));
                }
            }
            stored = Some(channel.stored);
        }
        let stored = stored?;
        let name = self.path.file_name().unwrap_or_default().to_string_lossy();
        Some(format!(
            "{kind} ← {name} {} ({stored}; {})",
            letters.concat(),
            self.recognised_as
        ))
    }
}

/// What a channel of a packed file holds, by its convention.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Packed {
    Roughness,
    /// 1 − roughness (Unity's smoothness).
    Smoothness,
    Metallic,
    Occlusion,
    Height,
    /// Unity HDRP's detail mask: carried as data.
    DetailMask,
    /// Nothing the convention defines (glTF's red channel): carried as data, so nothing in
    /// it is lost.
    Unused,
}

impl Packed {
    /// The map this channel supplies, and how it stores it; `None` for data matup carries.
    pub fn supplies(self) -> Option<(MapKind, Stored)> {
        match self {
            Packed::Roughness => Some((MapKind::Roughness, Stored::Linear)),
            Packed::Smoothness => Some((MapKind::Roughness, Stored::Inverted)),
            Packed::Metallic => Some((MapKind::Metallic, Stored::Linear)),
            Packed::Height => Some((MapKind::Height, Stored::Linear)),
            Packed::Occlusion | Packed::DetailMask | Packed::Unused => None,
        }
    }

    /// The name a carried channel is known by (and written under with matup's names).
    pub fn name(self) -> &'static str {
        match self {
            Packed::Roughness => "roughness",
            Packed::Smoothness => "smoothness",
            Packed::Metallic => "metallic",
            Packed::Occlusion => "occlusion",
            Packed::Height => "height",
            Packed::DetailMask => "detailMask",
            Packed::Unused => "unused",
        }
    }
}

/// A packing convention: which channel of a file holds what.
#[derive(Clone, Debug, PartialEq)]
pub struct Packing {
    /// "glTF 2.0 metallicRoughness", "ORM (name spells the channels)".
    pub name: String,
    /// What each channel holds, R first; channels past these are carried as data.
    pub channels: Vec<Packed>,
    /// The normal convention of the exporter that writes this packing, if it has one.
    pub normals: Option<NormalConvention>,
    /// Spelled letter by letter (`ORM` in a name, `--packed orh`): every letter names a
    /// channel the file must have. A table row's last channel may be missing (a mask map
    /// saved without alpha).
    pub spelled: bool,
}

/// A packing convention as a table row.
pub struct PackingRow {
    /// The key `--packing` takes.
    pub key: &'static str,
    pub name: &'static str,
    /// Name parts (lowercase, separators removed) that mark a file of this packing.
    pub words: &'static [&'static str],
    pub channels: &'static [Packed],
    pub normals: Option<NormalConvention>,
}

/// The packing conventions exporters write (sources in `docs/materials.md`). Names that spell
/// their channel order (`ORM`, `ARM`, `RMA`, `MRA`, …) are read by [`spelled_packing`].
pub const PACKINGS: &[PackingRow] = &[
    PackingRow {
        key: "gltf",
        name: "glTF 2.0 metallicRoughness",
        words: &["metallicroughness"],
        channels: &[Packed::Unused, Packed::Roughness, Packed::Metallic],
        normals: Some(NormalConvention::OpenGl),
    },
    PackingRow {
        key: "unreal",
        name: "Unreal OcclusionRoughnessMetallic",
        words: &["occlusionroughnessmetallic"],
        channels: &[Packed::Occlusion, Packed::Roughness, Packed::Metallic],
        normals: Some(NormalConvention::DirectX),
    },
    PackingRow {
        key: "hdrp-mask",
        name: "Unity HDRP mask map",
        words: &["maskmap"],
        channels: &[
            Packed::Metallic,
            Packed::Occlusion,
            Packed::DetailMask,
            Packed::Smoothness,
        ],
        normals: Some(NormalConvention::OpenGl),
    },
    PackingRow {
        key: "unity-metallic-smoothness",
        name: "Unity metallic/smoothness",
        words: &["metallicsmoothness", "metallicgloss", "metallicglossmap"],
        channels: &[
            Packed::Metallic,
            Packed::Unused,
            Packed::Unused,
            Packed::Smoothness,
        ],
        normals: Some(NormalConvention::OpenGl),
    },
    PackingRow {
        key: "megascans-unreal",
        name: "Megascans for Unreal ORDp (occlusion, roughness, displacement)",
        words: &["ordp"],
        channels: &[Packed::Occlusion, Packed::Roughness, Packed::Height],
        normals: Some(NormalConvention::DirectX),
    },
];

impl PackingRow {
    fn packing(&self) -> Packing {
        Packing {
            name: self.name.to_string(),
            channels: self.channels.to_vec(),
            normals: self.normals,
            spelled: false,
        }
    }
}

/// What the letters of a spelled channel order hold: `ORM`, `ARM`, `RMA`, `MRAH`.
const LETTERS: &[(char, Packed)] = &[
    ('o', Packed::Occlusion),
    ('a', Packed::Occlusion),
    ('r', Packed::Roughness),
    ('m', Packed::Metallic),
    ('h', Packed::Height),
];

/// The packing a word spells, channel by channel (`arm`: occlusion, roughness, metallic):
/// letters of [`LETTERS`], each holding something else. A file's name spells three or four,
/// roughness and metallic among them. With `unused` (`--packed`), any one to four letters that
/// hold something, `x` marking a channel that holds nothing (`xrm`, `orh`, `orx`).
pub fn spelled_packing(word: &str, unused: bool) -> Option<Packing> {
    let lengths = if unused { 1..=4 } else { 3..=4 };
    if !lengths.contains(&word.chars().count()) {
        return None;
    }
    let mut channels = Vec::new();
    for letter in word.chars() {
        let held = match LETTERS.iter().find(|(l, _)| *l == letter) {
            Some((_, held)) => *held,
            None if unused && letter == 'x' => Packed::Unused,
            None => return None,
        };
        if held != Packed::Unused && channels.contains(&held) {
            return None;
        }
        channels.push(held);
    }
    let has = |p| channels.contains(&p);
    let enough = match unused {
        true => channels.iter().any(|&c| c != Packed::Unused),
        false => has(Packed::Roughness) && has(Packed::Metallic),
    };
    enough.then(|| Packing {
        name: format!("{} (the name spells its channels)", word.to_uppercase()),
        channels,
        normals: None,
        spelled: true,
    })
}

/// The packing that a file's name parts (words and runs of adjacent words glued) mark, if any.
pub fn packing_of_name(candidates: &[String], words: &[String]) -> Option<Packing> {
    let named = PACKINGS
        .iter()
        .find(|row| candidates.iter().any(|c| row.words.contains(&c.as_str())));
    match named {
        Some(row) => Some(row.packing()),
        None => words.iter().find_map(|w| spelled_packing(w, false)),
    }
}

impl FromStr for Packing {
    type Err = Error;
    /// A row's key (`gltf`, `unreal`, `hdrp-mask`, `unity-metallic-smoothness`) or the letters
    /// of the channels (`orm`, `rma`, `xrm`: x for a channel holding nothing).
    fn from_str(s: &str) -> Result<Packing> {
        let s = s.to_ascii_lowercase();
        if let Some(row) = PACKINGS.iter().find(|row| row.key == s) {
            return Ok(row.packing());
        }
        spelled_packing(&s, true).ok_or_else(|| {
            let keys: Vec<&str> = PACKINGS.iter().map(|r| r.key).collect();
            Error::Invalid(format!(
                "unknown packing '{s}'; use {}, or one to four letters, a file's channels in \
                 order (o or a occlusion, r roughness, m metallic, h height, x nothing; each \
                 once; e.g. orm, rma, xrm, orh)",
                keys.join(", ")
            ))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stored_values_decode_back_to_what_was_encoded() {
        use NormalConvention::*;
        for stored in [
            Stored::Linear,
            Stored::Srgb,
            Stored::Normal(DirectX),
            Stored::Normal(OpenGl),
            Stored::Inverted,
            Stored::Turns,
        ] {
            for component in 0..3 {
                for v in [0.0f32, 0.2, 0.5, 0.9] {
                    let back = stored.decode(component, stored.encode(component, v));
                    assert!(
                        (back - v).abs() < 1e-5,
                        "{stored:?} {component} {v}: {back}"
                    );
                }
            }
        }
        // OpenGL's green points up: a normal leaning down the rows (+y) is dark green there.
        assert!(Stored::Normal(OpenGl).encode(1, 0.8) < 0.5);
        assert!(Stored::Normal(DirectX).encode(1, 0.8) > 0.5);
        assert_eq!(Stored::Normal(OpenGl).encode(0, 0.8), 0.9);
        assert_eq!(Stored::Inverted.decode(0, 0.25), 0.75);
    }

    #[test]
    fn stored_values_encode_alike_on_a_device() {
        use candle_core::Device;
        let values: Vec<f32> = (0..=40).map(|i| i as f32 / 40.0 * 1.2 - 0.1).collect();
        let t = Tensor::new(values.as_slice(), &Device::Cpu).unwrap();
        for stored in [
            Stored::Linear,
            Stored::Srgb,
            Stored::Normal(NormalConvention::DirectX),
            Stored::Normal(NormalConvention::OpenGl),
            Stored::Inverted,
            Stored::Turns,
        ] {
            for component in 0..3 {
                let on_device = stored.encode_tensor(component, &t).unwrap();
                for (v, got) in values.iter().zip(on_device.to_vec1::<f32>().unwrap()) {
                    let want = stored.encode(component, *v);
                    assert!(
                        (got - want).abs() < 1e-6,
                        "{stored:?} {component} {v}: {got}"
                    );
                }
            }
        }
    }

    #[test]
    fn packings_from_names_and_keys() {
        let words = |s: &[&str]| s.iter().map(|w| w.to_string()).collect::<Vec<_>>();
        let gltf = packing_of_name(&words(&["metallicroughness"]), &[]).unwrap();
        assert_eq!(
            gltf.channels,
            [Packed::Unused, Packed::Roughness, Packed::Metallic]
        );
        let arm = packing_of_name(&[], &words(&["rock", "arm", "1k"])).unwrap();
        assert_eq!(
            arm.channels,
            [Packed::Occlusion, Packed::Roughness, Packed::Metallic]
        );
        let mra = spelled_packing("mra", false).unwrap();
        assert_eq!(
            mra.channels,
            [Packed::Metallic, Packed::Roughness, Packed::Occlusion]
        );
        // Not orders: a repeated target, no metallic, other letters, x outside --packing.
        for word in ["rmr", "oar", "arms", "rock", "xrm", "ao"] {
            assert_eq!(spelled_packing(word, false), None, "{word}");
        }
        assert_eq!(
            "xrm".parse::<Packing>().unwrap().channels[0],
            Packed::Unused
        );
        assert_eq!(
            "hdrp-mask".parse::<Packing>().unwrap().channels[3],
            Packed::Smoothness
        );
        assert!("rgb".parse::<Packing>().is_err());
        // Every packing --packed's help describes: any letters, each once, holding something.
        for (word, channels) in [
            (
                "orh",
                vec![Packed::Occlusion, Packed::Roughness, Packed::Height],
            ),
            (
                "orx",
                vec![Packed::Occlusion, Packed::Roughness, Packed::Unused],
            ),
            (
                "ormh",
                vec![
                    Packed::Occlusion,
                    Packed::Roughness,
                    Packed::Metallic,
                    Packed::Height,
                ],
            ),
            ("r", vec![Packed::Roughness]),
        ] {
            let packing = word.parse::<Packing>().unwrap();
            assert_eq!(packing.channels, channels, "{word}");
            assert!(packing.spelled, "{word}: every letter names a channel");
        }
        for word in ["xxx", "oo", "ormhx", "orq"] {
            let e = word.parse::<Packing>().unwrap_err().to_string();
            assert!(e.contains("one to four letters"), "{word}: {e}");
        }
        // Megascans' Unreal packing, by its name.
        let ordp = packing_of_name(&words(&["ordp"]), &words(&["t", "rock", "4k", "ordp"]));
        assert_eq!(
            ordp.unwrap().channels,
            [Packed::Occlusion, Packed::Roughness, Packed::Height]
        );
    }
}
