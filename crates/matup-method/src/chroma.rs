//! Keeping the base colour's hue to the input's: an SR network may sharpen brightness, but a
//! hue the input has nowhere near (a grey groove turned magenta) is an error an artist sees at
//! once. Colours here are sRGB-encoded, split into luma (Rec. 709 weights) and chroma
//! (R′ − G′, B′ − G′), the chroma `matup eval`'s false-colour count judges.

use rayon::prelude::*;

use matup_core::candle_core::{self, Tensor};
use matup_core::color::{
    linear_to_srgb, linear_to_srgb_tensor, srgb_to_linear, srgb_to_linear_tensor,
};
use matup_core::device_maps;
use matup_core::map::Map;
use matup_core::resample::{lr_texel, neighbourhood_ranges, Border};

const WEIGHTS: [f32; 3] = [0.2126, 0.7152, 0.0722];

pub(crate) fn luma(rgb: [f32; 3]) -> f32 {
    (0..3).map(|c| WEIGHTS[c] * rgb[c]).sum()
}

/// Texel `i` of the first three channels of `m` (linear), sRGB-encoded.
fn encoded(m: &Map, i: usize) -> [f32; 3] {
    [0, 1, 2].map(|c| linear_to_srgb(m.plane(c)[i]))
}

/// The chroma (R′ − G′, B′ − G′) of an sRGB-encoded colour.
fn chroma(rgb: [f32; 3]) -> [f32; 2] {
    [rgb[0] - rgb[1], rgb[2] - rgb[1]]
}

/// The colour of luma `y` and chroma `(cr, cb)`; where a channel would leave [0, 1], the
/// chroma is scaled toward grey until none does (`y` is kept).
fn from_luma_chroma(y: f32, chroma: [f32; 2]) -> [f32; 3] {
    let y = y.clamp(0.0, 1.0);
    // y = g + 0.2126 cr + 0.0722 cb, r = g + cr, b = g + cb.
    let offsets = |k: f32| {
        let (cr, cb) = (k * chroma[0], k * chroma[1]);
        let g = -(WEIGHTS[0] * cr + WEIGHTS[2] * cb);
        [g + cr, g, g + cb]
    };
    let full = offsets(1.0);
    // The largest k ≤ 1 with y + k·offset in [0, 1] for every channel.
    let k = full.iter().fold(1.0f32, |k, &o| {
        if y + o > 1.0 {
            k.min((1.0 - y) / o)
        } else if y + o < 0.0 {
            k.min(y / -o)
        } else {
            k
        }
    });
    offsets(k.max(0.0)).map(|o| (y + o).clamp(0.0, 1.0))
}

/// A linear colour map with the luma of `luma_from` and the chroma of `chroma_from` (two
/// upsamplings of one colour map).
pub fn with_chroma_of(luma_from: &Map, chroma_from: &Map) -> Map {
    let mut out = Map::filled(luma_from.width(), luma_from.height(), 3, 0.0);
    for i in 0..luma_from.texels() {
        let rgb = from_luma_chroma(luma(encoded(luma_from, i)), chroma(encoded(chroma_from, i)));
        for (c, v) in rgb.into_iter().enumerate() {
            out.plane_mut(c)[i] = srgb_to_linear(v);
        }
    }
    out
}

/// Clamps the chroma of each texel of `hr` (its first three channels a linear colour, `scale`
/// times the size of `lr`'s) into the chroma range of its `lr` texel's 3×3 neighbourhood
/// (rows and columns past the edge wrapped or mirrored as `border` says), its luma kept: the
/// output has no hue its input lacks around it.
pub fn clamp_chroma_to_input(hr: &mut Map, lr: &Map, scale: usize, border: Border) {
    let lr_chroma: Vec<[f32; 2]> = (0..lr.texels()).map(|i| chroma(encoded(lr, i))).collect();
    let ranges = neighbourhood_ranges(&lr_chroma, lr.width(), border);
    let (w, n) = (hr.width(), hr.texels());
    let (red, rest) = hr.data_mut().split_at_mut(n);
    let (green, rest) = rest.split_at_mut(n);
    let blue = &mut rest[..n];
    // Row by row on rayon's threads: three sRGB encodings a texel make this a whole-map cost.
    (red.par_chunks_mut(w).zip(green.par_chunks_mut(w)))
        .zip(blue.par_chunks_mut(w))
        .enumerate()
        .for_each(|(y, ((red, green), blue))| {
            for x in 0..w {
                let range = &ranges[lr_texel(y * w + x, w, scale, lr.width())];
                let colour = [red[x], green[x], blue[x]].map(linear_to_srgb);
                let own = chroma(colour);
                let clamped = [0, 1].map(|k| own[k].clamp(range[k][0], range[k][1]));
                if clamped == own {
                    continue;
                }
                [red[x], green[x], blue[x]] =
                    from_luma_chroma(luma(colour), clamped).map(srgb_to_linear);
            }
        });
}

