//! Outputs of any size in bounded memory: a level's output is made in bands of whole rows,
//! each from the LR rows it covers plus enough rows of context above and below that the
//! rows it keeps come out as the whole image's would (within the upsampler's own tiling
//! differences). Bands are full width, so every column sees the material's own border (wrap
//! or mirror) exactly; only the band's top and bottom need context: wrapped around for
//! tileable materials, and none beyond the material's edge otherwise (the band's mirror
//! border there is the whole image's).

use matup_core::map::Map;
use matup_core::material::Material;
use matup_core::resample::Border;
use matup_core::{Error, Result};

/// Heap bytes a band needs per output texel it makes, context rows included: the residual
/// base's 7 features, an upsampled map and the upsampler's accumulators, the 8 decoded maps,
/// and the height solve's two f64 buffers with its blurs (89 measured with `cargo bench
/// --bench memory`, 1K² → 4K² in 17 bands; README "Memory of large outputs").
pub const BYTES_PER_BAND_TEXEL: u64 = 96;

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
    pub fn keep(&self, out: &mut Material, scale: usize) {
        let skip = (self.first as isize - self.read_first) as usize * scale;
        let rows = self.rows * scale;
        out.base_color.keep_rows(skip, rows);
        out.normal.keep_rows(skip, rows);
        out.roughness.keep_rows(skip, rows);
        out.metallic.keep_rows(skip, rows);
        for map in [
            &mut out.height,
            &mut out.anisotropy,
            &mut out.anisotropy_angle,
        ]
        .into_iter()
        .flatten()
        {
            map.keep_rows(skip, rows);
        }
    }
}

/// How a level's LR rows are cut into bands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BandPlan {
    /// LR rows in all.
    pub height: usize,
    /// LR rows each band keeps (the last may keep fewer).
    pub rows: usize,
    /// LR rows of context read above and below a band.
    pub context: usize,
    pub border: Border,
}

impl BandPlan {
    /// The whole image as one band.
    pub fn whole(height: usize, border: Border) -> BandPlan {
        BandPlan {
            height,
            rows: height.max(1),
            context: 0,
            border,
        }
    }

    pub fn count(&self) -> usize {
        self.height.div_ceil(self.rows)
    }

    pub fn is_whole(&self) -> bool {
        self.count() <= 1
    }

    pub fn bands(&self) -> impl Iterator<Item = Band> + '_ {
        (0..self.height).step_by(self.rows).map(move |first| {
            let rows = self.rows.min(self.height - first);
            let (read_first, read_end) = if self.is_whole() {
                (0, self.height as isize)
            } else if self.border == Border::Wrap {
                let c = self.context as isize;
                (first as isize - c, (first + rows) as isize + c)
            } else {
                (
                    first.saturating_sub(self.context) as isize,
                    (first + rows + self.context).min(self.height) as isize,
                )
            };
            Band {
                first,
                rows,
                read_first,
                read_rows: (read_end - read_first) as usize,
            }
        })
    }
}

