//! Outputs of any size in bounded memory: a level's output is made in bands of whole rows,
//! each from the LR rows it covers plus enough rows of context above and below that the
//! rows it keeps come out as the whole image's would (within the upsampler's own tiling
//! differences). Bands are full width, so every column sees the material's own border (wrap
//! or mirror) exactly; only the band's top and bottom need context: wrapped around for
//! tileable materials, and none beyond the material's edge otherwise (the band's mirror
//! border there is the whole image's).

use matup_core::map::Map;
use matup_core::material::Material;
use matup_core::output_band::OutputBand;
use matup_core::resample::Border;
use matup_core::{Error, Result};

/// Heap bytes a band needs per output texel it makes, context rows included: the residual
/// base's 7 features, an upsampled map and the upsampler's accumulators, the 8 decoded maps,
/// and the height solve's two f64 buffers with its blurs. `cargo bench --bench memory`
/// measured 64 at 2K² and 4K² → ×4 (2 and 4 bands) and 73 at 1K² (3 small bands;
/// docs/experiments/2026-11-24-memory-of-large-outputs.md); the rest is headroom for what the process holds beside the heap.
pub const BYTES_PER_BAND_TEXEL: u64 = 80;

/// Heap bytes per output texel a self-ensemble adds to a band: the sum of a colour map's
/// passes (3 × f32) beside the pass being made. The 1K² → 4K² run in 3 bands at 1 GiB peaked
/// at 757 MiB with two passes against 655 MiB with one (docs/experiments/2026-11-25-self-ensemble.md).
pub const ENSEMBLE_BYTES_PER_BAND_TEXEL: u64 = 12;

/// GPU bytes per output texel of a band whose residual base is made on the GPU
/// (`residual::residual_base_on_device`): a map's passes as the network leaves them (2 × 3
/// f32) and their sum, the 7 features, and the back-projection's, settling's and chroma
/// clamp's full-size temporaries, several alive at once. Decoding the features into maps there
/// (`fit::decoded_maps_on_device`) comes after and holds less (about 200 bytes at its peak).
/// Counted from the stages' tensors, not yet measured on a GPU; a band is planned within a
/// quarter of the GPU's free memory.
pub const DEVICE_BYTES_PER_BAND_TEXEL: u64 = 320;

/// Heap bytes per texel of an upsampler's native scale where it serves a smaller one
/// ([`matup_core::upsample::route`]): the image at the native scale (RGB f32) and the
/// network's last feature map before it is rearranged into that image. At ×2 through ×4
/// there are 4 of these texels to each output texel.
pub const ROUTE_BYTES_PER_NATIVE_TEXEL: u64 = 24;

/// Heap bytes per LR texel that do not shrink with the band: the level's input (36 bytes a
/// texel with height), what the caller holds beside it, the writers' buffers.
pub const BYTES_PER_LR_TEXEL: u64 = 100;

/// The fewest LR rows a band keeps: narrower bands would spend most of their time on context.
pub const MIN_BAND_ROWS: usize = 8;

/// One band: the LR rows it keeps and the rows it reads (`read_first` may be negative or run
/// past the last row for tileable materials, whose rows wrap around).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Band {
    pub first: usize,
    pub rows: usize,
    pub read_first: isize,
    pub read_rows: usize,
}

impl Band {
    /// The rows of `m` this band reads.
    pub fn read(&self, m: &Map) -> Map {
        let h = m.height() as isize;
        m.gather_rows(self.read_rows, |y| {
            (self.read_first + y as isize).rem_euclid(h) as usize
        })
    }

    /// The rows of every map of `m` this band reads (maps as they are: no invariants touched).
    pub fn read_material(&self, m: &Material) -> Material {
        m.map_maps(|map| self.read(map))
    }

    /// Cuts `out`, made from [`Band::read`]'s rows at `scale`, down to the rows this band
    /// keeps, in place.
    pub fn keep(&self, out: &mut OutputBand, scale: usize) -> Result<()> {
        let skip = (self.first as isize - self.read_first) as usize * scale;
        out.keep_rows(skip, self.rows * scale)
    }
}

/// How a level's LR rows are cut into bands.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BandPlan {
    bands: Vec<Band>,
}

impl BandPlan {
    /// The whole image as one band.
    pub fn whole(height: usize) -> BandPlan {
        BandPlan {
            bands: vec![Band {
                first: 0,
                rows: height,
                read_first: 0,
                read_rows: height,
            }],
        }
    }

    /// Bands of `height` rows, each reading at most `max_read` rows: `context` rows above and
    /// below what it keeps (wrapped around with [`Border::Wrap`]; none past the edge
    /// otherwise, where the band keeps those rows instead), every band but the last as large
    /// as `max_read` allows. Needs `max_read > 2 · context`.
    pub fn greedy(height: usize, max_read: usize, context: usize, border: Border) -> BandPlan {
        assert!(
            max_read > 2 * context,
            "bands of {max_read} rows, {context} of context"
        );
        let wrap = border == Border::Wrap;
        let mut bands = Vec::new();
        let mut first = 0;
        while first < height {
            let above = if wrap { context } else { context.min(first) };
            let rest = height - first;
            let rows = if wrap {
                rest.min(max_read - 2 * context)
            } else if above + rest <= max_read {
                rest
            } else {
                max_read - above - context
            };
            let below = if wrap {
                context
            } else {
                context.min(rest - rows)
            };
            bands.push(Band {
                first,
                rows,
                read_first: first as isize - above as isize,
                read_rows: above + rows + below,
            });
            first += rows;
        }
        BandPlan { bands }
    }

