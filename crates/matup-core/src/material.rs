//! [`Material`]: an SVBRDF as planar f32 maps with every convention resolved.

use std::collections::BTreeMap;
use std::path::PathBuf;

use crate::layout::FileLayout;
use crate::map::{Dihedral, Map};
use crate::resample::{
    area_resize, box_downsample, neighbourhood_ranges, upsample, Border, Kernel,
};
use crate::shading::{Svbrdf, Texel};

/// `alpha = r²` is clamped to `[MIN_ALPHA, 1]`.
pub const MIN_ALPHA: f32 = 2e-3;
/// Height displaces the shading point by `DISPLACEMENT · (h − ½)`.
pub const DISPLACEMENT: f32 = 0.01;

pub use crate::file_format::{
    BlockQuality, DdsCodec, DdsFormat, FileFormat, SampleDepth, DDS_CODECS,
};
pub use crate::map_kind::{MapKind, NormalConvention};

/// Where a loaded material came from, so it can be saved the way it was given.
#[derive(Clone, Debug, PartialEq)]
pub struct MaterialOrigin {
    /// The folder it was loaded from (outputs never go there).
    pub folder: PathBuf,
    /// Every file read, with what each channel holds and how it is stored; writing mirrors
    /// it.
    pub layout: Vec<FileLayout>,
    /// The convention of the normal map read.
    pub normal_convention: NormalConvention,
    /// How that convention was found: the name, the option, the exporter, or measured.
    pub normal_evidence: String,
    /// The size of its maps: [width, height].
    pub size: [usize; 2],
    /// The folder's images of another size than its maps, not loaded: each size is a
    /// material of its own (`matup upscale` upscales them after the maps, by the same factor).
    pub other_sizes: Vec<OtherSizeFile>,
    /// What else the run should say about how the files were read (a flag that replaced a
    /// file of the folder).
    pub notes: Vec<String>,
    /// What the material's source says of its tiling, where it says something: whether it
    /// tiles, and why (a glTF model's UVs read one copy of an atlas). Without it, and without
    /// a setting, its edges decide.
    pub tiling: Option<(bool, String)>,
}

/// An image of a material's folder whose size is not its maps', carried as a material of its
/// own size.
#[derive(Clone, Debug, PartialEq)]
pub struct OtherSizeFile {
    pub path: PathBuf,
    /// [width, height].
    pub size: [usize; 2],
    /// Whether its name says it holds data (occlusion, a mask) rather than colour.
    pub data: bool,
}

impl MaterialOrigin {
    /// The file a map of `kind` was read from, if one was.
    pub fn source(&self, kind: MapKind) -> Option<&FileLayout> {
        self.layout.iter().find(|f| f.holds(kind))
    }

    /// For every map read, the file and channels it came from and how they were stored
    /// ("roughness ← x_MaskMap.png A (1 − value; Unity HDRP mask map)"), then how the normal
    /// convention was found.
    pub fn sources(&self) -> Vec<String> {
        let mut lines: Vec<String> = (MapKind::ALL.into_iter())
            .filter_map(|kind| self.source(kind)?.describe(kind))
            .collect();
        if self.source(MapKind::Normal).is_some() {
            lines.push(format!(
                "normal convention: {} ({})",
                self.normal_convention, self.normal_evidence
            ));
        }
        lines
    }
}

