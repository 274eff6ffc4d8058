//! The per-map path, the first stage of matup's defaults: every map upsampled on its own by an
//! RGB upsampler as a picture (the way an artist runs each texture file through Lanczos or an
//! SR network), under the self-ensemble's symmetries, with flat maps skipping the upsampler.
//! One pass of it, not back-projected, is the per-map baseline that evaluations compare with
//! ([`upscale_per_map`]).

use matup_core::candle_core::{DType, Device, Tensor};
use matup_core::color::{linear_to_srgb, srgb_to_linear, srgb_to_linear_tensor};
use matup_core::device_maps;
use matup_core::io::{decode_normals, encode_normals};
use matup_core::map::Dihedral;
use matup_core::map::Map;
use matup_core::material::{
    restore_map_invariants, transformed_map, turn_with_surface, MapKind, Material, NormalConvention,
};
use matup_core::resample::{Border, Kernel};
use matup_core::upsample::{KernelUpsampler, RgbUpsampler};
use matup_core::{Error, Result};
use serde::{Deserialize, Serialize};

/// Upsamples each map of `material` by `scale` with `upsampler`, as the map's file would be:
/// base colour sRGB-encoded, normals as `(n + 1) / 2` colours (io's own encoding), grey maps
/// as grey RGB images (the three results averaged back). Normals are renormalised and values
/// clamped after. The maps a material carries unrendered (alpha, occlusion, …) are no part of
/// this baseline: they are left out.
pub fn upscale_per_map(
    material: &Material,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> Result<Material> {
    let mut out = material.clone();
    out.carried = Default::default();
    upscale_each_map(
        material,
        &MapUpsamplers::one(upsampler),
        scale,
        border,
        MapPasses::ONE,
        |kind, map| {
            *out.map_mut(kind).expect("present in the clone") = map;
            Ok(())
        },
    )?;
    Ok(out)
}

/// [`upscale_per_map`] a map at a time, each map by its upsampler, as `passes` says: each map
/// of `material` is upsampled, decoded and handed to `each` before the next is upsampled, so a
/// caller that packs them elsewhere never holds all of them at the output size (at 8K² each
/// map is 0.25–0.75 GB).
pub fn upscale_each_map(
    material: &Material,
    upsamplers: &MapUpsamplers,
    scale: usize,
    border: Border,
    passes: MapPasses,
    mut each: impl FnMut(MapKind, Map) -> Result<()>,
) -> Result<()> {
    for kind in MapKind::ALL {
        let Some(map) = material.map(kind) else {
            continue;
        };
        let upsampler = upsamplers.of(kind);
        each(
            kind,
            upscale_one_map(kind, map, upsampler, scale, border, passes)?,
        )?;
    }
    Ok(())
}

/// The upsampler of each map of a material: the run's, but for the maps routed apart, their
/// own (`crate::plan::InputRoute`: a model's JPEG colour runs the network for JPEG maps, its
/// PNG normal map the material network).
#[derive(Clone)]
pub struct MapUpsamplers<'a> {
    /// Every map's but those routed apart.
    pub run: &'a dyn RgbUpsampler,
    /// The maps routed apart, each with its upsampler.
    pub apart: Vec<(MapKind, &'a dyn RgbUpsampler)>,
    /// The clean route's upsampler, whose normals are blended in where the input's stand past
    /// its noise (`FilterConfig::normal_blend_noise`).
    pub clean_normals: Option<&'a dyn RgbUpsampler>,
}

impl<'a> MapUpsamplers<'a> {
    /// `upsampler` for every map.
    pub fn one(upsampler: &'a dyn RgbUpsampler) -> Self {
        MapUpsamplers {
            run: upsampler,
            apart: Vec::new(),
            clean_normals: None,
        }
    }

    /// The upsampler of a map of `kind`.
    pub fn of(&self, kind: MapKind) -> &'a dyn RgbUpsampler {
        (self.apart.iter())
            .find(|(k, _)| *k == kind)
            .map_or(self.run, |(_, u)| *u)
    }

    /// Every upsampler, the run's first.
    pub fn all(&self) -> impl Iterator<Item = &'a dyn RgbUpsampler> + '_ {
        (std::iter::once(self.run).chain(self.apart.iter().map(|(_, u)| *u)))
            .chain(self.clean_normals)
    }
}