    pub fn count(&self) -> usize {
        self.bands.len()
    }

    pub fn is_whole(&self) -> bool {
        self.count() <= 1
    }

    /// The most LR rows a band keeps.
    pub fn rows(&self) -> usize {
        self.bands.iter().map(|b| b.rows).max().unwrap_or(0)
    }

    pub fn bands(&self) -> impl Iterator<Item = Band> + '_ {
        self.bands.iter().copied()
    }
}

/// The bands for an LR input of `width × height` upsampled by `scale` within `limit` bytes
/// of heap (none: one band), each reading `context` LR rows beyond what it keeps and needing
/// `per_texel` bytes per output texel ([`BYTES_PER_BAND_TEXEL`], plus
/// [`ENSEMBLE_BYTES_PER_BAND_TEXEL`] with a self-ensemble). One band
/// when the whole fits; an error naming the limit when not even [`MIN_BAND_ROWS`] rows do.
///
/// The rows a band reads are a multiple of `tile` where that fits (the upsampler's tiles: a
/// band reading 261 rows would run two rows of 256² tiles), and every band but the last
/// reads as many as fit: the work repeated is the context's, twice per band boundary, so the
/// fewest bands cost the least.
#[allow(clippy::too_many_arguments)] // independent quantities; a struct would only rename them
pub fn plan_bands(
    width: usize,
    height: usize,
    scale: usize,
    context: usize,
    tile: Option<usize>,
    border: Border,
    limit: Option<u64>,
    per_texel: u64,
) -> Result<BandPlan> {
    let whole = BandPlan::whole(height);
    let Some(limit) = limit else {
        return Ok(whole);
    };
    let s2 = (scale * scale) as u64;
    let fixed = BYTES_PER_LR_TEXEL * (width * height) as u64;
    let per_lr_row = per_texel * s2 * width as u64;
    let rows_fitting = (limit.saturating_sub(fixed) / per_lr_row.max(1)) as usize;
    if rows_fitting >= height {
        return Ok(whole);
    }
    let max_read = match tile {
        Some(t) if t > 0 && rows_fitting / t * t >= 2 * context + MIN_BAND_ROWS => {
            rows_fitting / t * t
        }
        _ => rows_fitting,
    };
    if max_read < 2 * context + MIN_BAND_ROWS {
        let needed = fixed + per_lr_row * (MIN_BAND_ROWS + 2 * context) as u64;
        return Err(Error::Invalid(format!(
            "a memory limit of {} MiB is too low for {width}×{height} → {}×{}: bands of {} \
             rows with {context} rows of context need about {} MiB",
            limit >> 20,
            width * scale,
            height * scale,
            MIN_BAND_ROWS,
            needed.div_ceil(1 << 20)
        )));
    }
    Ok(BandPlan::greedy(height, max_read, context, border))
}

/// The default memory limit: a quarter of the machine's memory (Linux's `MemTotal`; 16 GiB
/// elsewhere), between 1 and 16 GiB. A share, not all: the machine runs other things; and
/// not less, because narrow bands repeat their context's work (docs/experiments/2026-11-24-memory-of-large-outputs.md).
pub fn default_memory_limit() -> u64 {
    const GIB: u64 = 1 << 30;
    let total = std::fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|info| {
            let line = info.lines().find(|l| l.starts_with("MemTotal:"))?;
            let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
            Some(kib * 1024)
        })
        .unwrap_or(16 * GIB * 4);
    (total / 4).clamp(GIB, 16 * GIB)
}

/// Assembles a level's bands into one material (levels before the last, and
/// [`crate::pipeline::upscale`], which returns the whole output).
pub struct Assembler {
    material: Option<Material>,
    height: usize,
}

impl Assembler {
    /// For an output `height` rows tall.
    pub fn new(height: usize) -> Assembler {
        Assembler {
            material: None,
            height,
        }
    }

    /// Copies `band`, the output's rows from `first` on, into place.
    pub fn add(&mut self, first: usize, band: &Material) {
        let height = self.height;
        let whole = self.material.get_or_insert_with(|| {
            band.map_maps(|m| Map::filled(m.width(), height, m.channels(), 0.0))
        });
        for (into, from) in whole.maps_mut().zip(band.maps()) {
            into.paste_rows(first, from);
        }
    }

