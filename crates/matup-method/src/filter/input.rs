//! The filter's input as training reads it: the LR features upsampled to the output size
//! once, so every window is a plain N×N×C crop and the first layer is one dense product per
//! batch. Folding the layer per phase (inference's way, [`super::folded`]) needs 8× fewer
//! multiply-adds per texel, but re-folding after every weight update and unfolding every
//! gradient cost more than the products saved at 128 texels a step (measured on 2 cores:
//! 2.5 ms of a 5.5 ms step, against about 1.1 ms for the two products).

use rayon::prelude::*;

use super::geometry::WindowGeometry;
use matup_core::map::Map;
use matup_core::resample::{upsample, Border};

/// The upsampled input features with a margin of N/2 texels on every side (read beyond the
/// edges as the border says), texel-major: `[y][x][c]`.
pub struct UpsampledInput {
    /// Output size.
    width: usize,
    height: usize,
    channels: usize,
    /// N.
    window: usize,
    data: Vec<f32>,
}

impl UpsampledInput {
    /// `channels` of the LR `features`, upsampled as `geometry` says.
    pub fn new(
        features: &Map,
        channels: &[usize],
        border: Border,
        geometry: &WindowGeometry,
    ) -> UpsampledInput {
        let s = geometry.scale;
        let (width, height) = (features.width() * s, features.height() * s);
        // With no channels there is nothing to read: every window is empty.
        let data = if channels.is_empty() {
            Vec::new()
        } else {
            with_margin(features, channels, border, geometry)
        };
        UpsampledInput {
            width,
            height,
            channels: channels.len(),
            window: geometry.window,
            data,
        }
    }

    /// Length of one window (N·N·C).
    pub fn window_len(&self) -> usize {
        self.window * self.window * self.channels
    }

    /// Appends the window of output texel (row, col), `[dy][dx][c]`, to `out`: N row copies
    /// (no zero-filling first).
    pub fn push_window(&self, row: usize, col: usize, out: &mut Vec<f32>) {
        debug_assert!(row < self.height && col < self.width);
        let (n, c) = (self.window, self.channels);
        let stride = (self.width + n - 1) * c;
        // Texel (row, col) sits at (row + margin, col + margin); its window starts at
        // (row, col).
        for dy in 0..n {
            out.extend_from_slice(&self.data[(row + dy) * stride + col * c..][..n * c]);
        }
    }
}

/// `channels` of `features` upsampled with a margin of N/2 texels, texel-major.
fn with_margin(
    features: &Map,
    channels: &[usize],
    border: Border,
    geometry: &WindowGeometry,
) -> Vec<f32> {
    let s = geometry.scale;
    let margin = geometry.window / 2;
    // The LR map padded far enough that the upsampling's own border handling never reaches
    // the crop: the margin's values are then exactly those of the LR map read beyond its
    // edges, whatever the border.
    let reach = (geometry.kernel.phase_taps(s).iter().flatten())
        .map(|&(k, _)| k.unsigned_abs())
        .max()
        .unwrap_or(0);
    let pad = margin.div_ceil(s) + reach + 1;
    let (lw, lh) = (features.width(), features.height());
    let padded = Map::from_fn(lw + 2 * pad, lh + 2 * pad, channels.len(), |c, y, x| {
        features.get(
            channels[c],
            border.index(y as isize - pad as isize, lh),
            border.index(x as isize - pad as isize, lw),
        )
    });
    let up = upsample(&padded, s, geometry.kernel, Border::Clamp);
    let skip = pad * s - margin;
    let row_len = (lw * s + 2 * margin) * channels.len();
    let mut data = vec![0f32; (lh * s + 2 * margin) * row_len];
    data.par_chunks_mut(row_len)
        .enumerate()
        .for_each(|(y, row)| {
            for (x, texel) in row.chunks_exact_mut(channels.len()).enumerate() {
                for (c, v) in texel.iter_mut().enumerate() {
                    *v = up.get(c, skip + y, skip + x);
                }
            }
        });
    data
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::folded::FoldedLayer;
    use crate::filter::{pseudo_random, test_map};
    use matup_core::resample::Kernel;
    use std::sync::Arc;

    /// A dense layer on the upsampled windows equals the folded layer on the LR windows, at
    /// every texel (edges included), for each kernel and border: training and inference
    /// compute the same filter.
    #[test]
    fn upsampled_windows_equal_the_folded_lr_windows() {
        let lr = test_map(7, 5, 3);
        let channels = [2, 0];
        let hidden = 3;
        for (kernel, border) in [
            (Kernel::Bilinear, Border::Wrap),
            (Kernel::Bilinear, Border::Mirror),
            (Kernel::Bilinear, Border::Clamp),
            (Kernel::Bicubic { a: -0.5 }, Border::Wrap),
            (Kernel::Lanczos3, Border::Mirror),
        ] {
            let geometry = Arc::new(WindowGeometry::new(4, 9, kernel));
            let layer = FoldedLayer {
                geometry: geometry.clone(),
                channels: channels.len(),
                hidden,
            };
            let weights = pseudo_random(layer.weight_len(), 5);
            let folded = layer.fold(&weights);
            let input = UpsampledInput::new(&lr, &channels, border, &geometry);
            let mut window = Vec::with_capacity(input.window_len());
            let mut lr_window = vec![0f32; geometry.window_len(channels.len())];
            for row in 0..lr.height() * 4 {
                for col in 0..lr.width() * 4 {
                    window.clear();
                    input.push_window(row, col, &mut window);
                    geometry.gather(&lr, &channels, border, row, col, &mut lr_window);
                    let phase = geometry.phase(row, col);
                    let want = layer.apply(&folded, &lr_window, &[phase]);
                    for (h, want) in want.iter().enumerate() {
                        let got: f32 = window
                            .iter()
                            .enumerate()
                            .map(|(i, v)| v * weights[i * hidden + h])
                            .sum();
                        assert!(
                            (got - want).abs() < 1e-4,
                            "{kernel:?} {border:?} ({row}, {col}) h{h}: {got} vs {want}"
                        );
                    }
                }
            }
        }
    }
}
