//! Height from normals (METHOD.md): integrate the slope field with a Poisson solve, keep its
//! high-pass part, scale it to the height map's units, and add it to the upsampled LR height.

use rayon::prelude::*;
use rustdct::DctPlanner;
use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

use matup_core::map::Map;
use matup_core::resample::{gaussian_blur, upsample, Border, Kernel};

/// Integrates unit normals (3 channels, geometry frame) into a height field in the units of
/// the material's square ([−1, 1]² spans the map), least-squares, mean zero. Periodic for
/// tileable maps; otherwise Neumann, by solving on the mirrored (even) extension.
pub fn integrate_normals(normal: &Map, tileable: bool) -> Map {
    integrate_over(normal, tileable, [normal.width(), normal.height()])
}

/// [`integrate_normals`] for a part of a map of `size` texels, in that map's units.
fn integrate_over(normal: &Map, tileable: bool, size: [usize; 2]) -> Map {
    let (w, h) = (normal.width(), normal.height());
    let (dx, dy) = (2.0 / size[0] as f64, 2.0 / size[1] as f64);
    // Surface slopes ∂z/∂x = −nx/nz, ∂z/∂y = −ny/nz, in height per texel.
    let slopes = |x: usize, y: usize| {
        let i = y * w + x;
        let nz = (normal.plane(2)[i] as f64).max(0.05);
        let slope = |c: usize| -(normal.plane(c)[i] as f64) / nz;
        (slope(0) * dx, slope(1) * dy)
    };
    let height = if tileable {
        solve_periodic(slopes, w, h)
    } else {
        solve_neumann(slopes, w, h)
    };
    let mean = height.iter().sum::<f64>() / height.len() as f64;
    Map::from_planar(w, h, 1, height.iter().map(|v| (v - mean) as f32).collect())
}

/// Least-squares integration of periodic slopes `slopes(x, y) = (gx, gy)` on a `w × h` grid
/// (centred differences, which the half-texel averaging of forward differences reduces to):
/// `ĥ = −i(sin ωx Ĝx + sin ωy Ĝy) / (4 sin²(ωx/2) + 4 sin²(ωy/2))`.
///
/// Both slope fields are real, so one complex transform carries them: with `z = gx + i·gy`,
/// `Ĝx(k) = (Ẑ(k) + conj Ẑ(−k)) / 2` and `Ĝy(k) = (Ẑ(k) − conj Ẑ(−k)) / 2i`, and the solution
/// is written over `Ẑ` a pair of frequencies (k, −k) at a time: one buffer instead of three.
fn solve_periodic(
    slopes: impl Fn(usize, usize) -> (f64, f64) + Sync,
    w: usize,
    h: usize,
) -> Vec<f64> {
    let mut planner = FftPlanner::<f64>::new();
    let mut z: Vec<Complex<f64>> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            let (gx, gy) = slopes(i % w, i / w);
            Complex::new(gx, gy)
        })
        .collect();
    fft2(&mut planner, &mut z, w, h, false);
    let tau = std::f64::consts::TAU;
    let (along_x, along_y) = (sines(w, tau), sines(h, tau));
    let solution = |gx: Complex<f64>, gy: Complex<f64>, u: usize, v: usize| {
        let ((sin_x, sq_x), (sin_y, sq_y)) = (along_x[u], along_y[v]);
        let denom = sq_x + sq_y;
        if denom < 1e-12 {
            return Complex::new(0.0, 0.0); // the mean is free
        }
        let num = gx * sin_x + gy * sin_y;
        Complex::new(num.im, -num.re) / denom // −i·num
    };
    for v in 0..h {
        let v_neg = (h - v) % h;
        for u in 0..w {
            let u_neg = (w - u) % w;
            let (i, j) = (v * w + u, v_neg * w + u_neg);
            if j < i {
                continue; // solved with its partner
            }
            let (zi, zj) = (z[i], z[j]);
            let gx = (zi + zj.conj()) * 0.5;
            let gy = (zi - zj.conj()) * Complex::new(0.0, -0.5);
            z[i] = solution(gx, gy, u, v);
            z[j] = solution(gx.conj(), gy.conj(), u_neg, v_neg);
        }
    }
    fft2(&mut planner, &mut z, w, h, true);
    let norm = 1.0 / (w * h) as f64; // rustfft does not normalise
    z.par_iter().map(|c| c.re * norm).collect()
}

