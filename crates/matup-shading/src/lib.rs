//! matup's built-in shading models, each registered with `inventory`: `ggx` (METHOD.md's
//! Cook–Torrance), `ggx-aniso` (anisotropic GGX) and `lambert` (diffuse only).
//!
//! Rooms:
//! - `ggx`, `aniso`, `lambert`: each model's radiance and its analytic Jacobian.
//! - `tensor_forms`: the same formulas as candle operations; `clamps`: METHOD.md's clamped
//!   cosines and floored lengths; `dual`: forward-mode dual numbers for the Jacobians.

mod aniso;
mod clamps;
mod dual;
mod ggx;
mod lambert;
mod tensor_forms;

pub use aniso::GgxAniso;
pub use ggx::Ggx;
pub use lambert::Lambert;
