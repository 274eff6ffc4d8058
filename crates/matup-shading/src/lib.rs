//! matup's built-in shading models, each registered with `inventory`: `ggx` (METHOD.md's
//! Cook–Torrance), `ggx-aniso` (anisotropic GGX) and `lambert` (diffuse only).

mod aniso;
mod clamps;
mod dual;
mod ggx;
mod lambert;
mod tensor_forms;

pub use aniso::GgxAniso;
pub use ggx::Ggx;
pub use lambert::Lambert;