/// The same least-squares integration with Neumann borders: the periodic solve of the even
/// (half-sample) mirror of the height over a `2w × 2h` grid, where `gx` is odd across vertical
/// mirrors and `gy` across horizontal ones, done with real transforms on the `w × h` grid
/// alone. Mirrored sequences have spectra of cosines (even) and sines (odd), so with `Gx` the
/// DST-II along x and DCT-II along y of `gx`, `Gy` the DCT-II along x and DST-II along y of
/// `gy`, the height's 2-D DCT-II is `H(k, l) = −(sin(πk/w) Gx(k, l) + sin(πl/h) Gy(k, l)) /
/// (4 sin²(πk/2w) + 4 sin²(πl/2h))`, inverted by DCT-III. Two real buffers the size of the map,
/// where solving the mirror itself took a complex one of four times its area: at 8K², 1.1 GB
/// instead of 4.3 GB.
fn solve_neumann(
    slopes: impl Fn(usize, usize) -> (f64, f64) + Sync,
    w: usize,
    h: usize,
) -> Vec<f64> {
    let mut planner = DctPlanner::<f64>::new();
    let (along_x, along_y) = (planner.plan_dct2(w), planner.plan_dct2(h));
    let (mut gx, mut gy) = (vec![0f64; w * h], vec![0f64; w * h]);
    (gx.par_chunks_mut(w).zip(gy.par_chunks_mut(w)))
        .enumerate()
        .for_each(|(y, (gx, gy))| {
            for x in 0..w {
                (gx[x], gy[x]) = slopes(x, y);
            }
        });
    gx.par_chunks_mut(w)
        .for_each(|row| along_x.process_dst2(row));
    gy.par_chunks_mut(w)
        .for_each(|row| along_x.process_dct2(row));
    for_each_column(&mut gx, w, h, |column| along_y.process_dct2(column));
    for_each_column(&mut gy, w, h, |column| along_y.process_dst2(column));
    let pi = std::f64::consts::PI;
    let (freq_x, freq_y) = (sines(w, pi), sines(h, pi));
    // DST-II's output k holds frequency k + 1. H is written over Gx from the highest k down,
    // so each Gx(k − 1) is read before it is overwritten; rows are independent.
    gx.par_chunks_mut(w).enumerate().for_each(|(l, row)| {
        let (sin_y, sq_y) = freq_y[l];
        for k in (0..w).rev() {
            let (sin_x, sq_x) = freq_x[k];
            let denom = sq_x + sq_y;
            let across = if k > 0 { row[k - 1] } else { 0.0 };
            let down = if l > 0 { gy[(l - 1) * w + k] } else { 0.0 };
            let num = sin_x * across + sin_y * down;
            row[k] = if denom < 1e-12 { 0.0 } else { -num / denom }; // the mean is free
        }
    });
    drop(gy);
    gx.par_chunks_mut(w)
        .for_each(|row| along_x.process_dct3(row));
    for_each_column(&mut gx, w, h, |column| along_y.process_dct3(column));
    let norm = 4.0 / (w * h) as f64; // DCT-III inverts DCT-II up to 2/n along each axis
    gx.par_iter_mut().for_each(|v| *v *= norm);
    gx
}

/// Per frequency k of an axis of `n` texels, with ω = `period`·k/n: (sin ω, 4 sin²(ω/2)), the
/// factors of the Poisson solve's spectral division, tabulated rather than computed twice
/// a texel.
fn sines(n: usize, period: f64) -> Vec<(f64, f64)> {
    (0..n)
        .map(|k| {
            let omega = period * k as f64 / n as f64;
            (omega.sin(), 4.0 * (omega / 2.0).sin().powi(2))
        })
        .collect()
}

