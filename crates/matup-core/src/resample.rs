//! Separable resampling kernels with border modes. One implementation serves the classical
//! upsampler plugins, the filter's bilinear input, supersampled renders and the baselines.

use std::fmt;
use std::str::FromStr;

use rayon::prelude::*;
use serde::Serialize;

use crate::map::{Dihedral, Map, PARALLEL_TEXELS};
use crate::{Error, Result};

/// What lies beyond an image's edge.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Border {
    /// The image repeats (tileable materials): the output of a tileable input is tileable.
    Wrap,
    /// The edge texel repeats.
    Clamp,
    /// The image is reflected about its edge (half-sample symmetric: …, 1, 0 | 0, 1, …).
    #[default]
    Mirror,
}

impl Border {
    /// Maps a possibly out-of-range index into `0..n`.
    #[inline]
    pub fn index(self, i: isize, n: usize) -> usize {
        let n = n as isize;
        match self {
            Border::Wrap => i.rem_euclid(n) as usize,
            Border::Clamp => i.clamp(0, n - 1) as usize,
            Border::Mirror => {
                let m = i.rem_euclid(2 * n);
                (if m >= n { 2 * n - 1 - m } else { m }) as usize
            }
        }
    }

    /// The border for a material: wrap when it tiles, mirror otherwise.
    pub fn for_tiling(tileable: bool) -> Border {
        if tileable {
            Border::Wrap
        } else {
            Border::Mirror
        }
    }
}

impl FromStr for Border {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "wrap" => Ok(Border::Wrap),
            "clamp" => Ok(Border::Clamp),
            "mirror" => Ok(Border::Mirror),
            _ => Err(Error::Invalid(format!(
                "unknown border '{s}'; use wrap, clamp or mirror"
            ))),
        }
    }
}

impl fmt::Display for Border {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Border::Wrap => "wrap",
            Border::Clamp => "clamp",
            Border::Mirror => "mirror",
        })
    }
}

/// A separable interpolation kernel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Kernel {
    /// Linear interpolation (the tent kernel).
    Bilinear,
    /// Keys' cubic convolution with parameter `a` (−0.5 reproduces quadratics).
    Bicubic { a: f32 },
    /// Windowed sinc with three lobes.
    Lanczos3,
}

/// A kernel's name, as configurations and the upsampler registry spell it.
impl fmt::Display for Kernel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Kernel::Bilinear => "bilinear",
            Kernel::Bicubic { .. } => "bicubic",
            Kernel::Lanczos3 => "lanczos3",
        })
    }
}

impl Kernel {
    /// Half-width of the kernel's support, in input texels.
    pub fn radius(self) -> f32 {
        match self {
            Kernel::Bilinear => 1.0,
            Kernel::Bicubic { .. } => 2.0,
            Kernel::Lanczos3 => 3.0,
        }
    }

    /// The kernel's weight at distance `x` (in input texels).
    pub fn weight(self, x: f32) -> f32 {
        let x = x.abs();
        match self {
            Kernel::Bilinear => (1.0 - x).max(0.0),
            Kernel::Bicubic { a } => {
                if x <= 1.0 {
                    ((a + 2.0) * x - (a + 3.0)) * x * x + 1.0
                } else if x < 2.0 {
                    ((a * x - 5.0 * a) * x + 8.0 * a) * x - 4.0 * a
                } else {
                    0.0
                }
            }
            Kernel::Lanczos3 => {
                if x < 1e-6 {
                    1.0
                } else if x < 3.0 {
                    let px = std::f32::consts::PI * x;
                    3.0 * px.sin() * (px / 3.0).sin() / (px * px)
                } else {
                    0.0
                }
            }
        }
    }

    /// Taps of each output phase for an integer upscale: output texel `o = i·scale + φ` sits at
    /// input coordinate `i + (φ + ½)/scale − ½`; `taps[φ]` lists (input offset from `i`,
    /// weight), weights normalised to sum to 1 so constants stay constant.
    pub fn phase_taps(self, scale: usize) -> Vec<Vec<(isize, f32)>> {
        let reach = self.radius().ceil() as isize + 1;
        (0..scale)
            .map(|phase| {
                let frac = (phase as f32 + 0.5) / scale as f32 - 0.5;
                normalised((-reach..=reach).map(|k| (k, self.weight(frac - k as f32))))
            })
            .collect()
    }
}