/// A physically based material: planar f32 maps of one size, conventions resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    /// Linear RGB base colour.
    pub base_color: Map,
    /// Unit tangent-space normals (3 channels) in the geometry frame: x right, y down the rows
    /// (the DirectX convention), z out of the surface.
    pub normal: Map,
    /// Perceptual roughness `r` (1 channel); shading uses `alpha = r²`.
    pub roughness: Map,
    /// Metallic in [0, 1] (1 channel); constant 0 when the input has none.
    pub metallic: Map,
    /// Height in [0, 1] (1 channel), if the input has one.
    pub height: Option<Map>,
    /// Anisotropy strength in [−1, 1], if any.
    pub anisotropy: Option<Map>,
    /// Anisotropy direction in radians from +x, if any.
    pub anisotropy_angle: Option<Map>,
    /// Alpha channels and the folder's other maps, carried through unrendered.
    pub carried: Carried,
    pub origin: Option<MaterialOrigin>,
    /// The maps whose texels went through lossy storage on their way here, each with what it
    /// was ("JPEG", "BC1 blocks"): read from their files' formats, or set by a simulated
    /// degradation (`crate::degrade`). An upscale run reads these maps as degraded
    /// (`input_quality = "auto"`). Averaging blocks of texels (`box_downsample`) clears it.
    pub lossy: BTreeMap<MapKind, String>,
}

/// What a material carries beside the maps it is rendered with: matup upsamples these as
/// pictures and writes them back, so nothing of the input is left behind.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Carried {
    /// The alpha channel of a map's file (cutouts, decals), by the map it came with.
    pub alpha: BTreeMap<MapKind, Map>,
    /// Every other map of the folder (occlusion, opacity, emission, …).
    pub extras: Vec<Extra>,
}

/// A map matup does not render with, as its file holds it.
#[derive(Clone, Debug, PartialEq)]
pub struct Extra {
    /// The stem of the file it is written to: its own file's.
    pub name: String,
    /// The file it came from.
    pub source: PathBuf,
    pub format: FileFormat,
    /// Grey or RGB; RGB as linear colour (decoded from sRGB when the file stores integers, as
    /// base colour is), grey as stored.
    pub map: Map,
    /// Its alpha channel, if the file has one.
    pub alpha: Option<Map>,
}

impl Carried {
    /// Every map through `f`.
    pub fn map_maps(&self, f: impl Fn(&Map) -> Map) -> Carried {
        Carried {
            alpha: self.alpha.iter().map(|(k, m)| (*k, f(m))).collect(),
            extras: (self.extras.iter())
                .map(|e| Extra {
                    map: f(&e.map),
                    alpha: e.alpha.as_ref().map(&f),
                    ..e.clone()
                })
                .collect(),
        }
    }

    /// Every map, in a fixed order (that of [`Carried::maps_mut`]).
    pub fn maps(&self) -> impl Iterator<Item = &Map> {
        (self.alpha.values()).chain(
            (self.extras.iter()).flat_map(|e| std::iter::once(&e.map).chain(e.alpha.as_ref())),
        )
    }

    /// Every map, in the order of [`Carried::maps`].
    pub fn maps_mut(&mut self) -> impl Iterator<Item = &mut Map> {
        (self.alpha.values_mut()).chain(
            (self.extras.iter_mut())
                .flat_map(|e| std::iter::once(&mut e.map).chain(e.alpha.as_mut())),
        )
    }

    pub fn is_empty(&self) -> bool {
        self.alpha.is_empty() && self.extras.is_empty()
    }
}

impl Material {
    /// A flat material of constant values (tests, examples).
    pub fn uniform(size: usize, base_color: [f32; 3], roughness: f32, metallic: f32) -> Self {
        Material {
            base_color: Map::from_fn(size, size, 3, |c, _, _| base_color[c]),
            normal: Map::from_fn(size, size, 3, |c, _, _| if c == 2 { 1.0 } else { 0.0 }),
            roughness: Map::filled(size, size, 1, roughness),
            metallic: Map::filled(size, size, 1, metallic),
            height: None,
            anisotropy: None,
            anisotropy_angle: None,
            carried: Carried::default(),
            origin: None,
            lossy: BTreeMap::new(),
        }
    }

    pub fn width(&self) -> usize {
        self.base_color.width()
    }
    pub fn height_px(&self) -> usize {
        self.base_color.height()
    }