/// One map of `kind` upsampled as [`upscale_each_map`] upsamples it.
pub fn upscale_one_map(
    kind: MapKind,
    map: &Map,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
    passes: MapPasses,
) -> Result<Map> {
    if !passes.upsampled.includes(kind) {
        let left_out = KernelUpsampler::new(LEFT_OUT);
        return upscale_one_map(kind, map, &left_out, scale, border, MapPasses::ONE);
    }
    if let Some(flat) = flat_upsampled(map, scale) {
        Ok(flat)
    } else if let Some(symmetries) = passes.ensemble.symmetries_for(kind)? {
        upscale_map_ensemble(kind, map, upsampler, scale, border, symmetries)
    } else {
        upscale_map(kind, map, upsampler, scale, border)
    }
}

/// A map of `kind` upsampled once, as [`upscale_per_map`] upsamples it.
fn upscale_map(
    kind: MapKind,
    map: &Map,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> Result<Map> {
    let up = upscale_maps(kind, std::slice::from_ref(map), upsampler, scale, border)?;
    Ok(up.into_iter().next().expect("one map in, one out"))
}

/// Maps of `kind` upsampled in one call of the upsampler, and decoded.
fn upscale_maps(
    kind: MapKind,
    maps: &[Map],
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
) -> Result<Vec<Map>> {
    let images: Vec<Map> = maps.iter().map(|m| encode_for_upsampler(kind, m)).collect();
    let ups = upsampler.upsample(&images, scale, border)?;
    check_count(kind, ups.len(), maps.len())?;
    ups.into_iter()
        .zip(maps)
        .map(|(up, map)| decoded(kind, map, up, scale))
        .collect()
}

/// An error unless the upsampler returned as many images (`returned`) as it was given maps of
/// `kind` (`given`).
fn check_count(kind: MapKind, returned: usize, given: usize) -> Result<()> {
    if returned != given {
        return Err(Error::Invalid(format!(
            "the upsampler returned {returned} images for {given} {kind:?} maps"
        )));
    }
    Ok(())
}

/// An error unless `[width, height, channels]`, the upsampler's image of `map` at ×`scale`,
/// is the size it should be.
fn check_upsampled(kind: MapKind, map: &Map, [w, h, c]: [usize; 3], scale: usize) -> Result<()> {
    let want = (map.width() * scale, map.height() * scale);
    if (w, h) != want || c < 3 {
        return Err(Error::Invalid(format!(
            "the upsampler returned a {w}×{h}×{c} image for the {}×{} {kind:?} map at ×{scale} \
             (expected {}×{}×3)",
            map.width(),
            map.height(),
            want.0,
            want.1
        )));
    }
    Ok(())
}

/// `up`, the upsampler's image of `map` at ×`scale`, checked and decoded into a map of `kind`.
fn decoded(kind: MapKind, map: &Map, up: Map, scale: usize) -> Result<Map> {
    check_upsampled(kind, map, [up.width(), up.height(), up.channels()], scale)?;
    let mut decoded = match kind {
        MapKind::BaseColor => up.map_values(|v| srgb_to_linear(v.clamp(0.0, 1.0))),
        MapKind::Normal => {
            let mut normals = up;
            decode_normals(&mut normals, NormalConvention::DirectX);
            normals
        }
        _ => {
            let (w, h) = (up.width(), up.height());
            Map::from_fn(w, h, 1, |_, y, x| {
                (up.get(0, y, x) + up.get(1, y, x) + up.get(2, y, x)) / 3.0
            })
        }
    };
    restore_map_invariants(kind, &mut decoded);
    Ok(decoded)
}

/// A map whose every texel is the same, upsampled: the same value at the output size. Any
/// upsampler should return a flat map as it is, and a network returns it with a small bias of
/// its own, so none is run on one; most materials' metallic maps are flat, and skipping them
/// saves a quarter of the upsampler's time.
fn flat_upsampled(map: &Map, scale: usize) -> Option<Map> {
    is_flat(map).then(|| {
        Map::from_fn(
            map.width() * scale,
            map.height() * scale,
            map.channels(),
            |c, _, _| map.plane(c)[0],
        )
    })
}

/// Whether every texel of `map` is the same ([`flat_upsampled`]).
fn is_flat(map: &Map) -> bool {
    map.texels() > 0 && (0..map.channels()).all(|c| map.is_constant(c, 0.0))
}

/// [`upscale_one_map`] where `upsampler` leaves its outputs on a device
/// ([`RgbUpsampler::upsample_on_device`]): every pass of the self-ensemble in one call, each
/// decoded, turned back and summed there, the mean's invariants restored there. The map comes
/// back as a `[channels, h·scale, w·scale]` tensor on that device.
pub fn upscale_one_map_on_device(
    kind: MapKind,
    map: &Map,
    upsampler: &dyn RgbUpsampler,
    device: &Device,
    scale: usize,
    border: Border,
    passes: MapPasses,
) -> Result<Tensor> {
    if !passes.upsampled.includes(kind) {
        let left_out = KernelUpsampler::on(LEFT_OUT, device.clone());
        return upscale_one_map_on_device(
            kind,
            map,
            &left_out,
            device,
            scale,
            border,
            MapPasses::ONE,
        );
    }
    let (w, h) = (map.width() * scale, map.height() * scale);
    if is_flat(map) {
        let planes = (0..map.channels())
            .map(|c| Tensor::full(map.plane(c)[0], (1, h, w), device))
            .collect::<candle_core::Result<Vec<_>>>()?;
        return Ok(Tensor::cat(&planes, 0)?);
    }
    let covered = passes.ensemble.symmetries_for(kind)?;
    // Not covered: one pass, the identity.
    let symmetries = covered.unwrap_or(&Dihedral::ALL[..1]);
    let images: Vec<Map> = (symmetries.iter())
        .map(|&t| encode_for_upsampler(kind, &transformed_map(kind, map, t)))
        .collect();
    let ups = upsampler.upsample_on_device(&images, scale, border)?;
    check_count(kind, ups.len(), images.len())?;
    let mut sum: Option<Tensor> = None;
    for (&t, up) in symmetries.iter().zip(&ups) {
        let (c, uh, uw) = up.dims3()?;
        check_upsampled(kind, map, [uw, uh, c], scale)?;
        let decoded = decoded_on_device(kind, &up.narrow(0, 0, 3)?)?;
        // Turned back: the directions first, then the texels, into the sum.
        let back = t.inverse();
        let turned =
            device_maps::turned(&turn_with_surface_on_device(kind, &decoded, back)?, back)?;
        sum = Some(match sum {
            None => turned,
            Some(sum) => (sum + turned)?,
        });
    }
    let sum = sum.expect("at least the identity");
    if covered.is_none() {
        return Ok(sum);
    }
    Ok(restore_invariants_on_device(
        kind,
        &(sum / symmetries.len() as f64)?,
    )?)
}

/// [`decoded`] of `up`, `[3, h, w]` on a device (its size checked by the caller).
fn decoded_on_device(kind: MapKind, up: &Tensor) -> candle_core::Result<Tensor> {
    let decoded = match kind {
        MapKind::BaseColor => srgb_to_linear_tensor(&up.clamp(0f32, 1f32)?)?,
        // DirectX colours, matup's own frame: 2v − 1, renormalised (as `decode_normals`).
        MapKind::Normal => unit_normals(&up.affine(2.0, -1.0)?)?,
        // The grey image's three channels averaged, added in order as on the host.
        _ => {
            let channel = |c| up.narrow(0, c, 1);
            (((channel(0)? + channel(1)?)? + channel(2)?)? / 3.0)?
        }
    };
    restore_invariants_on_device(kind, &decoded)
}

/// [`restore_map_invariants`] on a device.
fn restore_invariants_on_device(kind: MapKind, map: &Tensor) -> candle_core::Result<Tensor> {
    match kind {
        MapKind::BaseColor | MapKind::Metallic | MapKind::Roughness => map.clamp(0f32, 1f32),
        MapKind::Normal => unit_normals(map),
        _ => Ok(map.clone()),
    }
}

/// Normals `[3, h, w]` scaled to unit length; +z where one is nearly zero (as
/// `normalize_normals`).
fn unit_normals(n: &Tensor) -> candle_core::Result<Tensor> {
    let squared = n.sqr()?.sum_keepdim(0)?;
    let unit = n.broadcast_mul(&squared.sqrt()?.recip()?)?;
    let (_, h, w) = n.dims3()?;
    let up = Tensor::cat(
        &[
            Tensor::zeros((2, h, w), DType::F32, n.device())?,
            Tensor::ones((1, h, w), DType::F32, n.device())?,
        ],
        0,
    )?;
    squared
        .gt(1e-12)?
        .broadcast_as(n.shape())?
        .where_cond(&unit, &up)
}

/// [`turn_with_surface`] of normals `[3, h, w]` on a device (other kinds hold no directions
/// the ensemble turns).
fn turn_with_surface_on_device(kind: MapKind, map: &Tensor, t: Dihedral) -> Result<Tensor> {
    if kind != MapKind::Normal || t == Dihedral::default() {
        return Ok(map.clone());
    }
    let signed = |c: usize, flip: bool| -> candle_core::Result<Tensor> {
        let v = map.narrow(0, c, 1)?;
        if flip {
            v.neg()
        } else {
            Ok(v)
        }
    };
    let (x, y) = (signed(0, t.flip_x)?, signed(1, t.flip_y)?);
    let (x, y) = if t.transpose { (y, x) } else { (x, y) };
    Ok(Tensor::cat(&[x, y, map.narrow(0, 2, 1)?], 0)?)
}

/// A map of `kind` upsampled under each of `symmetries`, turned back and averaged (geometric
/// self-ensemble, as SR papers report it): the map is mirrored and transposed as the surface
/// would be (normals turn with it, [`transformed_map`]), so the normal maps the network sees
/// are real normal maps. Normals are renormalised after the mean.
fn upscale_map_ensemble(
    kind: MapKind,
    map: &Map,
    upsampler: &dyn RgbUpsampler,
    scale: usize,
    border: Border,
    symmetries: &[Dihedral],
) -> Result<Map> {
    let (w, h) = (map.width() * scale, map.height() * scale);
    let mut sum: Option<Map> = None;
    // All passes in one call where the upsampler batches images (a GPU: their outputs held at
    // once), else one pass a call (one output beside the sum).
    let per_call = if upsampler.batches_images() {
        symmetries.len()
    } else {
        1
    };
    for turns in symmetries.chunks(per_call.max(1)) {
        let passes: Vec<Map> = (turns.iter())
            .map(|&t| transformed_map(kind, map, t))
            .collect();
        for (&t, mut up) in turns
            .iter()
            .zip(upscale_maps(kind, &passes, upsampler, scale, border)?)
        {
            // Turned back: the directions first (texel by texel), then the texels, into the sum.
            let back = t.inverse();
            turn_with_surface(kind, &mut up, back);
            match sum.as_mut() {
                // The identity's pass is the sum so far as it stands: no map of zeros to add
                // it to.
                None if back == Dihedral::default() => sum = Some(up),
                None => {
                    let mut first = Map::filled(w, h, up.channels(), 0.0);
                    first.add_transformed(&up, back);
                    sum = Some(first);
                }
                Some(sum) => sum.add_transformed(&up, back),
            }
        }
    }
    let sum = sum.ok_or_else(|| Error::Invalid("a self-ensemble of no symmetries".into()))?;
    let n = symmetries.len() as f32;
    let mut mean = sum.map_values(|v| v / n);
    restore_map_invariants(kind, &mut mean);
    Ok(mean)
}

/// How the per-map path runs the upsampler over a material's maps: on which of them (the others
/// go through Lanczos-3), and under which symmetries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MapPasses {
    pub ensemble: SelfEnsemble,
    pub upsampled: UpsampledMaps,
}

