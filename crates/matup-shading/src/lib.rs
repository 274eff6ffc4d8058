//! matup's built-in shading models, each registered with `inventory`: `ggx` (METHOD.md's
//! Cook–Torrance), `ggx-aniso` (anisotropic GGX) and `lambert` (diffuse only).

mod aniso;
mod conventions;
mod dual;
mod ggx;
mod lambert;
mod tensors;

pub use aniso::GgxAniso;
pub use ggx::Ggx;
pub use lambert::Lambert;