    /// The map of a kind, if the material has it.
    pub fn map(&self, kind: MapKind) -> Option<&Map> {
        match kind {
            MapKind::BaseColor => Some(&self.base_color),
            MapKind::Normal => Some(&self.normal),
            MapKind::Roughness => Some(&self.roughness),
            MapKind::Metallic => Some(&self.metallic),
            MapKind::Height => self.height.as_ref(),
            MapKind::Anisotropy => self.anisotropy.as_ref(),
            MapKind::AnisotropyAngle => self.anisotropy_angle.as_ref(),
        }
    }

    pub fn map_mut(&mut self, kind: MapKind) -> Option<&mut Map> {
        match kind {
            MapKind::BaseColor => Some(&mut self.base_color),
            MapKind::Normal => Some(&mut self.normal),
            MapKind::Roughness => Some(&mut self.roughness),
            MapKind::Metallic => Some(&mut self.metallic),
            MapKind::Height => self.height.as_mut(),
            MapKind::Anisotropy => self.anisotropy.as_mut(),
            MapKind::AnisotropyAngle => self.anisotropy_angle.as_mut(),
        }
    }

    /// The position of texel `index` on the material's square [−1, 1]², displaced by height.
    #[inline]
    pub fn position(&self, index: usize) -> [f32; 3] {
        texel_position(index, self.width(), self.height_px(), self.height.as_ref())
    }

    /// The shading parameters of texel `index`.
    #[inline]
    pub fn texel(&self, index: usize) -> Texel {
        let r = self.roughness.data()[index];
        Texel {
            params: Svbrdf {
                base_color: self.base_color.texel(index),
                metallic: self.metallic.data()[index],
                normal: self.normal.texel(index),
                alpha: alpha_from_roughness(r),
                anisotropy: self.anisotropy.as_ref().map_or(0.0, |m| m.data()[index]),
                anisotropy_angle: self
                    .anisotropy_angle
                    .as_ref()
                    .map_or(0.0, |m| m.data()[index]),
            },
            position: self.position(index),
        }
    }

    /// Applies a map-wise operation to every map, then restores the invariants (unit
    /// normals, value ranges).
    fn map_every(&self, f: impl Fn(&Map) -> Map) -> Material {
        let mut out = self.map_maps(f);
        out.restore_invariants();
        out
    }

    /// Every map through `f`, as it comes out (no invariants restored; the origin kept).
    /// Built map by map, not over a clone: cropping 512² out of an 8K² material would first
    /// copy all of it.
    pub fn map_maps(&self, f: impl Fn(&Map) -> Map) -> Material {
        Material {
            base_color: f(&self.base_color),
            normal: f(&self.normal),
            roughness: f(&self.roughness),
            metallic: f(&self.metallic),
            height: self.height.as_ref().map(&f),
            anisotropy: self.anisotropy.as_ref().map(&f),
            anisotropy_angle: self.anisotropy_angle.as_ref().map(&f),
            carried: self.carried.map_maps(&f),
            origin: self.origin.clone(),
            lossy: self.lossy.clone(),
        }
    }

    /// Every map the material has, carried ones included, in a fixed order (that of
    /// [`Material::maps_mut`]).
    pub fn maps(&self) -> impl Iterator<Item = &Map> {
        (MapKind::ALL.into_iter().filter_map(|k| self.map(k))).chain(self.carried.maps())
    }

    /// Every map, in the order of [`Material::maps`].
    pub fn maps_mut(&mut self) -> impl Iterator<Item = &mut Map> {
        [
            Some(&mut self.base_color),
            Some(&mut self.normal),
            Some(&mut self.roughness),
            Some(&mut self.metallic),
            self.height.as_mut(),
            self.anisotropy.as_mut(),
            self.anisotropy_angle.as_mut(),
        ]
        .into_iter()
        .flatten()
        .chain(self.carried.maps_mut())
    }