    /// The assembled material (`None` before any band).
    pub fn finish(self) -> Option<Material> {
        self.material
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reads(plan: &BandPlan) -> Vec<(usize, usize, isize, usize)> {
        plan.bands()
            .map(|b| (b.first, b.rows, b.read_first, b.read_rows))
            .collect()
    }

    #[test]
    fn bands_cover_every_row_once_with_their_context() {
        // Mirror: no context beyond the edges; the first and last bands keep those rows.
        let mirrored = BandPlan::greedy(10, 8, 2, Border::Mirror);
        assert_eq!(reads(&mirrored), [(0, 6, 0, 8), (6, 4, 4, 6)]);
        let wrapped = BandPlan::greedy(10, 8, 2, Border::Wrap);
        assert_eq!(reads(&wrapped), [(0, 4, -2, 8), (4, 4, 2, 8), (8, 2, 6, 6)]);
        // One band reads the rows as they are, even when tileable.
        assert_eq!(reads(&BandPlan::whole(10)), [(0, 10, 0, 10)]);
    }

    #[test]
    fn a_band_reads_wrapped_rows_and_keeps_its_own() {
        let m = Map::from_fn(3, 10, 2, |c, y, x| (c * 100 + y * 10 + x) as f32);
        let band = BandPlan::greedy(10, 8, 2, Border::Wrap)
            .bands()
            .next()
            .unwrap();
        let read = band.read(&m);
        let first_column: Vec<f32> = (0..read.height()).map(|y| read.get(1, y, 0)).collect();
        assert_eq!(
            first_column,
            [180.0, 190.0, 100.0, 110.0, 120.0, 130.0, 140.0, 150.0]
        );
        // Upsampled ×2 (row y of the read rows → rows 2y, 2y + 1), the kept rows are the
        // band's own.
        let material = Material::uniform(1, [0.0; 3], 0.5, 0.0);
        let mut out =
            OutputBand::from(material.map_maps(|_| Map::from_fn(6, 16, 1, |_, y, _| y as f32)));
        band.keep(&mut out, 2).unwrap();
        let material = out.to_material().unwrap();
        assert_eq!(material.roughness.height(), 8);
        assert_eq!(material.roughness.get(0, 0, 0), 4.0);
        assert_eq!(material.roughness.get(0, 7, 5), 11.0);
    }

    #[test]
    fn the_plan_fits_the_limit_or_says_why_not() {
        let mib = 1u64 << 20;
        let plan = |tile, border, limit, per_texel| {
            plan_bands(512, 512, 4, 30, tile, border, limit, per_texel)
        };
        // No limit, or a generous one: one band.
        assert!(plan(None, Border::Wrap, None, BYTES_PER_BAND_TEXEL)
            .unwrap()
            .is_whole());
        assert!(
            plan(None, Border::Wrap, Some(4096 * mib), BYTES_PER_BAND_TEXEL)
                .unwrap()
                .is_whole()
        );
        let fixed = BYTES_PER_LR_TEXEL * 512 * 512;
        for per_texel in [
            BYTES_PER_BAND_TEXEL,
            BYTES_PER_BAND_TEXEL + ENSEMBLE_BYTES_PER_BAND_TEXEL,
        ] {
            let band_bytes = |read: usize| per_texel * 16 * 512 * read as u64;
            for border in [Border::Wrap, Border::Mirror] {
                for tile in [None, Some(128)] {
                    let p = plan(tile, border, Some(200 * mib), per_texel).unwrap();
                    assert!(p.count() > 1, "{p:?}");
                    let mut next = 0;
                    for (i, band) in p.bands().enumerate() {
                        assert_eq!(band.first, next, "{p:?}");
                        next += band.rows;
                        assert!(fixed + band_bytes(band.read_rows) <= 200 * mib, "{p:?}");
                        // Every band but the last reads whole tiles.
                        if let (Some(t), true) = (tile, i + 1 < p.count()) {
                            assert_eq!(band.read_rows % t, 0, "{p:?}");
                        }
                    }
                    assert_eq!(next, 512);
                }
            }
        }
        // A self-ensemble's bytes make the bands narrower.
        let rows = |per_texel| {
            let p = plan(None, Border::Mirror, Some(200 * mib), per_texel).unwrap();
            p.bands().map(|b| b.read_rows).max().unwrap()
        };
        assert!(
            rows(BYTES_PER_BAND_TEXEL + ENSEMBLE_BYTES_PER_BAND_TEXEL) < rows(BYTES_PER_BAND_TEXEL)
        );
        let error = plan(None, Border::Wrap, Some(40 * mib), BYTES_PER_BAND_TEXEL).unwrap_err();
        assert!(error.to_string().contains("40 MiB"), "{error}");
    }

    #[test]
    fn assembled_bands_give_back_the_whole() {
        let whole = Material::uniform(1, [0.0; 3], 0.5, 0.0)
            .map_maps(|_| Map::from_fn(5, 12, 1, |_, y, x| (y * 5 + x) as f32));
        let mut assembler = Assembler::new(12);
        for (first, rows) in [(0, 5), (5, 5), (10, 2)] {
            assembler.add(first, &whole.map_maps(|m| m.rows(first, rows)));
        }
        assert!(assembler.finish().unwrap() == whole);
    }
}
