//! matup's evaluation: how close an upsampled material comes to the truth (render PSNR,
//! FLIP, sharpness and per-map errors under held-out lights), and the per-map baselines
//! (each map through an RGB upsampler) that the method and experiments compare against.
//! Built on `matup-core` only.

pub mod baseline;
pub mod metrics;
