//! `preview.png`: the bilinearly upsampled input beside matup's result, rendered under a
//! high and a low light, labelled; and the central square of a streamed output it is made
//! from.

use crate::bands::Assembler;
use crate::plan::Plan;
use matup_core::lights::Light;
use matup_core::map::Map;
use matup_core::material::Material;
use matup_core::output_band::OutputBand;
use matup_core::render::{render, RenderOptions};
use matup_core::resample::{Border, Kernel};
use matup_core::Result;
use matup_draw::labelled_sheet;

/// `input` upsampled bilinearly to `output`'s size: what the preview and the viewer compare
/// matup's result with.
pub fn bilinear_baseline(input: &Material, output: &Material, tileable: bool) -> Material {
    bilinear_to(input, [output.width(), output.height_px()], tileable)
}

/// `input` upsampled bilinearly to `size`: by the whole scale that reaches it, area-shrunk to
/// it where that overshoots (a size asked for between scales).
fn bilinear_to(input: &Material, size: [usize; 2], tileable: bool) -> Material {
    let up = input.upsample(
        scale_between(input, size[0]),
        Kernel::Bilinear,
        Border::for_tiling(tileable),
    );
    if [up.width(), up.height_px()] == size {
        up
    } else {
        up.area_resize(size[0], size[1])
    }
}

/// The whole scale that makes `input` at least `output_width` wide (at least 1).
fn scale_between(input: &Material, output_width: usize) -> usize {
    output_width.div_ceil(input.width().max(1)).max(1)
}

/// The side of the square the preview shows (the whole of a smaller output).
const PREVIEW_SIDE: usize = 512;

/// The side of the preview's square for an output of `size`.
fn preview_side(size: [usize; 2]) -> usize {
    PREVIEW_SIDE.min(size[0]).min(size[1])
}

/// The top-left texel of the central `side` × `side` square of an output of `size`.
fn centre_origin(size: [usize; 2], side: usize) -> (usize, usize) {
    ((size[0] - side) / 2, (size[1] - side) / 2)
}

/// The central square of an output that the preview shows, collected from the output's
/// bands as they pass (a streamed output is never whole).
pub struct PreviewWindow {
    side: usize,
    origin: (usize, usize),
    rows: Assembler,
}

impl PreviewWindow {
    /// For an output of `size` ([width, height]).
    pub fn new(size: [usize; 2]) -> PreviewWindow {
        let side = preview_side(size);
        PreviewWindow {
            side,
            origin: centre_origin(size, side),
            rows: Assembler::new(side),
        }
    }

    /// Keeps what of `band`, the output's rows from `first` on, lies in the square (brought
    /// back from a device, where its maps are there).
    pub fn add(&mut self, first: usize, band: &OutputBand) -> Result<()> {
        let (x0, y0) = self.origin;
        let top = first.max(y0);
        let bottom = (first + band.rows()).min(y0 + self.side);
        if top < bottom {
            let piece = band.crop(x0, top - first, self.side, bottom - top)?;
            self.rows.add(top - y0, &piece);
        }
        Ok(())
    }

    /// The square (`None` before any band).
    pub fn finish(self) -> Option<Material> {
        self.rows.finish()
    }
}

/// The central `side` × `side` texels of `m`.
fn centre(m: &Material, side: usize) -> Material {
    if side == m.width() && side == m.height_px() {
        return m.clone();
    }
    let (x0, y0) = centre_origin([m.width(), m.height_px()], side);
    // The maps as they are, as [`PreviewWindow`] keeps them from bands.
    m.map_maps(|map| map.crop(x0, y0, side, side))
}

/// `centre` of `input` upsampled bilinearly to `output_size`, from a window of the input
/// with two texels of context (bilinear taps reach one) instead of the whole input: a 2K²
/// input's preview would otherwise upsample all of it to 8K² (2 GB) for 512² texels.
/// Windows that reach the input's edges take the whole, whose borders wrap or mirror.
fn bilinear_centre(
    input: &Material,
    output_size: [usize; 2],
    side: usize,
    tileable: bool,
) -> Material {
    let scale = scale_between(input, output_size[0]);
    if output_size != [input.width() * scale, input.height_px() * scale] {
        // Between scales: the whole, shrunk (such outputs are made whole too).
        return centre(&bilinear_to(input, output_size, tileable), side);
    }
    let border = Border::for_tiling(tileable);
    let (x0, y0) = centre_origin(output_size, side);
    let window = |start: usize, len: usize| {
        let first = (start / scale).saturating_sub(2);
        let end = (start + side).div_ceil(scale) + 2;
        (first > 0 && end < len).then_some((first, end - first))
    };
    match (window(x0, input.width()), window(y0, input.height_px())) {
        (Some((wx, ww)), Some((wy, wh))) => {
            // The maps as they are: `Material::crop` would renormalise the input's normals,
            // which the whole upsample reads unrenormalised.
            let window = input.map_maps(|m| m.crop(wx, wy, ww, wh));
            let up = window.upsample(scale, Kernel::Bilinear, border);
            up.map_maps(|m| m.crop(x0 - wx * scale, y0 - wy * scale, side, side))
        }
        _ => centre(&bilinear_to(input, output_size, tileable), side),
    }
}

