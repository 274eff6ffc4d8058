//! Height from normals (METHOD.md): integrate the slope field with a Poisson solve, keep its
//! high-pass part, scale it to the height map's units, and add it to the upsampled LR height.

use rustfft::num_complex::Complex;
use rustfft::FftPlanner;

use matup_core::map::Map;
use matup_core::resample::{gaussian_blur, upsample, Border, Kernel};

/// Integrates unit normals (3 channels, geometry frame) into a height field in the units of
/// the material's square ([−1, 1]² spans the map), least-squares, mean zero. Periodic for
/// tileable maps; otherwise Neumann, by solving on the mirrored (even) extension.
pub fn integrate_normals(normal: &Map, tileable: bool) -> Map {
    let (w, h) = (normal.width(), normal.height());
    let (dx, dy) = (2.0 / w as f64, 2.0 / h as f64);
    // Surface slopes ∂z/∂x = −nx/nz, ∂z/∂y = −ny/nz, in height per texel.
    let slope = |c: usize, i: usize| {
        let nz = (normal.plane(2)[i] as f64).max(0.05);
        -(normal.plane(c)[i] as f64) / nz * if c == 0 { dx } else { dy }
    };
    let gx: Vec<f64> = (0..w * h).map(|i| slope(0, i)).collect();
    let gy: Vec<f64> = (0..w * h).map(|i| slope(1, i)).collect();
    let height = if tileable {
        solve_periodic(&gx, &gy, w, h)
    } else {
        // Even extension of the height: gx is odd across vertical mirrors, gy across
        // horizontal ones.
        let (w2, h2) = (2 * w, 2 * h);
        let mut ex = vec![0f64; w2 * h2];
        let mut ey = vec![0f64; w2 * h2];
        for y in 0..h2 {
            let (sy, fy) = if y < h { (y, 1.0) } else { (h2 - 1 - y, -1.0) };
            for x in 0..w2 {
                let (sx, fx) = if x < w { (x, 1.0) } else { (w2 - 1 - x, -1.0) };
                ex[y * w2 + x] = fx * gx[sy * w + sx];
                ey[y * w2 + x] = fy * gy[sy * w + sx];
            }
        }
        let full = solve_periodic(&ex, &ey, w2, h2);
        (0..h)
            .flat_map(|y| full[y * w2..y * w2 + w].to_vec())
            .collect()
    };
    let mean = height.iter().sum::<f64>() / height.len() as f64;
    Map::from_planar(w, h, 1, height.iter().map(|v| (v - mean) as f32).collect())
}

/// Least-squares integration of periodic slopes given per texel (centred differences, which
/// the half-texel averaging of forward differences reduces to): `ĥ = −i(sin ωx Ĝx + sin ωy Ĝy)
/// / (4 sin²(ωx/2) + 4 sin²(ωy/2))`.
fn solve_periodic(gx: &[f64], gy: &[f64], w: usize, h: usize) -> Vec<f64> {
    let mut planner = FftPlanner::<f64>::new();
    let mut fx: Vec<Complex<f64>> = gx.iter().map(|&v| Complex::new(v, 0.0)).collect();
    let mut fy: Vec<Complex<f64>> = gy.iter().map(|&v| Complex::new(v, 0.0)).collect();
    fft2(&mut planner, &mut fx, w, h, false);
    fft2(&mut planner, &mut fy, w, h, false);
    let tau = std::f64::consts::TAU;
    let mut out = vec![Complex::new(0.0, 0.0); w * h];
    for v in 0..h {
        let wy = tau * v as f64 / h as f64;
        for u in 0..w {
            let wx = tau * u as f64 / w as f64;
            let denom = 4.0 * ((wx / 2.0).sin().powi(2) + (wy / 2.0).sin().powi(2));
            if denom < 1e-12 {
                continue; // the mean is free
            }
            let i = v * w + u;
            let num = fx[i] * wx.sin() + fy[i] * wy.sin();
            out[i] = Complex::new(num.im, -num.re) / denom; // −i·num
        }
    }
    fft2(&mut planner, &mut out, w, h, true);
    let norm = 1.0 / (w * h) as f64; // rustfft does not normalise
    out.iter().map(|c| c.re * norm).collect()
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
    for r in data.chunks_mut(w) {
        row.process(r);
    }
    let col = if inverse {
        planner.plan_fft_inverse(h)
    } else {
        planner.plan_fft_forward(h)
    };
    let mut buffer = vec![Complex::new(0.0, 0.0); h];
    for x in 0..w {
        for y in 0..h {
            buffer[y] = data[y * w + x];
        }
        col.process(&mut buffer);
        for y in 0..h {
            data[y * w + x] = buffer[y];
        }
    }
}

/// The detail of a 1-channel map above a Gaussian blur of width `sigma`.
fn high_pass(map: &Map, sigma: f32, border: Border) -> Map {
    let (w, h) = (map.width(), map.height());
    let low = gaussian_blur(map.data(), w, h, sigma, border);
    let detail = map.data().iter().zip(low).map(|(v, l)| v - l).collect();
    Map::from_planar(w, h, 1, detail)
}

/// The HR height: the upsampled LR height plus the high-pass detail of the integrated HR
/// normals, scaled to the height map's units by a least-squares fit of the LR height's own
/// high-pass against its LR normals' integral (0 when they do not agree).
pub fn reconstruct_height(
    lr_height: &Map,
    lr_normal: &Map,
    hr_normal: &Map,
    scale: usize,
    tileable: bool,
) -> Map {
    let border = Border::for_tiling(tileable);
    // Units: fit k with HP(h_LR) ≈ k · HP(∫ n_LR) at LR, where both bands exist.
    let lr_detail = high_pass(&integrate_normals(lr_normal, tileable), 2.0, border);
    let lr_reference = high_pass(lr_height, 2.0, border);
    let (num, den) = lr_detail
        .data()
        .iter()
        .zip(lr_reference.data())
        .fold((0.0f64, 0.0f64), |(n, d), (a, b)| {
            (n + (*a as f64) * (*b as f64), d + (*a as f64).powi(2))
        });
    let k = if den > 1e-20 {
        (num / den).max(0.0) as f32
    } else {
        0.0
    };
    // Detail above the LR band: subtract a blur about as wide as the upsampling factor.
    let hr_detail = high_pass(
        &integrate_normals(hr_normal, tileable),
        scale as f32 / 2.0,
        border,
    );
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
}