    /// The maps the input did not have, which stand in with [`MapKind::stand_in`] values (a
    /// material without an origin has every map).
    pub fn stand_ins(&self) -> Vec<MapKind> {
        let Some(origin) = &self.origin else {
            return Vec::new();
        };
        (MapKind::ALL.into_iter())
            .filter(|&k| k.stand_in().is_some() && origin.source(k).is_none())
            .collect()
    }

    /// Upsamples every map by `scale` with `kernel` (normals renormalised, values clamped
    /// to their ranges: interpolation overshoots).
    pub fn upsample(&self, scale: usize, kernel: Kernel, border: Border) -> Material {
        self.map_every(|m| upsample(m, scale, kernel, border))
    }

    /// Averages `factor × factor` blocks of every map: linear base colour, averaged then
    /// renormalised normals, averaged roughness, metallic and height. The result is no longer
    /// what a lossy file stored: its [`Material::lossy`] is empty.
    pub fn box_downsample(&self, factor: usize) -> Material {
        Material {
            lossy: BTreeMap::new(),
            ..self.map_every(|m| box_downsample(m, factor))
        }
    }

    /// Every map shrunk to `width × height` by area averaging (linear base colour; normals
    /// renormalised after), as [`Material::box_downsample`] for any ratio.
    pub fn area_resize(&self, width: usize, height: usize) -> Material {
        self.map_every(|m| area_resize(m, width, height))
    }

    /// The material under a symmetry of the square, as if the surface itself were mirrored
    /// or turned: every map moves, normals and anisotropy directions turn with it (mirroring
    /// the columns negates normal x, mirroring the rows negates y, a transpose swaps them).
    pub fn transformed(&self, t: Dihedral) -> Material {
        let mut out = self.map_every(|m| m.transformed(t));
        turn_with_surface(MapKind::Normal, &mut out.normal, t);
        if let Some(angle) = out.anisotropy_angle.as_mut() {
            turn_with_surface(MapKind::AnisotropyAngle, angle, t);
        }
        out
    }

    /// The rectangle of every map starting at (`x0`, `y0`).
    pub fn crop(&self, x0: usize, y0: usize, width: usize, height: usize) -> Material {
        self.map_every(|m| m.crop(x0, y0, width, height))
    }

    /// Clamps values to their valid ranges and renormalises normals.
    pub fn restore_invariants(&mut self) {
        for kind in [
            MapKind::BaseColor,
            MapKind::Metallic,
            MapKind::Roughness,
            MapKind::Normal,
        ] {
            restore_map_invariants(kind, self.map_mut(kind).expect("always present"));
        }
    }
}

/// A map of `kind` under a symmetry of the square, as [`Material::transformed`] moves it: the
/// texels move, and normals and anisotropy directions turn with the surface.
pub fn transformed_map(kind: MapKind, map: &Map, t: Dihedral) -> Map {
    let mut out = map.transformed(t);
    turn_with_surface(kind, &mut out, t);
    out
}

/// Turns the directions a map of `kind` holds (normals, anisotropy angles) as the surface
/// turns under `t`, texel by texel: it moves no texel, so it may come before or after
/// [`Map::transformed`].
pub fn turn_with_surface(kind: MapKind, map: &mut Map, t: Dihedral) {
    match kind {
        MapKind::Normal => {
            let n = map.texels();
            let data = map.data_mut();
            for i in 0..n {
                [data[i], data[n + i]] = t.vector([data[i], data[n + i]]);
            }
        }
        MapKind::AnisotropyAngle => {
            for v in map.data_mut() {
                let [x, y] = t.vector([v.cos(), v.sin()]);
                *v = y.atan2(x);
            }
        }
        _ => {}
    }
}

