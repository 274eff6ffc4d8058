//! matup's evaluation: how close an upsampled material comes to the truth (render PSNR,
//! FLIP, sharpness and per-map errors under held-out lights). Built on `matup-core` only, so
//! that the method's self-validation can score its candidates with it; the per-map baselines
//! it is used to compare against are `matup_method::per_map`. `invented` measures structure an
//! output draws where its input is flat within its noise.

pub mod invented;
pub mod metrics;
