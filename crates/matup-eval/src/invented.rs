//! Invented structure: what an upscaled map draws where its input is flat within its noise,
//! and neither a smooth upsampling of the input nor (where given) the truth has. A network
//! shown compressed or noisy maps can read their noise as detail and draw veins and worm
//! strokes out of it; those stay inside the input's local range, so a bound on values
//! ([`crate::metrics::new_structure`]) does not see them. This measure does.
//!
//! Per map, in the file's 8-bit levels (colour: the luminance of its sRGB values; normals
//! and other maps: each channel):
//! 1. the input's noise level `σ`, from the median absolute response of Immerkær's
//!    Laplacian-difference operator (robust to the texture itself);
//! 2. flat input texels: those whose 3×3 neighbourhood's standard deviation is at most
//!    [`FLAT_NOISE_MULTIPLE`]`· σ` (and at least 1 level);
//! 3. in their blocks of the output, the texels whose detail (the output less its Gaussian blur
//!    of σ = half the scale: what is finer than an input texel) exceeds `T =`
//!    max([`INVENTED_LEVELS`], [`INVENTED_NOISE_MULTIPLE`]` · σ`) where the input's bilinear
//!    upsampling has none so large; with a truth, only where the truth has none either.
//!
//! The share of the output's texels so counted is its invented structure. A smooth upsampling
//! reads about 0, and so does an output that removes the input's noise (detail, not departure
//! from the input, is counted); a network that amplifies the noise into strokes reads above.

use matup_core::map::Map;
use matup_core::material::MapKind;
use matup_core::resample::{gaussian_blur, lr_texel, upsample, Border, Kernel};
use matup_core::texel_trace::{immerkaer_response, IMMERKAER_GAIN};

/// How many noise deviations a neighbourhood's spread may reach and still count as flat.
pub const FLAT_NOISE_MULTIPLE: f32 = 2.0;
/// The least departure from the smooth upsampling, in levels, that counts as drawn structure.
pub const INVENTED_LEVELS: f32 = 4.0;
/// The departure that counts, in noise deviations, where the input's noise is larger.
pub const INVENTED_NOISE_MULTIPLE: f32 = 2.0;

/// Invented structure of one map.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Invented {
    /// The share of the output's texels of invented structure.
    pub share: f64,
    /// The share of the input's texels that are flat within its noise (in any channel).
    pub flat_share: f64,
    /// The input's noise level in levels (the largest over its channels).
    pub noise_levels: f64,
}

/// [`Invented`] of `up` (a map of `kind` upscaled from `lr` by a whole factor), against
/// `truth` where given; neighbours past the edge as `border` says.
pub fn invented_structure(
    kind: MapKind,
    lr: &Map,
    up: &Map,
    truth: Option<&Map>,
    border: Border,
) -> Invented {
    let scale = up.width() / lr.width().max(1);
    let (lr, up, truth) = (
        signal(kind, lr),
        signal(kind, up),
        truth.map(|t| signal(kind, t)),
    );
    let smooth = upsample(&lr, scale, Kernel::Bilinear, border);
    let sigma_hr = 0.5 * scale as f32;
    let (w, h, lw) = (up.width(), up.height(), lr.width());
    let detail = |plane: &[f32]| -> Vec<f32> {
        let blurred = gaussian_blur(plane, w, h, sigma_hr, border);
        plane
            .iter()
            .zip(&blurred)
            .map(|(v, b)| (v - b).abs())
            .collect()
    };
    let (mut invented, mut noise_levels) = (0usize, 0f32);
    let mut counted = vec![false; up.texels()];
    let mut flat_anywhere = vec![false; lr.texels()];
    for c in 0..lr.channels() {
        let plane = lr.plane(c);
        let sigma = noise_sigma(plane, lw, lr.height());
        noise_levels = noise_levels.max(sigma);
        let flat = flat_texels(plane, lw, lr.height(), sigma, border);
        for (any, &f) in flat_anywhere.iter_mut().zip(&flat) {
            *any |= f;
        }
        let limit = INVENTED_LEVELS.max(INVENTED_NOISE_MULTIPLE * sigma);
        let (u, s) = (detail(up.plane(c)), detail(smooth.plane(c)));
        let t = truth.as_ref().map(|t| detail(t.plane(c)));
        for i in 0..up.texels() {
            if counted[i] || !flat[lr_texel(i, w, scale, lw)] {
                continue;
            }
            let elsewhere = s[i] > limit || t.as_ref().is_some_and(|t| t[i] > limit);
            if u[i] > limit && !elsewhere {
                counted[i] = true;
                invented += 1;
            }
        }
    }
    Invented {
        share: invented as f64 / up.texels().max(1) as f64,
        flat_share: flat_anywhere.iter().filter(|&&f| f).count() as f64 / lr.texels().max(1) as f64,
        noise_levels: noise_levels as f64,
    }
}