impl MapPasses {
    /// One pass of every map.
    pub const ONE: MapPasses = MapPasses {
        ensemble: SelfEnsemble::NONE,
        upsampled: UpsampledMaps::All,
    };

    /// What upsamples a map of `kind`, in words: the run's upsampler (called `name`) and its
    /// passes, or the kernel of the maps left out.
    pub fn by(self, kind: MapKind, name: &str) -> String {
        if !self.upsampled.includes(kind) {
            return LEFT_OUT.to_string();
        }
        match self.ensemble.symmetries {
            1 => name.to_string(),
            n => format!("{name} ({n} passes)"),
        }
    }
}

/// What upsamples the maps [`UpsampledMaps`] leaves out of the upsampler: one pass, as a
/// kernel is the same under every symmetry.
pub const LEFT_OUT: Kernel = Kernel::Lanczos3;

/// The geometric self-ensemble of the per-map upsampling: the maps it covers are upsampled
/// under `symmetries` symmetries of the square and averaged, the others once. Each symmetry
/// past the first is one more pass of the upsampler over the maps covered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SelfEnsemble {
    /// 1 (no ensemble), 2, 4 or 8: the first of [`ENSEMBLE_ORDER`].
    pub symmetries: usize,
    pub maps: EnsembleMaps,
}

