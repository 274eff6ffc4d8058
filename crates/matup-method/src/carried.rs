//! The maps a material carries beside those it is rendered with (alpha channels, occlusion,
//! opacity, emission, unknown maps): each upsampled on its own by the run's RGB upsampler, as
//! the per-map path upsamples base colour (RGB) or roughness (grey), then back-projected onto
//! its input. Alpha is kept free of halos, and a cutout's alpha stays binary.

use matup_core::candle_core::{Device, Tensor};
use matup_core::device_maps;
use matup_core::map::Map;
use matup_core::material::{Carried, MapKind, Material};
use matup_core::resample::{lr_texel, neighbourhood_ranges, upsample, Border, Kernel};
use matup_core::upsample::RgbUpsampler;
use matup_core::Result;

use crate::per_map::{upscale_one_map, upscale_one_map_on_device, MapPasses};
use crate::residual::{back_project_on_device, back_project_within};

/// How the carried maps are upsampled: the run's upsampler and its passes (Lanczos-3 where
/// they leave a map out), and whether the result is back-projected onto the input (the
/// defaults do; the per-map baseline does not).
#[derive(Clone, Copy)]
pub struct CarriedUpsampling<'a> {
    pub upsampler: &'a dyn RgbUpsampler,
    pub passes: MapPasses,
    pub back_project: bool,
    pub scale: usize,
    pub border: Border,
}

/// How one carried map is upsampled.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Method {
    /// A cutout's alpha (only 0 and 1): bicubic, thresholded at one half.
    Cutout,
    /// Any other alpha: the upsampler, back-projected, kept within its neighbourhood.
    SoftAlpha,
    /// An extra map through the upsampler as the per-map path takes a map of this kind (RGB as
    /// base colour, grey as height: values as they come), back-projected within [0, 1].
    Picture(MapKind),
    /// An extra map with values outside [0, 1] (HDR emission): Lanczos, no network.
    Lanczos,
    /// A map of one value (a mask channel at 255, an opaque alpha): that value, exactly.
    Constant,
}

/// How each of a material's carried maps is upsampled, in the order of [`Carried::maps`],
/// decided once from the whole maps: the bands of an output must all treat a map alike.
#[derive(Clone, Debug, PartialEq)]
pub struct CarriedPlan(Vec<Method>);

impl CarriedPlan {
    pub fn of(carried: &Carried) -> CarriedPlan {
        let constant = |m: &Map| m.data().iter().all(|&v| v == m.data()[0]);
        let alpha = |a: &Map| {
            if constant(a) {
                Method::Constant
            } else if a.data().iter().all(|&v| v == 0.0 || v == 1.0) {
                Method::Cutout
            } else {
                Method::SoftAlpha
            }
        };
        let extra = |m: &Map| match m.data().iter().all(|v| (0.0..=1.0).contains(v)) {
            _ if constant(m) => Method::Constant,
            false => Method::Lanczos,
            true if m.channels() == 3 => Method::Picture(MapKind::BaseColor),
            true => Method::Picture(MapKind::Height),
        };
        let mut methods: Vec<Method> = carried.alpha.values().map(alpha).collect();
        for e in &carried.extras {
            methods.push(extra(&e.map));
            methods.extend(e.alpha.as_ref().map(alpha));
        }
        CarriedPlan(methods)
    }
}

/// Every map `lr` carries (a material's, or a band of it), upsampled as `plan` (made from the
/// whole material) says.
pub fn upscale_carried(
    lr: &Carried,
    plan: &CarriedPlan,
    how: CarriedUpsampling,
) -> Result<Carried> {
    let mut out = lr.clone();
    let device = how.upsampler.device();
    for (map, &method) in out.maps_mut().zip(&plan.0) {
        *map = match (&device, method) {
            (Some(device), Method::SoftAlpha | Method::Picture(_)) => {
                upscale_on_device(map, method, how, device)?
            }
            _ => upscale(map, method, how)?,
        };
    }
    Ok(out)
}

