//! matup's applications, built on the method.
//!
//! Rooms:
//! - `folder`: one material folder upscaled into an output folder (maps, preview, run.json);
//!   `model`: a glTF model's textures upscaled in their roles, the model written beside them.
//! - `batch`: material libraries on one machine or a cluster (library walk, shards, claims,
//!   summary).
//! - `view`, `html`: the relightable viewer and the pages.
//! - `experiment`: bench and sweep, which run the pipeline on true materials and write
//!   tables and pages.

pub mod batch;
pub mod experiment;
pub mod folder;
pub mod html;
pub mod model;
pub mod view;