/// The chroma range of each of `lr`'s texels' 3×3 neighbourhoods (the range
/// [`clamp_chroma_to_input`] keeps to), on `device` at `scale` times `lr`'s size: `[4, h·scale,
/// w·scale]`, red's least and greatest, then blue's.
pub fn chroma_bounds_on_device(
    lr: &Map,
    scale: usize,
    border: Border,
    device: &candle_core::Device,
) -> candle_core::Result<Tensor> {
    let lr_chroma: Vec<[f32; 2]> = (0..lr.texels()).map(|i| chroma(encoded(lr, i))).collect();
    device_maps::neighbourhood_bounds(&lr_chroma, lr.width(), scale, border, device)
}

/// [`clamp_chroma_to_input`] on a device: `hr`, `[3, H, W]` linear colours, with each texel's
/// chroma clamped into `bounds` ([`chroma_bounds_on_device`]), its luma kept.
pub fn clamp_chroma_on_device(hr: &Tensor, bounds: &Tensor) -> candle_core::Result<Tensor> {
    let bound = |k: usize| bounds.narrow(0, k, 1);
    let colour = linear_to_srgb_tensor(hr)?;
    let channel = |c: usize| colour.narrow(0, c, 1);
    let (red, green, blue) = (channel(0)?, channel(1)?, channel(2)?);
    let own = [(&red - &green)?, (&blue - &green)?];
    let clamped = [
        own[0].maximum(&bound(0)?)?.minimum(&bound(1)?)?,
        own[1].maximum(&bound(2)?)?.minimum(&bound(3)?)?,
    ];
    let changed = own[0].ne(&clamped[0])?.maximum(&own[1].ne(&clamped[1])?)?;
    let luma = (((&red * WEIGHTS[0] as f64)? + (&green * WEIGHTS[1] as f64)?)?
        + (&blue * WEIGHTS[2] as f64)?)?;
    let moved = srgb_to_linear_tensor(&from_luma_chroma_on_device(&luma, &clamped)?)?;
    changed.broadcast_as(hr.shape())?.where_cond(&moved, hr)
}

/// [`from_luma_chroma`] of every texel: `y` `[1, h, w]`, the chroma two such; `[3, h, w]`.
fn from_luma_chroma_on_device(y: &Tensor, chroma: &[Tensor; 2]) -> candle_core::Result<Tensor> {
    let y = y.clamp(0f32, 1f32)?;
    let offsets = |k: &Tensor| -> candle_core::Result<[Tensor; 3]> {
        let (cr, cb) = (chroma[0].mul(k)?, chroma[1].mul(k)?);
        let g = ((&cr * WEIGHTS[0] as f64)? + (&cb * WEIGHTS[2] as f64)?)?.neg()?;
        Ok([(&g + &cr)?, g.clone(), (&g + &cb)?])
    };
    let one = y.ones_like()?;
    let mut k = one.clone();
    for o in offsets(&one)? {
        let reached = (&y + &o)?;
        let over = k.minimum(&((&one - &y)? / &o)?)?;
        let under = k.minimum(&(&y / &o.neg()?)?)?;
        k = reached
            .gt(1f32)?
            .where_cond(&over, &reached.lt(0f32)?.where_cond(&under, &k)?)?;
    }
    let channels = offsets(&k.maximum(0f32)?)?.map(|o| (&y + o).and_then(|v| v.clamp(0f32, 1f32)));
    let [r, g, b] = channels;
    Tensor::cat(&[r?, g?, b?], 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_and_chroma_round_trip_and_stay_in_range() {
        for rgb in [
            [0.2, 0.5, 0.9],
            [1.0, 0.0, 0.3],
            [0.0, 0.0, 0.0],
            [0.6, 0.6, 0.6],
        ] {
            let y = luma(rgb);
            let back = from_luma_chroma(y, chroma(rgb));
            for c in 0..3 {
                assert!((back[c] - rgb[c]).abs() < 1e-5, "{rgb:?} → {back:?}");
            }
        }
        // A dark texel with a strong chroma: the chroma gives way, the luma is kept.
        let rgb = from_luma_chroma(0.05, [0.5, 0.3]);
        assert!(rgb.iter().all(|v| (0.0..=1.0).contains(v)), "{rgb:?}");
        assert!((luma(rgb) - 0.05).abs() < 1e-5);
    }

    #[test]
    fn a_hue_the_input_lacks_is_clamped_away_and_its_brightness_kept() {
        // Grey input; an output texel turned magenta at the same brightness.
        let lr = Map::filled(4, 4, 3, 0.2);
        let mut hr = Map::filled(16, 16, 3, 0.2);
        let magenta = [0.35, 0.02, 0.3];
        for (c, v) in magenta.into_iter().enumerate() {
            hr.plane_mut(c)[5 * 16 + 7] = v;
        }
        let before = luma(encoded(&hr, 5 * 16 + 7));
        clamp_chroma_to_input(&mut hr, &lr, 4, Border::Mirror);
        let after = encoded(&hr, 5 * 16 + 7);
        assert!((after[0] - after[1]).abs() < 1e-4 && (after[2] - after[1]).abs() < 1e-4);
        assert!((luma(after) - before).abs() < 1e-4);
        // Texels already within range are untouched.
        assert_eq!(hr.plane(0)[0], 0.2);
    }
}
