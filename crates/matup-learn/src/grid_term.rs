//! The output's texel grid as a training term. An upsampler that draws its input's texel
//! edges makes the steps across the `scale`-texel block edges larger than those inside a
//! block (the block-edge ratio of `matup eval`); true materials read about 1. The term charges
//! how far the output's edge steps lie from the truth's ratio to its inside steps, either way
//! (edges flattened below the inside steps show the grid too), so a network learns to draw no
//! grid without being pushed toward the truth's overall sharpness, which the render loss
//! judges (docs/experiments/2026-11-26-seamless-by-default.md, "The block grid").

use candle_core::Tensor;

/// Per image of `maps` `[B, C, H, W]` (blocks of `scale` texels from the top-left corner):
/// the mean |difference| between neighbours across block edges and inside blocks, both axes
/// and every channel, as two `[B]` tensors.
fn edge_and_inside_steps(maps: &Tensor, scale: usize) -> candle_core::Result<(Tensor, Tensor)> {
    let (_, c, h, w) = maps.dims4()?;
    let device = maps.device();
    // Step i lies between texels i and i + 1: across a block edge where i + 1 is a multiple
    // of the scale.
    let edge_mask = |n: usize, shape: (usize, usize)| -> candle_core::Result<Tensor> {
        let mask: Vec<f32> = (0..n - 1)
            .map(|i| ((i + 1) % scale == 0) as u8 as f32)
            .collect();
        Tensor::from_vec(mask, (1, 1, shape.0, shape.1), device)
    };
    let across = (maps.narrow(3, 1, w - 1)? - maps.narrow(3, 0, w - 1)?)?.abs()?;
    let down = (maps.narrow(2, 1, h - 1)? - maps.narrow(2, 0, h - 1)?)?.abs()?;
    let (mask_x, mask_y) = (edge_mask(w, (1, w - 1))?, edge_mask(h, (h - 1, 1))?);
    let sum = |t: &Tensor| t.sum((1, 2, 3));
    let edge_sum = (sum(&across.broadcast_mul(&mask_x)?)? + sum(&down.broadcast_mul(&mask_y)?)?)?;
    let all_sum = (sum(&across)? + sum(&down)?)?;
    // Block edges per line of n texels: the multiples of the scale in 1..n.
    let edges_per_line = |n: usize| ((n - 1) / scale) as f64;
    let edges = (c * h) as f64 * edges_per_line(w) + (c * w) as f64 * edges_per_line(h);
    let all = (c * h * (w - 1) + c * (h - 1) * w) as f64;
    let edge_mean = (&edge_sum / edges.max(1.0))?;
    let inside_mean = ((all_sum - edge_sum)? / (all - edges).max(1.0))?;
    Ok((edge_mean, inside_mean))
}

