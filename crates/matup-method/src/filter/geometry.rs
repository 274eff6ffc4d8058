//! Where an output texel's input window comes from. The window is an N×N patch of the LR
//! features upsampled by a fixed kernel, so it is a fixed linear map of a K×K patch of the LR
//! features themselves, one map per sub-pixel phase (METHOD.md's folding idea): the filter
//! reads K×K×C LR values instead of N×N×C upsampled ones.

use matup_core::map::Map;
use matup_core::resample::{Border, Kernel};

/// The LR rows (or columns) one axis of a window reads, per phase.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisTaps {
    /// Offset of the first of the K LR rows from `I div scale`, per phase.
    pub start: Vec<isize>,
    /// Per phase, the nonzero weights as (window row d in 0..N, LR row a in 0..K, weight).
    pub weights: Vec<Vec<(usize, usize, f32)>>,
}

/// The geometry of the filter's input window at one scale.
#[derive(Clone, Debug, PartialEq)]
pub struct WindowGeometry {
    pub scale: usize,
    /// N: window side in output texels (odd).
    pub window: usize,
    /// K: LR texels per axis that any phase's window touches.
    pub taps: usize,
    /// The upsampling kernel the window is read through.
    pub kernel: Kernel,
    pub axis: AxisTaps,
}

impl WindowGeometry {
    pub fn new(scale: usize, window: usize, kernel: Kernel) -> Self {
        let phase_taps = kernel.phase_taps(scale);
        let radius = (window / 2) as isize;
        let s = scale as isize;
        let mut start = Vec::with_capacity(scale);
        let mut per_phase = Vec::with_capacity(scale);
        for phase in 0..scale {
            // Window row d sits at output row I + d − radius; I = s·i0 + phase.
            let mut entries = Vec::new();
            for d in 0..window {
                let rel = phase as isize + d as isize - radius;
                let (base, sub) = (rel.div_euclid(s), rel.rem_euclid(s) as usize);
                for &(k, w) in &phase_taps[sub] {
                    entries.push((d, base + k, w));
                }
            }
            let lo = entries.iter().map(|e| e.1).min().unwrap();
            start.push(lo);
            per_phase.push(entries);
        }
        let taps = per_phase
            .iter()
            .zip(&start)
            .map(|(entries, lo)| (entries.iter().map(|e| e.1).max().unwrap() - lo + 1) as usize)
            .max()
            .unwrap();
        let weights = per_phase
            .into_iter()
            .zip(&start)
            .map(|(entries, lo)| {
                // Merge entries that land on the same (d, a).
                let mut dense = vec![0f32; window * taps];
                for (d, off, w) in entries {
                    dense[d * taps + (off - lo) as usize] += w;
                }
                let mut sparse = Vec::new();
                for d in 0..window {
                    for a in 0..taps {
                        let w = dense[d * taps + a];
                        if w != 0.0 {
                            sparse.push((d, a, w));
                        }
                    }
                }
                sparse
            })
            .collect();
        WindowGeometry {
            scale,
            window,
            taps,
            kernel,
            axis: AxisTaps { start, weights },
        }
    }

    /// Number of sub-pixel phases (scale²).
    pub fn phases(&self) -> usize {
        self.scale * self.scale
    }

    /// Length of one gathered LR window for `channels` channels.
    pub fn window_len(&self, channels: usize) -> usize {
        self.taps * self.taps * channels
    }

    /// Phase index (`φy · scale + φx`) of output texel (row, column).
    #[inline]
    pub fn phase(&self, row: usize, col: usize) -> usize {
        (row % self.scale) * self.scale + col % self.scale
    }

    /// Gathers the LR window of output texel (row, col) from `features` (the LR maps) into
    /// `out`, laid out `[a][b][c]` over `channels`, reading beyond the edges as `border`.
    pub fn gather(
        &self,
        features: &Map,
        channels: &[usize],
        border: Border,
        row: usize,
        col: usize,
        out: &mut [f32],
    ) {
        let (w, h) = (features.width(), features.height());
        let k = self.taps;
        let nc = channels.len();
        let y0 = (row / self.scale) as isize + self.axis.start[row % self.scale];
        let x0 = (col / self.scale) as isize + self.axis.start[col % self.scale];
        let n = features.texels();
        let data = features.data();
        for a in 0..k {
            let y = border.index(y0 + a as isize, h);
            for b in 0..k {
                let x = border.index(x0 + b as isize, w);
                let texel = y * w + x;
                let o = (a * k + b) * nc;
                for (slot, &c) in channels.iter().enumerate() {
                    out[o + slot] = data[c * n + texel];
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::test_map;
    use matup_core::resample::upsample;

    /// The window of the upsampled map equals the folded LR window, for every phase.
    #[test]
    fn folding_reproduces_the_upsampled_window() {
        let lr = test_map(9, 7, 2);
        for (kernel, border) in [
            (Kernel::Bilinear, Border::Wrap),
            (Kernel::Bilinear, Border::Mirror),
            (Kernel::Bicubic { a: -0.5 }, Border::Wrap),
            (Kernel::Lanczos3, Border::Mirror),
        ] {
            let g = WindowGeometry::new(4, 17, kernel);
            if kernel == Kernel::Bilinear {
                assert_eq!(g.taps, 6, "METHOD.md: a 6×6 LR window per phase");
            }
            let hr = upsample(&lr, 4, kernel, border);
            let mut window = vec![0f32; g.window_len(2)];
            for (row, col) in [(0, 0), (5, 13), (27, 35), (13, 2)] {
                g.gather(&lr, &[0, 1], border, row, col, &mut window);
                let (py, px) = (row % 4, col % 4);
                for c in 0..2 {
                    for dy in 0..17 {
                        for dx in 0..17 {
                            let mut v = 0.0;
                            for &(d, a, wy) in &g.axis.weights[py] {
                                if d != dy {
                                    continue;
                                }
                                for &(e, b, wx) in &g.axis.weights[px] {
                                    if e == dx {
                                        v += wy * wx * window[(a * g.taps + b) * 2 + c];
                                    }
                                }
                            }
                            let y = border.index(row as isize + dy as isize - 8, hr.height());
                            let x = border.index(col as isize + dx as isize - 8, hr.width());
                            let want = hr.get(c, y, x);
                            assert!((v - want).abs() < 1e-5, "{kernel:?} {border} ({row},{col}) c{c} d({dy},{dx}): {v} vs {want}");
                        }
                    }
                }
            }
        }
    }
}
