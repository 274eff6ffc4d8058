//! matup's CPU kernels, shared by the renderer's colour transforms, the shading models'
//! fused loss, the ONNX executor and the per-material filter: one matrix product (`gemm`),
//! run-time dispatch to AVX2 + FMA (`with_avx2!`) and branch-free `exp` and `ln` (`simd`).
//! Internals of matup, not a plugin author's API.

pub mod gemm;
pub mod simd;
