//! matup's SIMD routines, shared by the renderer's colour transforms, the shading models'
//! fused loss, the ONNX executor and the per-material filter: one matrix product (`gemm`),
//! run-time dispatch to AVX2 + FMA (`with_avx2!`), branch-free `exp` and `ln` (`simd`) and
//! denormals flushed to zero for a network's layers (`denormals`).
//! Internals of matup, not a plugin author's API.

pub mod denormals;
pub mod gemm;
pub mod simd;
