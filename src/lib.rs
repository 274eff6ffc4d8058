//! matup upsamples physically based materials (SVBRDF maps) by fitting them to
//! super-resolved renders. This facade re-exports the libraries, layer by layer, and links
//! every built-in plugin, so its registries list them all.

pub use matup_apps::*;
pub use matup_core::*;
pub use matup_eval::*;
pub use matup_method::*;

pub use matup_apps as apps;
pub use matup_core as core;
pub use matup_draw as draw;
pub use matup_eval as eval;
pub use matup_method as method;
pub use matup_shading as shading_models;
pub use matup_upsamplers as upsamplers;
