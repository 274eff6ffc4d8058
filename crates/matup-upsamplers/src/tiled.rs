//! Tiled inference, for networks that run on pieces of an image: each image cut into tiles
//! read with context on every side (as the border says: wrapped for tileable materials),
//! several tiles a call, and the outputs blended with feathered weights where their kept
//! regions overlap, so memory stays bounded and no seam shows: on the host
//! ([`upsample_tiled`]), or on a device with the images and outputs kept there
//! ([`upsample_tiled_on_device`]). The ONNX networks and a caller's own function
//! ([`crate::function`]) share it.

use matup_core::candle_core::{self, Tensor};
use matup_core::resample::Border;
use matup_core::upsample::Watch;
use matup_core::{Map, Result};
use rayon::prelude::*;

/// Runs a network on a batch of tiles, each three planes (R, G, B) of `h × w` texels:
/// `run(tiles, [h, w])`, each tile's output a 3-channel map.
pub type RunTiles<'a> = dyn FnMut(&[Vec<f32>], [usize; 2]) -> Result<Vec<Map>> + 'a;

/// Output rows of one channel blended by one task.
const BLEND_ROWS: usize = 64;

/// Start of each tile along an axis of `len` texels, tiles of `tile` (the last one shifted
/// back to end at the edge).
pub(crate) fn tile_starts(len: usize, tile: usize) -> Vec<usize> {
    let tile = tile.min(len);
    let mut starts: Vec<usize> = (0..len.div_ceil(tile))
        .map(|k| (k * tile).min(len - tile))
        .collect();
    starts.dedup();
    starts
}

/// Feathering weight of an output texel at LR coordinate `u` (relative to the tile's core,
/// which spans [0, core)) with `margin` LR texels kept on each side: 1 inside the core,
/// falling linearly to near 0 at the kept region's edge.
fn feather(u: f32, core: f32, margin: f32) -> f32 {
    if margin <= 0.0 {
        return if (0.0..core).contains(&u) { 1.0 } else { 0.0 };
    }
    let d = (u + margin).min(core + margin - u);
    (d / margin).clamp(0.0, 1.0)
}

/// How tiles cover one axis of an image: cores of `core` LR texels, each read in a window of
/// `window` texels that starts `before` texels ahead of the core (the context).
#[derive(Clone, Copy, Debug)]
pub struct TileAxis {
    pub core: usize,
    pub before: usize,
    pub window: usize,
}

impl TileAxis {
    /// The tiling of an axis of `len` texels by a network that takes any size: as few tiles
    /// as `tile` allows, their cores evened out, each read with `overlap` texels of context
    /// on both sides. 840 texels in tiles of 256 run four cores of 210, not three of 256 and a
    /// fourth shifted back over the third (a band of rows of a larger output ends so, 12 %
    /// more work at 2K² → 8K² in 2 bands).
    pub fn even(len: usize, tile: usize, overlap: usize) -> TileAxis {
        let count = len.div_ceil(tile.max(1));
        let core = len.div_ceil(count.max(1));
        TileAxis {
            core,
            before: overlap,
            window: core + 2 * overlap,
        }
    }
}

/// Along one axis of a tile whose core starts at LR texel `origin`, keeping `margin` texels of
/// context on each side, the output texels that land in the image (`len` LR texels,
/// ×`scale`): a contiguous run of them, where it starts in the tile's output and in the
/// image's, and each texel's feathering weight.
fn kept_texels(origin: usize, axis: TileAxis, len: usize, margin: usize, scale: usize) -> Kept {
    let mut kept = Kept {
        in_tile: 0,
        in_image: 0,
        weights: Vec::new(),
    };
    for t in 0..axis.window * scale {
        // LR coordinate of this output texel relative to the tile's core.
        let u = (t as f32 + 0.5) / scale as f32 - axis.before as f32;
        let weight = feather(u, axis.core as f32, margin as f32);
        let global = (origin * scale + t) as isize - (axis.before * scale) as isize;
        if weight > 0.0 && global >= 0 && global < (len * scale) as isize {
            if kept.weights.is_empty() {
                (kept.in_tile, kept.in_image) = (t, global as usize);
            }
            kept.weights.push(weight);
        }
    }
    kept
}

/// One tile's output texels kept along an axis: `weights.len()` of them from `in_tile` in the
/// tile's output, landing from `in_image` in the image's.
pub(crate) struct Kept {
    pub(crate) in_tile: usize,
    pub(crate) in_image: usize,
    pub(crate) weights: Vec<f32>,
}