/// The non-zero taps of `taps`, their weights scaled to sum to 1 so constants stay constant.
fn normalised<T>(taps: impl Iterator<Item = (T, f32)>) -> Vec<(T, f32)> {
    let mut taps: Vec<(T, f32)> = taps.filter(|t| t.1 != 0.0).collect();
    let sum: f32 = taps.iter().map(|t| t.1).sum();
    taps.iter_mut().for_each(|t| t.1 /= sum);
    taps
}

/// Upsamples every channel of `map` by an integer `scale` (≥ 1) with `kernel`, reading
/// beyond the edges as `border` says. Texel centres are aligned (the output covers exactly
/// the same square as the input).
pub fn upsample(map: &Map, scale: usize, kernel: Kernel, border: Border) -> Map {
    assert!(scale >= 1, "upsample scale must be at least 1");
    if scale == 1 {
        return map.clone();
    }
    let taps = kernel.phase_taps(scale);
    let (w, h, channels) = (map.width(), map.height(), map.channels());
    let (ow, oh) = (w * scale, h * scale);
    let rows = rows_per_task(ow * scale);
    let mut out = vec![0f32; channels * oh * ow];
    out.par_chunks_mut(oh * ow)
        .zip(map.data().par_chunks(h * w))
        .for_each(|(out_plane, plane)| {
            out_plane
                .par_chunks_mut(rows * scale * ow)
                .enumerate()
                .for_each(|(task, chunk)| {
                    let mut out_rows = chunk.chunks_mut(ow);
                    let first = task * rows;
                    let lr_rows = first..(first + rows).min(h);
                    for_each_upsampled_row(
                        plane,
                        [w, h],
                        scale,
                        &taps,
                        border,
                        lr_rows,
                        |_, row| {
                            out_rows
                                .next()
                                .expect("a row per output row")
                                .copy_from_slice(row)
                        },
                    );
                });
        });
    Map::from_planar(ow, oh, channels, out)
}

/// Input rows a parallel task of [`for_each_upsampled_row`] takes, each `texels_per_row`
/// output texels: enough for a task to outweigh its scheduling, and at least 16, since each
/// task widens the kernel's reach of rows either side of its own again.
pub fn rows_per_task(texels_per_row: usize) -> usize {
    PARALLEL_TEXELS.div_ceil(texels_per_row.max(1)).max(16)
}

/// The output rows of the input rows `lr_rows` of a `w × h` plane upsampled by `scale` with
/// `taps` (a kernel's [`Kernel::phase_taps`]), top to bottom: `each(output_row, values)`.
/// What [`upsample`] computes, a few rows at a time, so that work on the output (a
/// back-projection's correction, say) need not hold it whole. Each input row is widened once
/// (along the row), then each output row mixes a few widened rows.
pub fn for_each_upsampled_row(
    plane: &[f32],
    [w, h]: [usize; 2],
    scale: usize,
    taps: &[Vec<(isize, f32)>],
    border: Border,
    lr_rows: std::ops::Range<usize>,
    mut each: impl FnMut(usize, &[f32]),
) {
    let ow = w * scale;
    let reach = taps.iter().flatten().map(|t| t.0.abs()).max().unwrap_or(0);
    let widen = |source: usize, out: &mut [f32]| {
        let row = &plane[source * w..][..w];
        for (i, texels) in out.chunks_exact_mut(scale).enumerate() {
            let i = i as isize;
            // Away from the edges the taps read the row directly (no border lookup).
            let inside = i >= reach && i + reach < w as isize;
            for (v, taps) in texels.iter_mut().zip(taps) {
                *v = if inside {
                    taps.iter().map(|&(k, wt)| wt * row[(i + k) as usize]).sum()
                } else {
                    taps.iter()
                        .map(|&(k, wt)| wt * row[border.index(i + k, w)])
                        .sum()
                };
            }
        }
    };
    // The widened rows of the input rows `i + k` that output rows of row `i` read, by `i + k`
    // (not yet wrapped by the border): a sliding window down the rows, whose rows leaving it
    // are reused.
    let mut widened: Vec<(isize, Vec<f32>)> = Vec::new();
    let mut spare: Vec<Vec<f32>> = Vec::new();
    let mut row = vec![0f32; ow];
    for i in lr_rows {
        let i = i as isize;
        let (kept, left): (Vec<_>, Vec<_>) = widened.drain(..).partition(|(j, _)| *j >= i - reach);
        spare.extend(left.into_iter().map(|(_, wide)| wide));
        widened = kept;
        for (phase, phase_taps) in taps.iter().enumerate() {
            let y = i as usize * scale + phase;
            row.fill(0.0);
            for &(k, wt) in phase_taps {
                let at = i + k;
                let slot = match widened.iter().position(|(j, _)| *j == at) {
                    Some(slot) => slot,
                    None => {
                        let mut wide = spare.pop().unwrap_or_else(|| vec![0f32; ow]);
                        widen(border.index(at, h), &mut wide);
                        widened.push((at, wide));
                        widened.len() - 1
                    }
                };
                let src = &widened[slot].1;
                row.iter_mut().zip(src).for_each(|(o, s)| *o += wt * s);
            }
            each(y, &row);
        }
    }
}