/// What [`upscale_carried`] does to each of `material`'s carried maps, for the run's report:
/// `"x_AmbientOcclusion.jpg as x_AmbientOcclusion: by onnx:span_x4_materials (2 passes),
/// back-projected"`.
pub fn describe_carried(
    material: &Material,
    plan: &CarriedPlan,
    upsampler: &str,
    how: CarriedUpsampling,
) -> Vec<String> {
    // What upsamples a map the upsampler would see as `kind`, its passes named.
    let by = |kind| how.passes.by(kind, upsampler);
    let projected = if how.back_project {
        ", back-projected"
    } else {
        ""
    };
    let describe = |method| match method {
        Method::Cutout => "alpha of a cutout: bicubic, thresholded at 0.5 (stays 0 or 1)".into(),
        Method::SoftAlpha => format!(
            "alpha: by {}{projected}, kept within its 3×3 neighbourhood (no halo)",
            by(MapKind::Height)
        ),
        Method::Picture(MapKind::BaseColor) => {
            format!("RGB, by {}{projected}", by(MapKind::BaseColor))
        }
        Method::Picture(kind) => format!("grey, by {}{projected}", by(kind)),
        Method::Lanczos => format!("by lanczos3 (values outside [0, 1]){projected}"),
        Method::Constant => "one value throughout: kept exactly".into(),
    };
    let file = |p: &std::path::Path| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned()
    };
    let mut methods = plan.0.iter().copied();
    let mut out = Vec::new();
    for kind in material.carried.alpha.keys() {
        let source = (material.origin.as_ref())
            .and_then(|o| o.source(*kind))
            .map_or_else(|| kind.to_string(), |f| file(&f.path));
        out.push(format!("{source}: {}", describe(methods.next().unwrap())));
    }
    for e in &material.carried.extras {
        let mut line = format!(
            "{} as {}: {}",
            file(&e.source),
            e.name,
            describe(methods.next().unwrap())
        );
        if e.alpha.is_some() {
            line += &format!("; {}", describe(methods.next().unwrap()));
        }
        out.push(line);
    }
    out
}

/// One carried map upsampled by `method`.
fn upscale(map: &Map, method: Method, how: CarriedUpsampling) -> Result<Map> {
    let through_upsampler =
        |kind| upscale_one_map(kind, map, how.upsampler, how.scale, how.border, how.passes);
    Ok(match method {
        Method::Constant => Map::filled(
            map.width() * how.scale,
            map.height() * how.scale,
            map.channels(),
            map.data().first().copied().unwrap_or(0.0),
        ),
        Method::Cutout => {
            // A smooth interpolant's half-level line is a smooth contour through the input's
            // edges; a network's output speckles there (it hallucinates texture at a hard
            // step).
            let mut up = upsample(map, how.scale, Kernel::Bicubic { a: -0.5 }, how.border);
            up.data_mut()
                .iter_mut()
                .for_each(|v| *v = if *v >= 0.5 { 1.0 } else { 0.0 });
            up
        }
        Method::SoftAlpha => {
            let mut up = through_upsampler(MapKind::Height)?;
            if how.back_project {
                back_project_within(&mut up, map, how.scale, how.border, |_| (0.0, 1.0));
            }
            // No ring (halo) around an edge: each texel within its LR texel's neighbourhood.
            let values: Vec<[f32; 1]> = map.data().iter().map(|&v| [v]).collect();
            let ranges = neighbourhood_ranges(&values, map.width(), how.border);
            let w = up.width();
            for (i, v) in up.data_mut().iter_mut().enumerate() {
                let [[low, high]] = ranges[lr_texel(i, w, how.scale, map.width())];
                *v = v.clamp(low, high);
            }
            up
        }
        Method::Picture(kind) => {
            let mut up = through_upsampler(kind)?;
            up.data_mut()
                .iter_mut()
                .for_each(|v| *v = v.clamp(0.0, 1.0));
            if how.back_project {
                back_project_within(&mut up, map, how.scale, how.border, |_| (0.0, 1.0));
            }
            up
        }
        Method::Lanczos => {
            let mut up = upsample(map, how.scale, Kernel::Lanczos3, how.border);
            if how.back_project {
                back_project_within(&mut up, map, how.scale, how.border, |_| {
                    (f32::MIN, f32::MAX)
                });
            }
            up
        }
    })
}