/// Runs `f` on each column of a row-major `w × h` grid, in parallel: in rounds, each task
/// gathering a block of columns into a buffer of its own (a column's values contiguous) and
/// transforming them, then every row taking its values back. A round's buffers hold a few
/// columns per thread, not a transposed copy of the grid (at 16K², 4 GB of complex values).
fn for_each_column<T: Copy + Default + Send + Sync>(
    data: &mut [T],
    w: usize,
    h: usize,
    f: impl Fn(&mut [T]) + Sync,
) {
    const BLOCK: usize = 8;
    let round = BLOCK * 4 * rayon::current_num_threads().max(1);
    for first in (0..w).step_by(round) {
        let last = (first + round).min(w);
        let starts: Vec<usize> = (first..last).step_by(BLOCK).collect();
        let shared = &*data;
        let blocks: Vec<(usize, Vec<T>)> = starts
            .into_par_iter()
            .map(|x0| {
                let n = BLOCK.min(last - x0);
                let mut buffer = vec![T::default(); n * h];
                for y in 0..h {
                    for i in 0..n {
                        buffer[i * h + y] = shared[y * w + x0 + i];
                    }
                }
                buffer.chunks_mut(h).for_each(&f);
                (x0, buffer)
            })
            .collect();
        data.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
            for (x0, buffer) in &blocks {
                for (i, column) in buffer.chunks(h).enumerate() {
                    row[x0 + i] = column[y];
                }
            }
        });
    }
}

fn fft2(
    planner: &mut FftPlanner<f64>,
    data: &mut [Complex<f64>],
    w: usize,
    h: usize,
    inverse: bool,
) {
    let row = if inverse {
        planner.plan_fft_inverse(w)
    } else {
        planner.plan_fft_forward(w)
    };
    data.par_chunks_mut(w).for_each(|r| row.process(r));
    let col = if inverse {
        planner.plan_fft_inverse(h)
    } else {
        planner.plan_fft_forward(h)
    };
    for_each_column(data, w, h, |column| col.process(column));
}

/// The detail of a 1-channel map above a Gaussian blur of width `sigma`.
fn high_pass(map: &Map, sigma: f32, border: Border) -> Map {
    let (w, h) = (map.width(), map.height());
    let low = gaussian_blur(map.data(), w, h, sigma, border);
    let detail = map.data().iter().zip(low).map(|(v, l)| v - l).collect();
    Map::from_planar(w, h, 1, detail)
}

/// The HR height: the upsampled LR height plus the high-pass detail of the integrated HR
/// normals, scaled to the height map's units by [`detail_scale`].
pub fn reconstruct_height(
    lr_height: &Map,
    lr_normal: &Map,
    hr_normal: &Map,
    scale: usize,
    tileable: bool,
) -> Map {
    let k = detail_scale(lr_height, lr_normal, tileable);
    rebuild_height(lr_height, hr_normal, k, scale, tileable, None)
}

/// The factor `k` that brings integrated normals to the height map's units: a least-squares
/// fit of the LR height's own high-pass against its LR normals' integral, `HP(h_LR) ≈ k ·
/// HP(∫ n_LR)`, at LR where both bands exist (0 when they do not agree).
pub fn detail_scale(lr_height: &Map, lr_normal: &Map, tileable: bool) -> f32 {
    let border = Border::for_tiling(tileable);
    let lr_detail = high_pass(&integrate_normals(lr_normal, tileable), 2.0, border);
    let lr_reference = high_pass(lr_height, 2.0, border);
    let (num, den) = lr_detail
        .data()
        .iter()
        .zip(lr_reference.data())
        .fold((0.0f64, 0.0f64), |(n, d), (a, b)| {
            (n + (*a as f64) * (*b as f64), d + (*a as f64).powi(2))
        });
    if den > 1e-20 {
        (num / den).max(0.0) as f32
    } else {
        0.0
    }
}