/// Averages `factor × factor` blocks (a box filter): how a lower-resolution capture, or an
/// anti-aliased render, sees the image. Width and height must be multiples of `factor`.
pub fn box_downsample(map: &Map, factor: usize) -> Map {
    box_downsample_channels(map, factor, 0..map.channels())
}

/// [`box_downsample`] of the planes in `channels` alone; the others come back zero (for
/// callers that correct a few planes of a many-planed map).
pub fn box_downsample_channels(map: &Map, factor: usize, channels: std::ops::Range<usize>) -> Map {
    assert!(
        map.width().is_multiple_of(factor) && map.height().is_multiple_of(factor),
        "box_downsample: {}×{} is not a multiple of {factor}",
        map.width(),
        map.height()
    );
    let (ow, oh) = (map.width() / factor, map.height() / factor);
    let norm = 1.0 / (factor * factor) as f32;
    let mut out = vec![0f32; map.channels() * oh * ow];
    out[channels.start * oh * ow..channels.end * oh * ow]
        .par_chunks_mut(ow)
        .enumerate()
        .for_each(|(r, row)| {
            let (c, y) = (channels.start + r / oh, r % oh);
            for (x, v) in row.iter_mut().enumerate() {
                let mut sum = 0.0;
                for dy in 0..factor {
                    for dx in 0..factor {
                        sum += map.get(c, y * factor + dy, x * factor + dx);
                    }
                }
                *v = sum * norm;
            }
        });
    Map::from_planar(ow, oh, map.channels(), out)
}

/// Each output texel's share of the input texels along one axis of `from` texels shrunk to
/// `to`: the input texels its footprint `[i·r, (i+1)·r)` covers (r = from / to), weighted by
/// how much of each it covers, normalised.
fn area_taps(from: usize, to: usize) -> Vec<Vec<(usize, f32)>> {
    let ratio = from as f64 / to as f64;
    (0..to)
        .map(|i| {
            let (start, end) = (i as f64 * ratio, (i + 1) as f64 * ratio);
            let first = start.floor() as usize;
            let last = (end.ceil() as usize).min(from);
            (first..last)
                .map(|k| {
                    let covered = end.min(k as f64 + 1.0) - start.max(k as f64);
                    (k, (covered / ratio) as f32)
                })
                .filter(|&(_, w)| w > 0.0)
                .collect()
        })
        .collect()
}

/// Each output texel's share of the input texels along one axis of `from` texels shrunk to
/// `to` by `kernel` stretched over the output texel's footprint (r = from / to input texels a
/// output texel), centres aligned, `border` read past the edges, weights normalised.
fn kernel_shrink_taps(
    from: usize,
    to: usize,
    kernel: Kernel,
    border: Border,
) -> Vec<Vec<(usize, f32)>> {
    let ratio = from as f64 / to as f64;
    let reach = (kernel.radius() as f64 * ratio).ceil() as isize;
    (0..to)
        .map(|i| {
            let centre = (i as f64 + 0.5) * ratio - 0.5;
            let reached = centre.floor() as isize - reach..=centre.ceil() as isize + reach;
            normalised(reached.map(|k| {
                let w = kernel.weight(((k as f64 - centre) / ratio) as f32);
                (border.index(k, from), w)
            }))
        })
        .collect()
}

/// How an image is shrunk to a smaller size.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shrink {
    /// Area averaging ([`area_resize`]).
    Area,
    /// A kernel stretched over each output texel's footprint (antialiased).
    Kernel(Kernel),
}