/// The bands for an LR input of `width × height` upsampled by `scale` within `limit` bytes
/// of heap (none: one band), each reading `context` LR rows beyond what it keeps, and as many
/// rows as a multiple of `tile` where one fits (the upsampler's tiles: a band of 133 rows
/// would run two rows of 128² tiles). One band when the whole fits; an error naming the limit
/// when not even [`MIN_BAND_ROWS`] rows do.
pub fn plan_bands(
    width: usize,
    height: usize,
    scale: usize,
    context: usize,
    tile: Option<usize>,
    border: Border,
    limit: Option<u64>,
) -> Result<BandPlan> {
    let whole = BandPlan::whole(height, border);
    let Some(limit) = limit else {
        return Ok(whole);
    };
    let s2 = (scale * scale) as u64;
    let fixed = BYTES_PER_LR_TEXEL * (width * height) as u64;
    let per_lr_row = BYTES_PER_BAND_TEXEL * s2 * width as u64;
    let rows_fitting = (limit.saturating_sub(fixed) / per_lr_row.max(1)) as usize;
    if rows_fitting >= height {
        return Ok(whole);
    }
    let aligned = |read: usize| match tile {
        Some(t) if t > 0 && read / t * t >= 2 * context + MIN_BAND_ROWS => read / t * t,
        _ => read,
    };
    let most = aligned(rows_fitting).saturating_sub(2 * context);
    if most < MIN_BAND_ROWS {
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
    // As few bands as fit, of even height (rounded up to whole tiles where that still fits):
    // no more memory than they need.
    let mut rows = height.div_ceil(height.div_ceil(most));
    if let Some(t) = tile.filter(|&t| t > 0) {
        let read = (rows + 2 * context).next_multiple_of(t);
        if read - 2 * context <= most {
            rows = read - 2 * context;
        }
    }
    Ok(BandPlan {
        height,
        rows,
        context,
        border,
    })
}

/// The default memory limit: a quarter of the machine's memory (Linux's `MemTotal`; 16 GiB
/// elsewhere), between 1 and 16 GiB. A share, not all: the machine runs other things; and
/// not less, because narrow bands repeat their context's work (README "Memory of large
/// outputs").
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
        whole.base_color.paste_rows(first, &band.base_color);
        whole.normal.paste_rows(first, &band.normal);
        whole.roughness.paste_rows(first, &band.roughness);
        whole.metallic.paste_rows(first, &band.metallic);
        for (into, from) in [
            (&mut whole.height, &band.height),
            (&mut whole.anisotropy, &band.anisotropy),
            (&mut whole.anisotropy_angle, &band.anisotropy_angle),
        ] {
            if let (Some(into), Some(from)) = (into.as_mut(), from.as_ref()) {
                into.paste_rows(first, from);
            }
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

    fn plan(height: usize, rows: usize, context: usize, border: Border) -> BandPlan {
        BandPlan {
            height,
            rows,
            context,
            border,
        }
    }

    #[test]
    fn bands_cover_every_row_once_with_their_context() {
        let bands: Vec<Band> = plan(10, 4, 2, Border::Mirror).bands().collect();
        let firsts: Vec<(usize, usize, isize, usize)> = bands
            .iter()
            .map(|b| (b.first, b.rows, b.read_first, b.read_rows))
            .collect();
        // Mirror: no context beyond the edges.
        assert_eq!(firsts, [(0, 4, 0, 6), (4, 4, 2, 8), (8, 2, 6, 4)]);
        let wrapped: Vec<(isize, usize)> = plan(10, 4, 2, Border::Wrap)
            .bands()
            .map(|b| (b.read_first, b.read_rows))
            .collect();
        assert_eq!(wrapped, [(-2, 8), (2, 8), (6, 6)]);
        // One band reads the rows as they are, even when tileable.
        let whole: Vec<Band> = BandPlan::whole(10, Border::Wrap).bands().collect();
        assert_eq!(whole.len(), 1);
        assert_eq!((whole[0].read_first, whole[0].read_rows), (0, 10));
    }

    #[test]
    fn a_band_reads_wrapped_rows_and_keeps_its_own() {
        let m = Map::from_fn(3, 10, 2, |c, y, x| (c * 100 + y * 10 + x) as f32);
        let band = plan(10, 4, 2, Border::Wrap).bands().next().unwrap();
        let read = band.read(&m);
        let first_column: Vec<f32> = (0..read.height()).map(|y| read.get(1, y, 0)).collect();
        assert_eq!(
            first_column,
            [180.0, 190.0, 100.0, 110.0, 120.0, 130.0, 140.0, 150.0]
        );
        // Upsampled ×2 (row y of the read rows → rows 2y, 2y + 1), the kept rows are the
        // band's own.
        let mut material = Material::uniform(1, [0.0; 3], 0.5, 0.0);
        material = material.map_maps(|_| Map::from_fn(6, 16, 1, |_, y, _| y as f32));
        band.keep(&mut material, 2);
        assert_eq!(material.roughness.height(), 8);
        assert_eq!(material.roughness.get(0, 0, 0), 4.0);
        assert_eq!(material.roughness.get(0, 7, 5), 11.0);
    }

    #[test]
    fn the_plan_fits_the_limit_or_says_why_not() {
        let mib = 1u64 << 20;
        // No limit, or a generous one: one band.
        assert!(plan_bands(512, 512, 4, 30, None, Border::Wrap, None)
            .unwrap()
            .is_whole());
        assert!(
            plan_bands(512, 512, 4, 30, None, Border::Wrap, Some(4096 * mib))
                .unwrap()
                .is_whole()
        );
        // 512 LR columns ×4: a row of bands costs 150 · 16 · 512 bytes = 1.17 MiB.
        let p = plan_bands(512, 512, 4, 30, None, Border::Wrap, Some(200 * mib)).unwrap();
        assert!(!p.is_whole());
        let fixed = BYTES_PER_LR_TEXEL * 512 * 512;
        let band = BYTES_PER_BAND_TEXEL * 16 * 512 * (p.rows + 2 * p.context) as u64;
        assert!(fixed + band <= 200 * mib, "{p:?}");
        // With 128-row tiles, the rows read are a multiple of them.
        let tiled = plan_bands(512, 512, 4, 30, Some(128), Border::Wrap, Some(200 * mib));
        let tiled = tiled.unwrap();
        assert_eq!((tiled.rows + 2 * tiled.context) % 128, 0, "{tiled:?}");
        assert!(tiled.rows <= p.rows);
        let error = plan_bands(512, 512, 4, 30, None, Border::Wrap, Some(40 * mib)).unwrap_err();
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