/// [`upscale`] of a map through an upsampler that leaves its outputs on `device`: the
/// passes, the back-projection and the clamps run there, and only the finished map comes back.
fn upscale_on_device(
    map: &Map,
    method: Method,
    how: CarriedUpsampling,
    device: &Device,
) -> Result<Map> {
    let kind = match method {
        Method::Picture(kind) => kind,
        _ => MapKind::Height,
    };
    let up = upscale_one_map_on_device(
        kind,
        map,
        how.upsampler,
        device,
        how.scale,
        how.border,
        how.passes,
    )?;
    let up = match method {
        Method::Picture(_) => up.clamp(0f32, 1f32)?,
        _ => up,
    };
    let up = if how.back_project {
        let c = map.channels();
        let ends = [0f32, 1.0].map(|v| Tensor::full(v, (c, 1, 1), device));
        let [lo, hi] = ends;
        let lr = device_maps::upload(map, device)?;
        back_project_on_device(&up, &lr, how.scale, how.border, &[lo?, hi?])?
    } else {
        up
    };
    let up = match method {
        Method::SoftAlpha => {
            // As `upscale`: each texel within its LR texel's neighbourhood (no halo).
            let values: Vec<[f32; 1]> = map.data().iter().map(|&v| [v]).collect();
            let bounds = device_maps::neighbourhood_bounds(
                &values,
                map.width(),
                how.scale,
                how.border,
                device,
            )?;
            up.maximum(&bounds.narrow(0, 0, 1)?)?
                .minimum(&bounds.narrow(0, 1, 1)?)?
        }
        _ => up,
    };
    Ok(device_maps::download(&up)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lanczos: an upsampler that rings at a step, as networks can.
    struct Lanczos;
    impl RgbUpsampler for Lanczos {
        fn upsample(&self, images: &[Map], scale: usize, border: Border) -> Result<Vec<Map>> {
            Ok(images
                .iter()
                .map(|m| upsample(m, scale, Kernel::Lanczos3, border))
                .collect())
        }
    }

    fn how(upsampler: &dyn RgbUpsampler) -> CarriedUpsampling<'_> {
        CarriedUpsampling {
            upsampler,
            passes: MapPasses::ONE,
            back_project: true,
            scale: 4,
            border: Border::Mirror,
        }
    }

    #[test]
    fn soft_alpha_gets_no_halo_where_the_upsampler_rings() {
        // Opaque on the left, 30% on the right: a soft (non-binary) alpha with a hard step.
        let alpha = Map::from_fn(16, 16, 1, |_, _, x| if x < 8 { 1.0 } else { 0.3 });
        let rings = upsample(&alpha, 4, Kernel::Lanczos3, Border::Mirror);
        let below = rings.data().iter().copied().fold(f32::INFINITY, f32::min);
        assert!(below < 0.29, "the upsampler undershoots the step: {below}");
        let up = upscale(&alpha, Method::SoftAlpha, how(&Lanczos)).unwrap();
        let (lo, hi) = (up.data().iter()).fold((f32::INFINITY, 0.0f32), |(lo, hi), &v| {
            (lo.min(v), hi.max(v))
        });
        assert!(lo >= 0.3 && hi <= 1.0, "{lo}..{hi}");
        // Away from the step the values are the input's.
        assert_eq!(up.get(0, 20, 4), 1.0);
        assert!((up.get(0, 20, 60) - 0.3).abs() < 1e-6);
    }

    #[test]
    fn a_cutout_stays_binary_with_its_edge_in_place() {
        let alpha = Map::from_fn(16, 16, 1, |_, y, x| ((x + y) < 16) as u8 as f32);
        let carried = Carried {
            alpha: [(MapKind::BaseColor, alpha.clone())].into(),
            extras: Vec::new(),
        };
        let plan = CarriedPlan::of(&carried);
        assert_eq!(plan, CarriedPlan(vec![Method::Cutout]));
        let opaque = Carried {
            alpha: [(MapKind::BaseColor, Map::filled(16, 16, 1, 1.0))].into(),
            extras: Vec::new(),
        };
        assert_eq!(
            CarriedPlan::of(&opaque),
            CarriedPlan(vec![Method::Constant])
        );
        let up = upscale_carried(&carried, &plan, how(&Lanczos))
            .unwrap()
            .alpha[&MapKind::BaseColor]
            .clone();
        assert!(up.data().iter().all(|&v| v == 0.0 || v == 1.0));
        let seen = matup_core::resample::box_downsample(&up, 4);
        let off: f32 = (seen.data().iter().zip(alpha.data()))
            .map(|(a, b)| (a - b).abs())
            .sum::<f32>()
            / alpha.texels() as f32;
        assert!(off < 0.05, "{off}");
    }
}