/// Shrinks `map` to `width × height` as `how` says, `border` read past the edges by a
/// kernel's reach (area averaging reads none). Neither side may grow.
pub fn shrink(map: &Map, width: usize, height: usize, how: Shrink, border: Border) -> Map {
    match how {
        Shrink::Area => area_resize(map, width, height),
        Shrink::Kernel(kernel) => {
            let taps = |from, to| kernel_shrink_taps(from, to, kernel, border);
            resize_by_taps(map, &taps(map.width(), width), &taps(map.height(), height))
        }
    }
}

/// Shrinks `map` to `width × height` by area averaging: each output texel is the mean of the
/// input it covers, fractions of texels weighted by their share (a box filter for whole
/// ratios, what a capture at the smaller size would see for any ratio). Neither side may grow.
pub fn area_resize(map: &Map, width: usize, height: usize) -> Map {
    assert!(
        (1..=map.width()).contains(&width) && (1..=map.height()).contains(&height),
        "area_resize shrinks: {}×{} to {width}×{height}",
        map.width(),
        map.height()
    );
    resize_by_taps(
        map,
        &area_taps(map.width(), width),
        &area_taps(map.height(), height),
    )
}

/// `map` resampled separably: output column i mixes input columns `columns[i]`, output row j
/// input rows `rows[j]`.
fn resize_by_taps(map: &Map, columns: &[Vec<(usize, f32)>], rows: &[Vec<(usize, f32)>]) -> Map {
    let (width, height) = (columns.len(), rows.len());
    let mut out = vec![0f32; map.channels() * height * width];
    out.par_chunks_mut(width).enumerate().for_each(|(r, row)| {
        let (c, y) = (r / height, r % height);
        let plane = map.plane(c);
        // The output row's footprint first (input rows weighted), then its columns.
        let mut line = vec![0f32; map.width()];
        for &(k, w) in &rows[y] {
            let input = &plane[k * map.width()..][..map.width()];
            line.iter_mut().zip(input).for_each(|(l, v)| *l += w * v);
        }
        for (v, taps) in row.iter_mut().zip(columns) {
            *v = taps.iter().map(|&(k, w)| w * line[k]).sum();
        }
    });
    Map::from_planar(width, height, map.channels(), out)
}

/// [`upsample`]'s weights along one axis of `n` texels as a dense `(n·scale) × n` matrix,
/// row-major, the border folded in: output texel `o` is row `o` times the input. A device
/// resamples with a matrix product ([`crate::device_maps::Separable`]).
pub fn upsample_matrix(n: usize, scale: usize, kernel: Kernel, border: Border) -> Vec<f32> {
    let taps = kernel.phase_taps(scale);
    let mut matrix = vec![0f32; n * scale * n];
    for i in 0..n {
        for (phase, taps) in taps.iter().enumerate() {
            let row = &mut matrix[(i * scale + phase) * n..][..n];
            for &(k, w) in taps {
                row[border.index(i as isize + k, n)] += w;
            }
        }
    }
    matrix
}

/// [`shrink`]'s weights along one axis of `from` texels shrunk to `to`, as a dense `to × from`
/// matrix, row-major (as [`upsample_matrix`]).
pub fn shrink_matrix(from: usize, to: usize, how: Shrink, border: Border) -> Vec<f32> {
    let taps = match how {
        Shrink::Area => area_taps(from, to),
        Shrink::Kernel(kernel) => kernel_shrink_taps(from, to, kernel, border),
    };
    let mut matrix = vec![0f32; to * from];
    for (row, taps) in matrix.chunks_exact_mut(from.max(1)).zip(&taps) {
        for &(k, w) in taps {
            row[k] += w;
        }
    }
    matrix
}

/// How far [`gaussian_blur`] and [`guided_blur`] of `sigma` reach each side: 3σ, in texels.
pub fn gaussian_radius(sigma: f32) -> usize {
    (3.0 * sigma).ceil() as usize
}

