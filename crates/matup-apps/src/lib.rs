//! matup's applications, built on the method: a material folder upscaled into an output
//! folder (`folder`), material libraries on one machine or a cluster (`batch`: library walk,
//! shards, claims, summary), glTF models upscaled whole (`model`), the pages (`view`, `html`), and experiments (`experiment`: bench
//! and sweep, which run the pipeline and write pages).

pub mod batch;
pub mod experiment;
pub mod folder;
pub mod html;
pub mod model;
pub mod view;