/// The maps a [`SelfEnsemble`] covers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum EnsembleMaps {
    /// Every map the upsampler runs on.
    #[default]
    All,
    /// The normal map alone (the map whose upsampling the renders depend on most).
    Normal,
}

serde_plain::derive_display_from_serialize!(EnsembleMaps);
serde_plain::derive_fromstr_from_deserialize!(EnsembleMaps, |e| -> Error {
    Error::Invalid(format!("the maps of the self-ensemble: {e}"))
});

/// The maps of a material the per-map path runs through the run's upsampler; the others go
/// through Lanczos-3.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum UpsampledMaps {
    /// Every map, but the normal map alone at a ×2 level after the first (×8's second) where
    /// the upsampler is a network: that level's input is the network's own output, and its
    /// other maps gain nothing there (within 0.03 dB, at 2.6× the time), while at a run's
    /// first ×2 level every map gains (docs/experiments/2026-11-27-x2-at-the-cost-of-x4.md).
    #[default]
    Auto,
    /// Every map.
    All,
    /// The normal map alone (the map that carries most of a network's gain), in about a
    /// quarter of the network's time.
    Normal,
}

serde_plain::derive_display_from_serialize!(UpsampledMaps);
serde_plain::derive_fromstr_from_deserialize!(UpsampledMaps, |e| -> Error {
    Error::Invalid(format!("the maps the upsampler runs on: {e}"))
});