/// A Gaussian of `sigma` truncated at 3σ each side: its radius and its taps from −radius to
/// radius, not normalised.
fn gaussian_taps(sigma: f32) -> (isize, Vec<f32>) {
    let radius = gaussian_radius(sigma) as isize;
    let taps = (-radius..=radius)
        .map(|k| (-(k * k) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    (radius, taps)
}

/// Separable Gaussian blur of a `w × h` plane, truncated at 3σ each side, normalised, with
/// `border` beyond the edges. Both passes run as whole-row multiply-adds, which the compiler
/// vectorises.
pub fn gaussian_blur(plane: &[f32], w: usize, h: usize, sigma: f32, border: Border) -> Vec<f32> {
    let (radius, raw) = gaussian_taps(sigma);
    let sum: f32 = raw.iter().sum();
    let weights: Vec<f32> = raw.iter().map(|v| v / sum).collect();
    let r = radius as usize;
    // Along rows: each row padded by the border, then one shifted axpy per tap.
    let mut across = vec![0.0f32; w * h];
    across
        .par_chunks_mut(w)
        .zip(plane.par_chunks(w))
        .for_each(|(out, row)| {
            let padded: Vec<f32> = (0..w + 2 * r)
                .map(|i| row[border.index(i as isize - radius, w)])
                .collect();
            for (k, wt) in weights.iter().enumerate() {
                for (o, v) in out.iter_mut().zip(&padded[k..k + w]) {
                    *o += wt * v;
                }
            }
        });
    // Along columns: each output row is a weighted sum of whole input rows.
    let mut out = vec![0.0f32; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (k, wt) in weights.iter().enumerate() {
            let yy = border.index(y as isize + k as isize - radius, h);
            for (o, v) in row.iter_mut().zip(&across[yy * w..(yy + 1) * w]) {
                *o += wt * v;
            }
        }
    });
    out
}

/// [`gaussian_blur`] of `plane` that keeps to its `guide`'s edges (a joint bilateral filter,
/// separable: along rows, then along columns): each tap also weighted by
/// `exp(-(guide difference)² / 2 range²)`, so what lies across a step in the guide larger than
/// `range` is barely mixed in. Hand-written: the imaging crates blur an image by itself, not
/// one plane guided by another.
pub fn guided_blur(
    plane: &[f32],
    guide: &[f32],
    w: usize,
    h: usize,
    sigma: f32,
    range: f32,
    border: Border,
) -> Vec<f32> {
    let (radius, spatial) = gaussian_taps(sigma);
    let pass = |values: &[f32], along_rows: bool| -> Vec<f32> {
        let mut out = vec![0.0f32; w * h];
        out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x, o) in row.iter_mut().enumerate() {
                let here = guide[y * w + x];
                let (mut sum, mut weight) = (0.0f32, 0.0f32);
                for (k, s) in (-radius..=radius).zip(&spatial) {
                    let i = match along_rows {
                        true => y * w + border.index(x as isize + k, w),
                        false => border.index(y as isize + k, h) * w + x,
                    };
                    let d = (guide[i] - here) / range;
                    let wt = s * (-0.5 * d * d).exp();
                    sum += wt * values[i];
                    weight += wt;
                }
                *o = sum / weight;
            }
        });
        out
    };
    pass(&pass(plane, true), false)
}

/// The texel of a map `lr_width` wide under texel `hr_index` of its ×`scale` upsampling,
/// `hr_width` wide (both row-major).
#[inline]
pub fn lr_texel(hr_index: usize, hr_width: usize, scale: usize, lr_width: usize) -> usize {
    (hr_index / hr_width / scale) * lr_width + (hr_index % hr_width) / scale
}

/// The least and greatest of each component of `values` (row-major, `width` texels wide)
/// over each texel's 3×3 neighbourhood, rows and columns past the edge as `border` says: the
/// range an upsampled texel keeps to so that it invents nothing its input lacks around it.
pub fn neighbourhood_ranges<const N: usize>(
    values: &[[f32; N]],
    width: usize,
    border: Border,
) -> Vec<[[f32; 2]; N]> {
    let height = values.len() / width.max(1);
    (0..values.len())
        .map(|i| {
            let (y, x) = ((i / width) as isize, (i % width) as isize);
            let mut range = [[f32::INFINITY, f32::NEG_INFINITY]; N];
            for (dy, dx) in (0..9).map(|k| (k / 3 - 1, k % 3 - 1)) {
                let j = border.index(y + dy, height) * width + border.index(x + dx, width);
                for (r, v) in range.iter_mut().zip(values[j]) {
                    r[0] = r[0].min(v);
                    r[1] = r[1].max(v);
                }
            }
            range
        })
        .collect()
}