/// What [`Material::restore_invariants`] does to a map of `kind`: base colour, metallic and
/// roughness clamped to [0, 1], normals renormalised; other maps are left as they are.
/// Roughness keeps the file's values down to 0 (a mirror's): the shading models clamp alpha
/// where they render ([`alpha_from_roughness`]), so nothing is lost in the maps.
pub fn restore_map_invariants(kind: MapKind, map: &mut Map) {
    let range = match kind {
        MapKind::BaseColor | MapKind::Metallic | MapKind::Roughness => 0.0..=1.0,
        MapKind::Normal => return normalize_normals(map),
        _ => return,
    };
    for v in map.data_mut() {
        *v = v.clamp(*range.start(), *range.end());
    }
}

/// The position of texel `index` of a `width × height` map on the square [−1, 1]² (METHOD.md:
/// x from the column, y from the row), displaced by `height` if given.
#[inline]
pub fn texel_position(
    index: usize,
    width: usize,
    height: usize,
    heights: Option<&Map>,
) -> [f32; 3] {
    let (i, j) = (index / width, index % width);
    let z = heights.map_or(0.0, |m| DISPLACEMENT * (m.data()[index] - 0.5));
    [
        2.0 * (j as f32 + 0.5) / width as f32 - 1.0,
        2.0 * (i as f32 + 0.5) / height as f32 - 1.0,
        z,
    ]
}

/// `alpha = r²`, clamped to `[MIN_ALPHA, 1]`.
#[inline]
pub fn alpha_from_roughness(r: f32) -> f32 {
    (r * r).clamp(MIN_ALPHA, 1.0)
}

/// Renormalises a 3-channel normal map in place; a zero vector becomes (0, 0, 1).
pub fn normalize_normals(normal: &mut Map) {
    let n = normal.texels();
    let data = normal.data_mut();
    for i in 0..n {
        let v = glam::Vec3::new(data[i], data[n + i], data[2 * n + i]);
        let u = if v.length_squared() > 1e-12 {
            v.normalize()
        } else {
            glam::Vec3::Z
        };
        data[i] = u.x;
        data[n + i] = u.y;
        data[2 * n + i] = u.z;
    }
}

/// How far past unit length (5%, beyond any 8-bit file's or JPEG's error) a file's normals
/// around a texel begin to have it read from its x and y alone, and how far (15%) they have
/// it read so wholly ([`normals_from_file`]).
const NORMAL_LENGTH_TRUSTED: f32 = 1.05;
const NORMAL_LENGTH_REBUILT: f32 = 1.15;