/// The grid term of `output` against `truth` (both `[B, C, H, W]`, ×`scale` of inputs whose
/// texels start at the top-left corner): how far the output's mean step across block edges
/// lies from its mean step inside blocks times the truth's block-edge ratio, either way, over
/// the truth's mean step inside blocks. The means run over the whole batch: a nearly flat
/// crop's own ratio is noise, and dividing by its tiny steps would let it dominate.
pub fn grid_term(output: &Tensor, truth: &Tensor, scale: usize) -> candle_core::Result<Tensor> {
    let (truth_edge, truth_inside) = edge_and_inside_steps(&truth.detach(), scale)?;
    let truth_inside = truth_inside.mean_all()?.clamp(1e-6, f32::INFINITY)?;
    let truth_ratio = (truth_edge.mean_all()? / &truth_inside)?;
    let (edge, inside) = edge_and_inside_steps(output, scale)?;
    let miss = (edge.mean_all()? - (inside.mean_all()? * truth_ratio)?)?.abs()?;
    miss / truth_inside
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::Device;

    fn row(values: &[f32]) -> Tensor {
        Tensor::from_vec(values.to_vec(), (1, 1, 1, values.len()), &Device::Cpu).unwrap()
    }

    fn term(output: &[f32], truth: &[f32]) -> f32 {
        grid_term(&row(output), &row(truth), 4)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap()
    }

    #[test]
    fn steps_on_the_block_edges_unlike_the_truths_are_charged_either_way() {
        // Nearest-neighbour ×4 of [0, 1]: one step of 1 across the block edge, none inside;
        // the truth ramps by 1/7 everywhere (ratio 1). The excess is 1 − 0, over 1/7.
        let blocky = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0];
        let ramp: Vec<f32> = (0..8).map(|i| i as f32 / 7.0).collect();
        assert!((term(&blocky, &ramp) - 7.0).abs() < 1e-4);
        // Edges flatter than the inside are charged as well: [0, 0.5, 1, 1.5] twice, a
        // step of 0 on the edge where the truth's ratio asks for 0.5; 0.5 over 1/7.
        let flat_edges = [0.0, 0.5, 1.0, 1.5, 1.5, 2.0, 2.5, 3.0];
        assert!((term(&flat_edges, &ramp) - 3.5).abs() < 1e-4);
        // The truth itself, and a ramp of another slope, draw no grid.
        assert!(term(&ramp, &ramp).abs() < 1e-6);
        let steeper: Vec<f32> = ramp.iter().map(|v| 2.0 * v).collect();
        assert!(term(&steeper, &ramp).abs() < 1e-6);
        // A truth with a grid of its own (ratio 3) allows the same in the output.
        let gridded = [0.0, 0.1, 0.2, 0.3, 0.6, 0.7, 0.8, 0.9];
        assert!(term(&gridded, &gridded).abs() < 1e-6);
    }

    #[test]
    fn a_flat_crop_in_the_batch_does_not_swamp_the_term() {
        // Beside the blocky row against its ramp, a flat truth whose output steps by 10⁻³ on
        // its block edge: its own ratio is 10⁻³ over nothing, but over the batch the means
        // are (1 + 10⁻³) / 2 across edges, 0 inside, and the truth's 1/14 and 1/14.
        let batch = |rows: [&[f32]; 2]| {
            let data: Vec<f32> = rows.iter().flat_map(|r| r.iter().copied()).collect();
            Tensor::from_vec(data, (2, 1, 1, 8), &Device::Cpu).unwrap()
        };
        let blocky = [0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0];
        let ramp: Vec<f32> = (0..8).map(|i| i as f32 / 7.0).collect();
        let nudged = [0.0, 0.0, 0.0, 0.0, 1e-3, 1e-3, 1e-3, 1e-3];
        let output = batch([&blocky, &nudged]);
        let truth = batch([&ramp, &[0.0; 8]]);
        let term = grid_term(&output, &truth, 4)
            .unwrap()
            .to_scalar::<f32>()
            .unwrap();
        assert!((term - 7.007).abs() < 1e-3, "{term}");
    }

    #[test]
    fn the_steps_are_split_at_the_block_edges_on_both_axes() {
        // A 4×8 image whose values change by 1 across the column block edge and by 0.5 inside
        // along the rows; down the columns every step (inside, as 4 rows make one block) is 0.
        let data: Vec<f32> = (0..4)
            .flat_map(|_| [0.0, 0.5, 1.0, 1.5, 2.5, 3.0, 3.5, 4.0])
            .collect();
        let maps = Tensor::from_vec(data, (1, 1, 4, 8), &Device::Cpu).unwrap();
        let (edge, inside) = edge_and_inside_steps(&maps, 4).unwrap();
        let (edge, inside) = (
            edge.to_vec1::<f32>().unwrap()[0],
            inside.to_vec1::<f32>().unwrap()[0],
        );
        assert!((edge - 1.0).abs() < 1e-6);
        // Inside: 6 steps of 0.5 per row (24) and 24 vertical steps of 0: 12 / 48.
        assert!((inside - 0.25).abs() < 1e-6, "{inside}");
    }
}