/// How well an image wraps around: the mean |difference| across the wrap-around edge over the
/// mean |difference| across interior edges at the same phase of a `period`-texel grid (≈ 1:
/// seamless; ≫ 1: a seam). The larger of the row and column ratios, over all channels
/// ([`seam_steps`] gives its two parts).
pub fn seam_ratio(map: &Map, period: usize) -> f32 {
    seam_steps(map, period).ratio() as f32
}

/// The two parts of a [`seam_ratio`] along the axis where it is larger.
///
/// An output upscaled ×s carries its input's texel grid: steps across the input's texel edges
/// (every s-th) are larger than those inside a texel. The wrap-around edge lies on that grid,
/// so it is compared with the interior steps every `period` = s texels; with `period` 1 (or one
/// that does not divide the side) it is compared with every interior step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct SeamSteps {
    /// The mean |difference| across the wrap-around edge.
    pub wrap: f64,
    /// The mean |difference| across the interior edges at the wrap-around edge's phase.
    pub interior: f64,
}

impl SeamSteps {
    /// `wrap` over `interior`: 1 where both are 0, infinite where only `interior` is.
    pub fn ratio(self) -> f64 {
        if self.interior > 1e-12 {
            self.wrap / self.interior
        } else if self.wrap <= 1e-12 {
            1.0
        } else {
            f64::INFINITY
        }
    }
}

/// The [`SeamSteps`] of `map` on a `period`-texel grid, along the axis whose ratio is larger.
pub fn seam_steps(map: &Map, period: usize) -> SeamSteps {
    // Along the rows of `m`: the step into row i from the one before it, wrapping at 0.
    let along_rows = |m: &Map| {
        let n = m.height();
        if n < 2 {
            return SeamSteps {
                wrap: 0.0,
                interior: 0.0,
            };
        }
        let period = if period > 1 && n.is_multiple_of(period) && n / period >= 2 {
            period
        } else {
            1
        };
        let step = |i: usize| row_difference(m, (i + n - 1) % n, i);
        let edges: Vec<usize> = (1..n / period).map(|k| k * period).collect();
        SeamSteps {
            wrap: step(0),
            interior: edges.iter().map(|&i| step(i)).sum::<f64>() / edges.len().max(1) as f64,
        }
    };
    let rows = along_rows(map);
    let columns = along_rows(&map.transformed(Dihedral::TRANSPOSE));
    if columns.ratio() > rows.ratio() {
        columns
    } else {
        rows
    }
}