/// Normals as a file stores them (decoded, not yet unit) made unit vectors. A well-formed
/// file's vectors are unit within its precision, and a filtered one's shorter (averaging
/// shortens them, its z agreeing with its x and y): both are renormalised. A vector longer
/// than unit comes from neither: its z disagrees with its x and y, as in a baked,
/// JPEG-compressed game texture whose blue channel jumps while red and green run smooth
/// (DamagedHelmet: lengths 0.53–1.27 along its stripes). Renormalising there turns a smooth
/// slope into directions that jump from texel to texel, which an SR network draws as patches
/// of noise (docs/experiments/2026-11-28-no-new-structure.md). So where any vector of a
/// texel's 3×3 neighbourhood is longer than unit by 5% or more, the texel's x and y are
/// taken at their word and z rebuilt from them, as engines that read two channels (BC5,
/// Unreal, Unity) do, blended in up to 15% so the reading changes smoothly.
pub fn normals_from_file(normal: &mut Map) {
    let n = normal.texels();
    let vector = |data: &[f32], i: usize| glam::Vec3::new(data[i], data[n + i], data[2 * n + i]);
    let lengths: Vec<[f32; 1]> = (0..n)
        .map(|i| [vector(normal.data(), i).length()])
        .collect();
    // The longest vector of each texel's 3×3 neighbourhood (those inside the map).
    let ranges = neighbourhood_ranges(&lengths, normal.width(), Border::Clamp);
    let data = normal.data_mut();
    for (i, [[_, longest]]) in ranges.into_iter().enumerate() {
        let rebuilt = ((longest - NORMAL_LENGTH_TRUSTED)
            / (NORMAL_LENGTH_REBUILT - NORMAL_LENGTH_TRUSTED))
            .clamp(0.0, 1.0);
        if rebuilt == 0.0 {
            continue;
        }
        let v = vector(data, i);
        let xy = glam::Vec2::new(v.x, v.y);
        let xy = if xy.length_squared() > 1.0 {
            xy.normalize()
        } else {
            xy
        };
        let z = (1.0 - xy.length_squared()).max(0.0).sqrt();
        let from_xy = glam::Vec3::new(xy.x, xy.y, if v.z < 0.0 { -z } else { z });
        let u = v.normalize_or(glam::Vec3::Z).lerp(from_xy, rebuilt);
        data[i] = u.x;
        data[n + i] = u.y;
        data[2 * n + i] = u.z;
    }
    normalize_normals(normal);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_normal_whose_z_disagrees_with_its_x_and_y_is_read_from_them() {
        // Two rows: a filtered map's short vectors (z agreeing with x and y) and unit ones,
        // renormalised; then DamagedHelmet's stripe, lengths 1.18 and 0.70 side by side, read
        // from x and y.
        let texels: [[[f32; 3]; 3]; 2] = [
            [[0.6, 0.0, 0.8], [0.3, 0.4, 0.9], [0.27, 0.0, 0.9]],
            [[0.0, 0.0, 1.0], [0.45, 0.44, 1.0], [-0.41, -0.46, 0.33]],
        ];
        let mut map = Map::from_fn(3, 2, 3, |c, y, x| texels[y][x][c]);
        // The first row alone: nothing longer than unit near it.
        let mut first = Map::from_fn(3, 1, 3, |c, _, x| texels[0][x][c]);
        let mut plain = first.clone();
        normals_from_file(&mut first);
        normalize_normals(&mut plain);
        assert_eq!(first.data(), plain.data(), "renormalised, bit for bit");
        normals_from_file(&mut map);
        let got = |y: usize, x: usize| {
            glam::Vec3::new(map.get(0, y, x), map.get(1, y, x), map.get(2, y, x))
        };
        for (y, x) in [(0, 0), (0, 1), (0, 2), (1, 0), (1, 1), (1, 2)] {
            assert!((got(y, x).length() - 1.0).abs() < 1e-5, "texel {y}, {x}");
        }
        for (x, [nx, ny]) in [(1, [0.45, 0.44]), (2, [-0.41, -0.46])] {
            let n = got(1, x);
            assert!((n.x - nx).abs() < 1e-5 && (n.y - ny).abs() < 1e-5, "{n:?}");
        }
        // A flat normal stays flat either way.
        assert!((got(1, 0) - glam::Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn positions_follow_method_convention() {
        let m = Material::uniform(4, [0.5; 3], 0.5, 0.0);
        assert_eq!(m.position(0), [-0.75, -0.75, 0.0]);
        assert_eq!(m.position(4 * 4 - 1), [0.75, 0.75, 0.0]);
        assert_eq!(m.position(1)[0], -0.25, "column index moves x");
        assert_eq!(m.position(4)[1], -0.25, "row index moves y");
    }

    #[test]
    fn height_displaces_z() {
        let mut m = Material::uniform(2, [0.5; 3], 0.5, 0.0);
        m.height = Some(Map::from_planar(2, 2, 1, vec![0.0, 0.5, 1.0, 0.75]));
        assert!((m.position(0)[2] + 0.005).abs() < 1e-7);
        assert_eq!(m.position(1)[2], 0.0);
        assert!((m.position(2)[2] - 0.005).abs() < 1e-7);
    }

    #[test]
    fn alpha_is_squared_roughness_clamped() {
        assert_eq!(alpha_from_roughness(0.5), 0.25);
        assert_eq!(alpha_from_roughness(0.0), MIN_ALPHA);
        assert_eq!(alpha_from_roughness(2.0), 1.0);
    }
}