impl UpsampledMaps {
    /// What this setting asks of a run's ×`scale` level `level` (0 for the first) by an
    /// upsampler of `native_scale`: `All` or `Normal`.
    pub fn at_level(self, level: usize, scale: usize, native_scale: Option<usize>) -> Self {
        match self {
            UpsampledMaps::Auto if level > 0 && scale == 2 && native_scale.is_some() => {
                UpsampledMaps::Normal
            }
            UpsampledMaps::Auto => UpsampledMaps::All,
            chosen => chosen,
        }
    }

    /// Whether the run's upsampler upsamples a map of `kind` (`Auto` as at a first level).
    pub fn includes(self, kind: MapKind) -> bool {
        match self {
            UpsampledMaps::Auto | UpsampledMaps::All => true,
            UpsampledMaps::Normal => kind == MapKind::Normal,
        }
    }
}

/// The symmetries of a self-ensemble, in the order its size takes them: the identity, the half
/// turn (it reverses both axes, so a shift the network makes along either cancels), the two
/// mirrors, then the four with a transpose.
pub const ENSEMBLE_ORDER: [Dihedral; 8] = {
    let order = [0, 3, 1, 2, 4, 7, 5, 6];
    let mut out = [Dihedral::ALL[0]; 8];
    let mut i = 0;
    while i < 8 {
        out[i] = Dihedral::ALL[order[i]];
        i += 1;
    }
    out
};

impl SelfEnsemble {
    /// One pass of every map.
    pub const NONE: SelfEnsemble = SelfEnsemble {
        symmetries: 1,
        maps: EnsembleMaps::All,
    };

    /// Whether a map of `kind` is upsampled under more than the identity.
    pub fn covers(self, kind: MapKind) -> bool {
        self.symmetries > 1 && (self.maps == EnsembleMaps::All || kind == MapKind::Normal)
    }

    /// The symmetries a map of `kind` is averaged over: `None` where it is upsampled once; an
    /// error for anisotropy directions, which do not average as numbers.
    pub fn symmetries_for(self, kind: MapKind) -> Result<Option<&'static [Dihedral]>> {
        if !self.covers(kind) {
            return Ok(None);
        }
        let symmetries = self.symmetries()?;
        if kind == MapKind::AnisotropyAngle {
            return Err(Error::Invalid(
                "the self-ensemble does not handle anisotropy directions".into(),
            ));
        }
        Ok(Some(symmetries))
    }

    /// The symmetries averaged, or an error for a size that is not 1, 2, 4 or 8.
    pub fn symmetries(self) -> Result<&'static [Dihedral]> {
        match self.symmetries {
            1 | 2 | 4 | 8 => Ok(&ENSEMBLE_ORDER[..self.symmetries]),
            n => Err(Error::Invalid(format!(
                "a self-ensemble averages 1, 2, 4 or 8 symmetries of the square, not {n}"
            ))),
        }
    }
}

/// A map of `kind` as the RGB image an upsampler sees: base colour sRGB-encoded, normals as
/// DirectX `(n + 1) / 2` colours, grey maps as grey RGB.
pub fn encode_for_upsampler(kind: MapKind, map: &Map) -> Map {
    match kind {
        MapKind::BaseColor => map.clone().map_values(linear_to_srgb),
        MapKind::Normal => encode_normals(map, NormalConvention::DirectX),
        _ => Map::stack(&[map, map, map]),
    }
}

#[cfg(test)]
mod tests;