/// `preview.png`: the bilinearly upsampled input (left) and the result (right), rendered
/// under two training lights (rows), labelled. Large outputs show their central 512² texels.
pub fn preview(input: &Material, output: &Material, plan: &Plan) -> Result<Map> {
    let size = [output.width(), output.height_px()];
    preview_of_centre(input, &centre(output, preview_side(size)), size, plan)
}

/// [`preview`] from the output's central square alone (what [`PreviewWindow`] kept of an
/// output of `output_size`).
pub fn preview_of_centre(
    input: &Material,
    result: &Material,
    output_size: [usize; 2],
    plan: &Plan,
) -> Result<Map> {
    let tileable = plan.tiling.tileable;
    let border = plan.tiling.border();
    let side = preview_side(output_size);
    let baseline = bilinear_centre(input, output_size, side, tileable);
    let model = &plan.shading;
    let lights = &plan.lights;
    // A high light and a low one: shading detail shows at grazing angles.
    let by_height = |a: &&Light, b: &&Light| a.position[2].total_cmp(&b.position[2]);
    let high = *lights.iter().max_by(by_height).unwrap();
    let low = *lights
        .iter()
        .filter(|l| l.position[2] > 0.3 * plan.setup.settings.lights.distance)
        .min_by(by_height)
        .unwrap_or(&high);
    let options = RenderOptions {
        supersample: false,
        border,
    };
    let mut tiles = Vec::new();
    let mut captions = Vec::new();
    for light in [high, low] {
        for m in [&baseline, result] {
            tiles.extend(render(m, model.as_ref(), &[light], options));
        }
        let [x, y, z] = light.position;
        captions.push(format!(
            "light at {:.0}° elevation, {:.0}° azimuth",
            z.atan2(x.hypot(y)).to_degrees(),
            y.atan2(x).to_degrees().rem_euclid(360.0)
        ));
    }
    let scale = scale_between(input, output_size[0]);
    let columns = [format!("bilinear ×{scale}"), "matup".to_string()];
    Ok(labelled_sheet(&tiles, 2, 4, &columns, &captions))
}

#[cfg(test)]
mod tests {
    use super::*;
    use matup_core::io::{load_material, LoadOptions};
    use matup_core::material::MapKind;

    #[test]
    fn the_preview_window_keeps_the_centre_of_the_bands() {
        let output = Material::uniform(1, [0.0; 3], 0.5, 0.0)
            .map_maps(|_| Map::from_fn(1100, 900, 1, |_, y, x| (y * 1100 + x) as f32));
        let mut window = PreviewWindow::new([1100, 900]);
        for first in (0..900).step_by(130) {
            let rows = 130.min(900 - first);
            let band = OutputBand::from(output.map_maps(|m| m.rows(first, rows)));
            window.add(first, &band).unwrap();
        }
        let kept = window.finish().unwrap();
        assert!(kept == centre(&output, 512));
        assert_eq!(kept.roughness.get(0, 0, 0), (194 * 1100 + 294) as f32);
    }

    #[test]
    fn the_preview_upsamples_a_window_equal_to_the_whole() {
        let sample =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../samples/victorian_wood");
        let input = load_material(Some(&sample), &LoadOptions::default()).unwrap();
        let output = input.upsample(4, Kernel::Bilinear, Border::Wrap); // its size is what counts
        for tileable in [true, false] {
            let whole = centre(&bilinear_baseline(&input, &output, tileable), 64);
            let size = [output.width(), output.height_px()];
            let window = bilinear_centre(&input, size, 64, tileable);
            for kind in MapKind::ALL {
                // Not assert_eq: a failure would print every value.
                let same = whole.map(kind).map(Map::data) == window.map(kind).map(Map::data);
                assert!(same, "{kind:?}, tileable {tileable}");
            }
        }
    }
}