/// What the measure reads of a map, in 8-bit levels: a colour's luminance of its sRGB values,
/// a normal's x and y, another map's channels.
fn signal(kind: MapKind, map: &Map) -> Map {
    let levels = |c: usize, i: usize| 255.0 * kind.stored(c, map.plane(c)[i]);
    let (w, h) = (map.width(), map.height());
    match kind {
        MapKind::BaseColor if map.channels() >= 3 => Map::from_fn(w, h, 1, |_, y, x| {
            let i = y * w + x;
            0.2126 * levels(0, i) + 0.7152 * levels(1, i) + 0.0722 * levels(2, i)
        }),
        MapKind::Normal => {
            Map::from_fn(w, h, 2.min(map.channels()), |c, y, x| levels(c, y * w + x))
        }
        _ => Map::from_fn(w, h, map.channels(), |c, y, x| levels(c, y * w + x)),
    }
}

/// A plane's noise deviation: Immerkær's operator (the difference of two Laplacians, which
/// cancels smooth variation; its weights' squares sum to 36), its median absolute response
/// over interior texels read as a Gaussian's (median |x| = 0.6745 σ).
fn noise_sigma(plane: &[f32], w: usize, h: usize) -> f32 {
    if w < 3 || h < 3 {
        return 0.0;
    }
    let mut responses: Vec<f32> = (1..h - 1)
        .flat_map(|y| (1..w - 1).map(move |x| (y, x)))
        .map(|(y, x)| immerkaer_response(|dx, dy| plane[(y + dy - 1) * w + x + dx - 1]).abs())
        .collect();
    let middle = responses.len() / 2;
    let (_, median, _) = responses.select_nth_unstable_by(middle, f32::total_cmp);
    *median / (0.6745 * IMMERKAER_GAIN)
}

/// Whether each texel's 3×3 neighbourhood varies no more than its noise.
fn flat_texels(plane: &[f32], w: usize, h: usize, sigma: f32, border: Border) -> Vec<bool> {
    let limit = (FLAT_NOISE_MULTIPLE * sigma).max(1.0);
    (0..plane.len())
        .map(|i| {
            let (y, x) = ((i / w) as isize, (i % w) as isize);
            let values = (0..9).map(|k| {
                plane[border.index(y + k / 3 - 1, h) * w + border.index(x + k % 3 - 1, w)]
            });
            let (mut sum, mut sum2) = (0.0f32, 0.0f32);
            for v in values {
                sum += v;
                sum2 += v * v;
            }
            let mean = sum / 9.0;
            (sum2 / 9.0 - mean * mean).max(0.0).sqrt() <= limit
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::rngs::StdRng;
    use rand::{Rng, SeedableRng};

    /// A grey input of a smooth ramp with noise of `sigma` levels.
    fn noisy(size: usize, sigma: f32, seed: u64) -> Map {
        let mut rng = StdRng::seed_from_u64(seed);
        let noise: Vec<f32> = (0..size * size)
            .map(|_| (0..12).map(|_| rng.random::<f32>()).sum::<f32>() - 6.0)
            .collect();
        Map::from_fn(size, size, 1, |_, y, x| {
            0.4 + 0.1 * x as f32 / size as f32 + sigma / 255.0 * noise[y * size + x]
        })
    }

    #[test]
    fn the_noise_level_is_read_through_the_texture() {
        for sigma in [1.0f32, 3.0, 6.0] {
            let map = noisy(96, sigma, 1);
            let read = noise_sigma(&signal(MapKind::Roughness, &map).into_data(), 96, 96);
            assert!((read / sigma - 1.0).abs() < 0.12, "σ {sigma}: read {read}");
        }
    }

    #[test]
    fn strokes_drawn_out_of_noise_count_and_a_smooth_upsampling_does_not() {
        let lr = noisy(32, 2.0, 2);
        let border = Border::Mirror;
        let smooth = upsample(&lr, 4, Kernel::Bicubic { a: -0.5 }, border);
        let quiet = invented_structure(MapKind::Roughness, &lr, &smooth, None, border);
        assert!(quiet.flat_share > 0.9, "{quiet:?}");
        assert!(quiet.share < 0.001, "bicubic: {quiet:?}");
        // Worm strokes: a dark line of 12 levels, one texel wide, every 8 rows.
        let mut wormy = smooth.clone();
        for y in (3..128).step_by(8) {
            for x in 0..128 {
                wormy.plane_mut(0)[y * 128 + x] -= 12.0 / 255.0;
            }
        }
        let drawn = invented_structure(MapKind::Roughness, &lr, &wormy, None, border);
        assert!((drawn.share - 1.0 / 8.0).abs() < 0.01, "{drawn:?}");
        // An output that removes the input's noise draws nothing.
        let clean = Map::from_fn(128, 128, 1, |_, _, x| 0.4 + 0.1 * x as f32 / 128.0);
        let denoised = invented_structure(MapKind::Roughness, &lr, &clean, None, border);
        assert!(denoised.share < 0.001, "denoised: {denoised:?}");
        // Where the truth has those lines, they are not invented.
        let known = invented_structure(MapKind::Roughness, &lr, &wormy, Some(&wormy), border);
        assert!(known.share < 0.001, "{known:?}");
        // Nor is anything counted where the input is not flat: a strong wave, drawn sharper.
        let busy = Map::from_fn(32, 32, 1, |_, y, x| {
            0.5 + 0.12 * ((x as f32).sin() + (y as f32 * 1.3).sin())
        });
        let up = upsample(&busy, 4, Kernel::Lanczos3, border);
        let m = invented_structure(MapKind::Roughness, &busy, &up, None, border);
        assert_eq!((m.share, m.flat_share), (0.0, 0.0), "{m:?}");
    }
}
