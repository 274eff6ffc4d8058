//! matup's built-in shading models, each registered with `inventory`: `ggx` (METHOD.md's
//! Cook–Torrance), `ggx-aniso` (anisotropic GGX) and `lambert` (diffuse only).

mod aniso;
mod dual;
mod ggx;
mod lambert;
mod tensors;
mod vec3;

pub use aniso::GgxAniso;
pub use ggx::Ggx;
pub use lambert::Lambert;