/// The kept texels of every tile along an axis (tiles starting at `starts`), each weight
/// divided by the sum of all tiles' weights at its texel. Tiles cover the image as a grid, so
/// a texel's 2-D weights sum to (sum over rows) × (sum over columns): with both axes
/// normalised, the tiles' weighted outputs add up to the blend with no division after, and
/// no image-sized plane of weights (it was a fourth stream of stores, 4 bytes an output texel).
pub(crate) fn blend_weights(
    starts: &[usize],
    axis: TileAxis,
    len: usize,
    margin: usize,
    scale: usize,
) -> Vec<Kept> {
    let mut kept: Vec<Kept> = (starts.iter())
        .map(|&origin| kept_texels(origin, axis, len, margin, scale))
        .collect();
    let mut total = vec![0f32; len * scale];
    for k in &kept {
        for (sum, w) in total[k.in_image..].iter_mut().zip(&k.weights) {
            *sum += w;
        }
    }
    for k in &mut kept {
        for (w, sum) in k.weights.iter_mut().zip(&total[k.in_image..]) {
            *w /= sum.max(1e-12);
        }
    }
    kept
}

/// How images of one size are cut into tiles: each axis's tiling, where its tiles start and the
/// output texels each keeps with their blending weights, and every tile of `images` images as
/// (image, row of tiles, column of tiles), row by row.
pub struct Tiling {
    pub(crate) rows: TileAxis,
    pub(crate) columns: TileAxis,
    pub(crate) row_starts: Vec<usize>,
    pub(crate) column_starts: Vec<usize>,
    pub(crate) kept_rows: Vec<Kept>,
    pub(crate) kept_columns: Vec<Kept>,
    pub(crate) grid: Vec<(usize, usize, usize)>,
    /// The upsampling factor of the network run on the tiles.
    pub(crate) scale: usize,
}

impl Tiling {
    /// Tiles of `images` images of `w × h`, cut along the rows and columns as `rows` and
    /// `columns` say, for a network upsampling ×`scale`. Tiles keep half their `overlap` of
    /// context, blended with their neighbours'.
    pub fn new(
        [w, h]: [usize; 2],
        images: usize,
        [rows, columns]: [TileAxis; 2],
        overlap: usize,
        scale: usize,
    ) -> Tiling {
        let margin = overlap / 2;
        let row_starts = tile_starts(h, rows.core);
        let column_starts = tile_starts(w, columns.core);
        let (n_rows, n_columns) = (row_starts.len(), column_starts.len());
        Tiling {
            kept_rows: blend_weights(&row_starts, rows, h, margin, scale),
            kept_columns: blend_weights(&column_starts, columns, w, margin, scale),
            rows,
            columns,
            row_starts,
            column_starts,
            grid: (0..images)
                .flat_map(|k| (0..n_rows).flat_map(move |i| (0..n_columns).map(move |j| (k, i, j))))
                .collect(),
            scale,
        }
    }
}

/// A call's pieces counted for its [`Watch`], out of a `total` known before the first.
pub struct PieceCount<'a> {
    watch: &'a dyn Watch,
    done: usize,
    total: usize,
}