/// The mean |difference| between rows `a` and `b` of `map`, over its columns and channels.
pub fn row_difference(map: &Map, a: usize, b: usize) -> f64 {
    let w = map.width();
    let mut sum = 0.0f64;
    for c in 0..map.channels() {
        let plane = map.plane(c);
        let (ra, rb) = (&plane[a * w..][..w], &plane[b * w..][..w]);
        sum += (ra.iter().zip(rb))
            .map(|(x, y)| (x - y).abs() as f64)
            .sum::<f64>();
    }
    sum / (w * map.channels()).max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    const KERNELS: [Kernel; 3] = [
        Kernel::Bilinear,
        Kernel::Bicubic { a: -0.5 },
        Kernel::Lanczos3,
    ];
    const BORDERS: [Border; 3] = [Border::Wrap, Border::Clamp, Border::Mirror];

    #[test]
    fn border_indices() {
        assert_eq!(Border::Wrap.index(-1, 4), 3);
        assert_eq!(Border::Wrap.index(5, 4), 1);
        assert_eq!(Border::Clamp.index(-3, 4), 0);
        assert_eq!(Border::Clamp.index(9, 4), 3);
        assert_eq!(Border::Mirror.index(-1, 4), 0);
        assert_eq!(Border::Mirror.index(-2, 4), 1);
        assert_eq!(Border::Mirror.index(4, 4), 3);
        assert_eq!(Border::Mirror.index(5, 4), 2);
    }

    #[test]
    fn constants_stay_constant() {
        let map = Map::filled(7, 5, 2, 0.37);
        for kernel in KERNELS {
            for border in BORDERS {
                for scale in [2, 3, 4] {
                    let up = upsample(&map, scale, kernel, border);
                    assert_eq!((up.width(), up.height()), (7 * scale, 5 * scale));
                    let worst = up
                        .data()
                        .iter()
                        .map(|v| (v - 0.37).abs())
                        .fold(0.0, f32::max);
                    assert!(worst < 1e-6, "{kernel:?} {border} ×{scale}: {worst}");
                }
            }
        }
    }

    #[test]
    fn upsampling_weighs_each_input_texel_by_the_kernel_along_both_axes() {
        // The definition, texel by texel, against the row-wise implementation: sizes below the
        // kernel's reach, odd ones, and more rows than one parallel task takes.
        for (w, h) in [(1, 3), (3, 2), (9, 41)] {
            let map = Map::from_fn(w, h, 2, |c, y, x| ((x * 7 + y * 3 + c * 5) % 11) as f32);
            for kernel in KERNELS {
                let taps = kernel.phase_taps(4);
                for border in BORDERS {
                    let up = upsample(&map, 4, kernel, border);
                    let mut worst = 0f32;
                    for (c, y, x) in every_texel(2, 4 * h, 4 * w) {
                        let (i, j) = ((y / 4) as isize, (x / 4) as isize);
                        let mut want = 0.0;
                        for &(ky, wy) in &taps[y % 4] {
                            for &(kx, wx) in &taps[x % 4] {
                                let (sy, sx) = (border.index(i + ky, h), border.index(j + kx, w));
                                want += wy * wx * map.get(c, sy, sx);
                            }
                        }
                        worst = worst.max((up.get(c, y, x) - want).abs());
                    }
                    assert!(worst < 1e-4, "{w}×{h} {kernel:?} {border}: {worst}");
                }
            }
        }
    }

    fn every_texel(a: usize, b: usize, c: usize) -> impl Iterator<Item = (usize, usize, usize)> {
        (0..a).flat_map(move |i| (0..b).flat_map(move |j| (0..c).map(move |k| (i, j, k))))
    }

    #[test]
    fn box_downsample_averages_blocks() {
        let map = Map::from_fn(4, 2, 1, |_, y, x| (y * 4 + x) as f32);
        let down = box_downsample(&map, 2);
        assert_eq!(down.data(), &[2.5, 4.5]);
    }

    #[test]
    fn box_downsample_of_some_channels_leaves_the_others_zero() {
        let map = Map::from_fn(4, 2, 3, |c, y, x| (c * 8 + y * 4 + x) as f32);
        let down = box_downsample_channels(&map, 2, 1..2);
        assert_eq!(down.data(), &[0.0, 0.0, 10.5, 12.5, 0.0, 0.0]);
        assert_eq!(down.plane(1), box_downsample(&map, 2).plane(1));
    }

    #[test]
    fn area_resize_averages_what_each_output_texel_covers() {
        // A whole ratio is the box filter.
        let map = Map::from_fn(12, 8, 2, |c, y, x| ((x * 5 + y * 3 + c) % 7) as f32);
        let (area, boxed) = (area_resize(&map, 6, 4), box_downsample(&map, 2));
        let worst =
            (area.data().iter().zip(boxed.data())).fold(0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst < 1e-5, "{worst}");
        // 4 → 3: output texel 1 covers two thirds of inputs 1 and 2, texel 0 input 0 and a third
        // of input 1.
        let row = Map::from_fn(4, 1, 1, |_, _, x| [0.0, 3.0, 6.0, 9.0][x]);
        let three = area_resize(&row, 3, 1);
        for (got, want) in three.data().iter().zip([0.75, 4.5, 8.25]) {
            assert!((got - want).abs() < 1e-5, "{:?}", three.data());
        }
        // The mean is kept at any ratio (every input texel is shared out whole).
        let odd = area_resize(&map, 5, 3);
        for c in 0..2 {
            let mean = |m: &Map| m.plane(c).iter().sum::<f32>() / m.plane(c).len() as f32;
            assert!((mean(&odd) - mean(&map)).abs() < 1e-4);
        }
    }

    #[test]
    fn kernel_shrinks_keep_constants_and_ramps() {
        let flat = Map::filled(12, 9, 2, 0.3);
        let ramp = Map::from_fn(16, 16, 1, |_, y, x| x as f32 + 2.0 * y as f32);
        for kernel in [Kernel::Lanczos3, Kernel::Bicubic { a: -0.5 }] {
            for border in [Border::Wrap, Border::Mirror] {
                let small = shrink(&flat, 9, 6, Shrink::Kernel(kernel), border);
                assert!(small.data().iter().all(|v| (v - 0.3).abs() < 1e-6));
            }
            // ÷2: output texel i sits at input 2i + ½, its taps symmetric about it, so a ramp
            // comes back on the ramp away from the borders.
            let half = shrink(&ramp, 8, 8, Shrink::Kernel(kernel), Border::Mirror);
            for (y, x) in [(3, 3), (4, 3), (3, 4), (4, 4)] {
                let want = (2 * x) as f32 + 0.5 + 2.0 * ((2 * y) as f32 + 0.5);
                assert!((half.get(0, y, x) - want).abs() < 1e-3, "{kernel:?}");
            }
        }
    }

    #[test]
    fn seam_ratio_sees_seams() {
        // A periodic triangle wave: every neighbour difference, across the edge too, is 1/8.
        let triangle = |i: usize| (i as f32 - 8.0).abs() / 8.0;
        let tileable = Map::from_fn(16, 16, 1, |_, y, x| triangle(x) + triangle(y));
        assert!((seam_ratio(&tileable, 1) - 1.0).abs() < 1e-5);
        let ramp = Map::from_fn(16, 16, 1, |_, _, x| x as f32);
        assert!(seam_ratio(&ramp, 1) > 10.0);
    }

    #[test]
    fn seam_ratio_compares_steps_at_the_grid_phase() {
        // A seamless ×4 output of a tileable input: steps of 1 across the input's texel edges
        // (every 4th, the wrap-around one too: a triangle wave of 8 texels) and 0 or 0.1 inside
        // a texel. Against every interior step the wrap-around one reads as a seam (1 over a
        // mean step of 0.28); at the grid's phase it is like the others.
        let texel = |x: usize| (x / 4).min(8 - x / 4) as f32 + [0.0, 0.1, 0.1, 0.0][x % 4];
        let grid = Map::from_fn(32, 32, 1, |_, y, x| texel(x) + texel(y));
        assert!(seam_ratio(&grid, 1) > 1.5, "{}", seam_ratio(&grid, 1));
        let phased = seam_ratio(&grid, 4);
        assert!((phased - 1.0).abs() < 0.2, "{phased}");
        // A real seam still stands out at the phase: the ramp's wrap step is 31 steps.
        let ramp = Map::from_fn(32, 32, 1, |_, _, x| x as f32);
        assert!(seam_ratio(&ramp, 4) > 10.0);
        // Its parts, from the columns (the rows do not vary): a wrap step of 31 over interior
        // steps of 1.
        let steps = seam_steps(&ramp, 4);
        assert_eq!((steps.wrap, steps.interior), (31.0, 1.0));
        assert_eq!(steps.ratio() as f32, seam_ratio(&ramp, 4));
    }

    #[test]
    fn a_guided_blur_is_a_gaussian_where_the_guide_is_flat_and_stops_at_its_edges() {
        let (w, h) = (32, 16);
        let noise: Vec<f32> = (0..w * h)
            .map(|i| ((i * 7919) % 13) as f32 / 13.0)
            .collect();
        let flat = vec![0.5; w * h];
        let guided = guided_blur(&noise, &flat, w, h, 2.0, 0.1, Border::Mirror);
        let plain = gaussian_blur(&noise, w, h, 2.0, Border::Mirror);
        let most = (guided.iter().zip(&plain))
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max);
        assert!(most < 1e-5, "{most}");
        // A correction of −0.2 left of a step from black to white in the guide: the plain blur
        // carries half of it across, the guided one almost none.
        let guide: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 16 { 0.9 } else { 0.0 })
            .collect();
        let step: Vec<f32> = (0..w * h)
            .map(|i| if i % w < 16 { -0.2 } else { 0.0 })
            .collect();
        let across = |blurred: &[f32]| blurred[8 * w + 16];
        let plain = gaussian_blur(&step, w, h, 4.0, Border::Mirror);
        let guided = guided_blur(&step, &guide, w, h, 4.0, 0.1, Border::Mirror);
        assert!(across(&plain) < -0.08, "{}", across(&plain));
        assert!(across(&guided).abs() < 1e-4, "{}", across(&guided));
        // Inside the corrected side, the correction holds.
        assert!(
            (guided[8 * w + 4] + 0.2).abs() < 1e-4,
            "{}",
            guided[8 * w + 4]
        );
    }
}