/// HR texels of context a band of rows needs around the rows it keeps for its height: the
/// integral of a band differs from the whole's by a harmonic function, which the high-pass
/// (a radially symmetric blur subtracted) removes but for what its edges leave, and those
/// fade over a few blur widths. 16 blur widths (σ = scale / 2) leave under 1/2¹⁶ of the
/// height's range (the band test in `tests/bands.rs`).
pub fn band_margin(scale: usize) -> usize {
    8 * scale
}

/// [`reconstruct_height`] with `k` given, for the whole map (`band: None`) or for a band of
/// rows of an output of `band = Some(size)`, read with [`band_margin`] rows of context (LR
/// height and HR normals, the band's rows alone). A band is integrated with Neumann borders;
/// a tileable band first gets `band_margin` columns wrapped around on each side, so its left
/// and right edges are as far from the kept texels as its top and bottom.
pub fn rebuild_height(
    lr_height: &Map,
    hr_normal: &Map,
    k: f32,
    scale: usize,
    tileable: bool,
    band: Option<[usize; 2]>,
) -> Map {
    let border = Border::for_tiling(tileable);
    // Detail above the LR band: subtract a blur about as wide as the upsampling factor.
    let sigma = scale as f32 / 2.0;
    let hr_detail = match band {
        None => high_pass(&integrate_normals(hr_normal, tileable), sigma, border),
        Some(size) if tileable => {
            let (w, m) = (hr_normal.width(), band_margin(scale).min(hr_normal.width()));
            let padded = Map::from_fn(w + 2 * m, hr_normal.height(), 3, |c, y, x| {
                hr_normal.get(c, y, (x + w - m) % w)
            });
            let integral = integrate_over(&padded, false, size);
            high_pass(&integral, sigma, Border::Mirror).crop(m, 0, w, hr_normal.height())
        }
        Some(size) => high_pass(&integrate_over(hr_normal, false, size), sigma, border),
    };
    let base = upsample(lr_height, scale, Kernel::Bilinear, border);
    Map::from_fn(base.width(), base.height(), 1, |_, y, x| {
        base.get(0, y, x) + k * hr_detail.get(0, y, x)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Normals of the surface z = f(x, y) on [−1, 1]².
    fn normals_of(w: usize, f_x: impl Fn(f64, f64) -> (f64, f64)) -> Map {
        let mut m = Map::filled(w, w, 3, 0.0);
        for i in 0..w {
            for j in 0..w {
                let (x, y) = (
                    2.0 * (j as f64 + 0.5) / w as f64 - 1.0,
                    2.0 * (i as f64 + 0.5) / w as f64 - 1.0,
                );
                let (zx, zy) = f_x(x, y);
                let len = (zx * zx + zy * zy + 1.0).sqrt();
                m.set(0, i, j, (-zx / len) as f32);
                m.set(1, i, j, (-zy / len) as f32);
                m.set(2, i, j, (1.0 / len) as f32);
            }
        }
        m
    }

    fn rms_error_after_mean(a: &Map, want: impl Fn(f64, f64) -> f64) -> f64 {
        let w = a.width();
        let vals: Vec<(f64, f64)> = (0..w * w)
            .map(|k| {
                let (i, j) = (k / w, k % w);
                let (x, y) = (
                    2.0 * (j as f64 + 0.5) / w as f64 - 1.0,
                    2.0 * (i as f64 + 0.5) / w as f64 - 1.0,
                );
                (a.data()[k] as f64, want(x, y))
            })
            .collect();
        let ma = vals.iter().map(|v| v.0).sum::<f64>() / vals.len() as f64;
        let mw = vals.iter().map(|v| v.1).sum::<f64>() / vals.len() as f64;
        (vals
            .iter()
            .map(|(a, b)| ((a - ma) - (b - mw)).powi(2))
            .sum::<f64>()
            / vals.len() as f64)
            .sqrt()
    }

    #[test]
    fn periodic_surface_is_recovered() {
        let pi = std::f64::consts::PI;
        let z = |x: f64, y: f64| 0.05 * (pi * x).sin() * (2.0 * pi * y).cos();
        let n = normals_of(64, |x, y| {
            (
                0.05 * pi * (pi * x).cos() * (2.0 * pi * y).cos(),
                -0.1 * pi * (pi * x).sin() * (2.0 * pi * y).sin(),
            )
        });
        let h = integrate_normals(&n, true);
        let err = rms_error_after_mean(&h, z);
        assert!(err < 0.02 * 0.05, "rms {err}");
    }

    #[test]
    fn non_periodic_surface_is_recovered_with_neumann_borders() {
        // A tilted plane plus a bump: not periodic, the wrap-around would tear it.
        let z = |x: f64, y: f64| 0.1 * x + 0.05 * y + 0.03 * (-(x * x + y * y) * 4.0).exp();
        let n = normals_of(64, |x, y| {
            let e = 0.03 * (-(x * x + y * y) * 4.0).exp();
            (0.1 - 8.0 * x * e, 0.05 - 8.0 * y * e)
        });
        let h = integrate_normals(&n, false);
        let err = rms_error_after_mean(&h, z);
        assert!(err < 0.01 * 0.1, "rms {err}");
        // The periodic solve cannot represent the tilt.
        assert!(rms_error_after_mean(&integrate_normals(&n, true), z) > 5.0 * err);
    }
    #[test]
    fn both_solves_satisfy_their_equations() {
        // ĥ = −i(sin ωx Ĝx + sin ωy Ĝy) / (4 sin²(ωx/2) + 4 sin²(ωy/2)) is, in texel space,
        // the 5-point Laplacian of h equal to the centred divergence of g, for any slopes,
        // integrable or not. Periodic: neighbours wrap. Neumann: on the half-sample mirror, a
        // neighbour beyond an edge is the texel at the edge, and gx changes sign across
        // vertical edges, gy across horizontal ones. Odd and even sizes pair frequencies
        // differently.
        let g = |x: usize, y: usize| {
            let k = (x * 31 + y * 17) as f64;
            ((k * 0.37).sin(), (k * 0.91).cos())
        };
        for mirrored in [false, true] {
            for (w, h) in [(7, 6), (8, 5), (6, 6)] {
                let height = if mirrored {
                    solve_neumann(g, w, h)
                } else {
                    solve_periodic(g, w, h)
                };
                // The texel a neighbour index reads, and whether it lies beyond an edge.
                let texel = |i: isize, n: usize| {
                    let outside = i < 0 || i >= n as isize;
                    let index = match (mirrored, i < 0) {
                        (false, _) => i.rem_euclid(n as isize) as usize,
                        (true, true) => (-1 - i) as usize,
                        (true, false) if outside => 2 * n - 1 - i as usize,
                        (true, false) => i as usize,
                    };
                    (index, outside && mirrored)
                };
                let at = |x: isize, y: isize| height[texel(y, h).0 * w + texel(x, w).0];
                let slope = |x: isize, y: isize| {
                    let ((tx, flip_x), (ty, flip_y)) = (texel(x, w), texel(y, h));
                    let (gx, gy) = g(tx, ty);
                    let sign = |flip: bool| if flip { -1.0 } else { 1.0 };
                    (gx * sign(flip_x), gy * sign(flip_y))
                };
                for i in 0..w * h {
                    let (x, y) = ((i % w) as isize, (i / w) as isize);
                    let laplacian =
                        at(x + 1, y) + at(x - 1, y) + at(x, y + 1) + at(x, y - 1) - 4.0 * at(x, y);
                    let divergence = (slope(x + 1, y).0 - slope(x - 1, y).0) / 2.0
                        + (slope(x, y + 1).1 - slope(x, y - 1).1) / 2.0;
                    assert!(
                        (laplacian - divergence).abs() < 1e-9,
                        "mirrored {mirrored}, {w}×{h} at ({x}, {y}): {laplacian} against {divergence}"
                    );
                }
            }
        }
    }
}