impl<'a> PieceCount<'a> {
    pub fn new(watch: &'a dyn Watch, total: usize) -> PieceCount<'a> {
        PieceCount {
            watch,
            done: 0,
            total,
        }
    }

    /// `pieces` more are finished (a fixed batch's copies past the last are not counted);
    /// the watch's error stops the call.
    pub fn add(&mut self, pieces: usize) -> Result<()> {
        self.done = (self.done + pieces).min(self.total);
        self.watch.pieces_done(self.done, self.total)
    }
}

/// `images` grouped by size, each group handed to `run` (the indices of its images) and
/// its outputs put back in the images' order.
pub fn by_size<T>(
    images: &[Map],
    mut run: impl FnMut(&[usize]) -> Result<Vec<T>>,
) -> Result<Vec<T>> {
    let mut results: Vec<Option<T>> = (0..images.len()).map(|_| None).collect();
    let mut sizes: Vec<(usize, usize)> = images.iter().map(|m| (m.width(), m.height())).collect();
    sizes.sort_unstable();
    sizes.dedup();
    for (w, h) in sizes {
        let same: Vec<usize> = (0..images.len())
            .filter(|&k| (images[k].width(), images[k].height()) == (w, h))
            .collect();
        for (k, out) in same.iter().zip(run(&same)?) {
            results[*k] = Some(out);
        }
    }
    Ok(results
        .into_iter()
        .map(|m| m.expect("every size is run"))
        .collect())
}

/// `images`, all of one size, in tiles read with context as `border` says, several tiles a
/// call across all the images, blended with feathered weights; `watch` told after each call.
pub fn upsample_tiled(
    images: &[&Map],
    border: Border,
    tiling: Tiling,
    batch: usize,
    fixed_batch: bool,
    run: &mut RunTiles,
    watch: &dyn Watch,
) -> Result<Vec<Map>> {
    let s = tiling.scale;
    let (w, h) = (images[0].width(), images[0].height());
    let Tiling {
        rows,
        columns,
        row_starts,
        column_starts,
        kept_rows,
        kept_columns,
        grid,
        ..
    } = tiling;
    let (out_w, out_h) = (w * s, h * s);
    let mut accs = vec![vec![0f32; 3 * out_w * out_h]; images.len()];
    let mut count = PieceCount::new(watch, grid.len());
    for group in grid.chunks(batch) {
        let mut tiles: Vec<Vec<f32>> = group
            .iter()
            .map(|&(k, i, j)| {
                let (y0, x0) = (row_starts[i], column_starts[j]);
                let mut t = Vec::with_capacity(3 * rows.window * columns.window);
                for c in 0..3 {
                    for ty in 0..rows.window {
                        let y = border.index(y0 as isize + ty as isize - rows.before as isize, h);
                        for tx in 0..columns.window {
                            let x = border
                                .index(x0 as isize + tx as isize - columns.before as isize, w);
                            t.push(images[k].get(c, y, x));
                        }
                    }
                }
                t
            })
            .collect();
        if fixed_batch {
            // Fill the fixed batch with copies; their outputs are not used.
            let last = tiles.last().expect("chunks are not empty").clone();
            tiles.resize(batch, last);
        }
        let outputs = run(&tiles, [rows.window, columns.window])?;
        count.add(group.len())?;
        let mut in_group: Vec<usize> = group.iter().map(|t| t.0).collect();
        in_group.dedup();
        for k in in_group {
            let acc = &mut accs[k];
            // Each thread a run of rows of one channel: each tile's kept row is one
            // contiguous run of its plane. Writing the three planes and a weight plane at
            // once (each 256 MB apart at 8K²) cost 7.5× the time per texel at 8K² that it
            // did at 4K² (perf), 14 s of 2K² → 8K²'s 174.
            let planes = acc.par_chunks_mut((out_w * out_h).max(1)).enumerate();
            let chunks = planes.flat_map(|(c, plane)| {
                let runs = plane
                    .par_chunks_mut((out_w * BLEND_ROWS).max(1))
                    .enumerate();
                runs.map(move |(r, dst_rows)| (c, r * BLEND_ROWS, dst_rows))
            });
            chunks.for_each(|(c, first, dst_rows)| {
                let last = (first + BLEND_ROWS).min(out_h);
                for (&(_, i, j), out) in
                    (group.iter().zip(&outputs)).filter(|((image, _, _), _)| *image == k)
                {
                    let (rows, columns) = (&kept_rows[i], &kept_columns[j]);
                    let tile = out.plane(c);
                    for (dy, &wy) in rows.weights.iter().enumerate() {
                        let y = rows.in_image + dy;
                        if y < first || y >= last {
                            continue;
                        }
                        let from = (rows.in_tile + dy) * out.width() + columns.in_tile;
                        let to = (y - first) * out_w + columns.in_image;
                        let n = columns.weights.len();
                        let (src, dst) = (&tile[from..from + n], &mut dst_rows[to..to + n]);
                        for ((d, &v), &wx) in dst.iter_mut().zip(src).zip(&columns.weights) {
                            *d += wy * wx * v;
                        }
                    }
                }
            });
        }
    }
    Ok(accs
        .into_iter()
        .map(|acc| Map::from_planar(out_w, out_h, 3, acc))
        .collect())
}

/// Runs a network on a batch of tile windows on a device, `[n, 3, h, w]` in, the outputs
/// `[n, 3, h·scale, w·scale]` in [0, 1] out.
pub type RunTilesOnDevice<'a> = dyn FnMut(Tensor) -> candle_core::Result<Tensor> + 'a;

/// [`upsample_tiled`] on a device: `uploaded` (`[images, 3, h, w]`, already in the network's
/// range and order) stays there; the tiles' windows are cut, run `batch` a call (filled to
/// `fixed_batch` with copies where the network fixes it), weighted and blended along each
/// row of tiles there, and each finished row of tiles is added into its output there. The
/// outputs, `[3, h·scale, w·scale]` each, stay on the device.
pub fn upsample_tiled_on_device(
    uploaded: &Tensor,
    border: Border,
    tiling: Tiling,
    batch: usize,
    fixed_batch: Option<usize>,
    run: &mut RunTilesOnDevice,
) -> candle_core::Result<Vec<Tensor>> {
    let s = tiling.scale;
    let (images, _, h, w) = uploaded.dims4()?;
    let device = uploaded.device();
    let Tiling {
        rows,
        columns,
        row_starts,
        column_starts,
        kept_rows,
        kept_columns,
        grid,
        ..
    } = tiling;
    // Each tile's window as indices into the image (the border decides beyond its edges).
    let window = |start: usize, axis: TileAxis, len: usize| {
        let at = |t: usize| border.index(start as isize + t as isize - axis.before as isize, len);
        let indices: Vec<u32> = (0..axis.window).map(|t| at(t) as u32).collect();
        Tensor::from_vec(indices, axis.window, device)
    };
    let row_windows = (row_starts.iter().map(|&y| window(y, rows, h)))
        .collect::<candle_core::Result<Vec<_>>>()?;
    let column_windows = (column_starts.iter().map(|&x| window(x, columns, w)))
        .collect::<candle_core::Result<Vec<_>>>()?;
    let weights =
        |k: &Kept, shape: (usize, usize, usize)| Tensor::from_slice(&k.weights, shape, device);
    let row_weights = (kept_rows
        .iter()
        .map(|k| weights(k, (1, k.weights.len(), 1))))
    .collect::<candle_core::Result<Vec<_>>>()?;
    let column_weights = (kept_columns
        .iter()
        .map(|k| weights(k, (1, 1, k.weights.len()))))
    .collect::<candle_core::Result<Vec<_>>>()?;

    let (out_w, out_h) = (w * s, h * s);
    let outputs = (0..images)
        .map(|_| Tensor::zeros((3, out_h, out_w), candle_core::DType::F32, device))
        .collect::<candle_core::Result<Vec<_>>>()?;
    // The row of tiles being blended: (image, row of tiles) and its [3, rows, out_w] sum.
    let mut strip: Option<((usize, usize), Tensor)> = None;
    let finish = |strip: Option<((usize, usize), Tensor)>| -> candle_core::Result<()> {
        let Some(((k, i), sum)) = strip else {
            return Ok(());
        };
        let kept = &kept_rows[i];
        let (to, n) = (kept.in_image, kept.weights.len());
        let blended = (outputs[k].narrow(1, to, n)? + sum)?.contiguous()?;
        outputs[k].slice_set(&blended, 1, to)
    };
    for group in grid.chunks(batch) {
        let mut windows = (group.iter())
            .map(|&(k, i, j)| {
                uploaded
                    .narrow(0, k, 1)?
                    .index_select(&row_windows[i], 2)?
                    .index_select(&column_windows[j], 3)
            })
            .collect::<candle_core::Result<Vec<_>>>()?;
        if let Some(fixed) = fixed_batch {
            // Fill the fixed batch with copies; their outputs are not used.
            let last = windows.last().expect("chunks are not empty").clone();
            windows.resize(fixed, last);
        }
        let out = run(Tensor::cat(&windows, 0)?)?;
        for (b, &(k, i, j)) in group.iter().enumerate() {
            let (kr, kc) = (&kept_rows[i], &kept_columns[j]);
            let tile = out
                .get(b)?
                .narrow(1, kr.in_tile, kr.weights.len())?
                .narrow(2, kc.in_tile, kc.weights.len())?
                .broadcast_mul(&row_weights[i])?
                .broadcast_mul(&column_weights[j])?;
            let right = out_w - kc.in_image - kc.weights.len();
            let tile = tile.pad_with_zeros(2, kc.in_image, right)?;
            strip = match strip.take() {
                Some((at, sum)) if at == (k, i) => Some((at, (sum + tile)?)),
                done => {
                    finish(done)?;
                    Some(((k, i), tile))
                }
            };
        }
    }
    finish(strip)?;
    Ok(outputs)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blend_weights_sum_to_one_at_every_output_texel() {
        // 100 LR texels in cores of 24 (the last shifted back to the edge) with 22 of context,
        // half of it kept and feathered; one tile covering all; no context.
        for (len, core, overlap, scale) in [(100, 24, 22, 4), (100, 100, 22, 2), (50, 16, 0, 4)] {
            let axis = TileAxis {
                core,
                before: overlap,
                window: core + 2 * overlap,
            };
            let starts = tile_starts(len, core);
            let kept = blend_weights(&starts, axis, len, overlap / 2, scale);
            let mut sums = vec![0f32; len * scale];
            for k in &kept {
                assert!(k.in_tile + k.weights.len() <= axis.window * scale);
                for (s, w) in sums[k.in_image..].iter_mut().zip(&k.weights) {
                    *s += w;
                }
            }
            let worst = sums.iter().map(|s| (s - 1.0).abs()).fold(0.0, f32::max);
            assert!(worst < 1e-6, "{len}, {core}, {overlap}: off by {worst}");
        }
    }
}
