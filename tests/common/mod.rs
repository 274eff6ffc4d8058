//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// `../shared/materials/<name>` (CI checks the repository out with `shared/` beside it).
pub fn shared_material(name: &str) -> PathBuf {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/materials")
        .join(name);
    assert!(
        path.is_dir(),
        "{} is missing: the tests read the shared materials beside the repository",
        path.display()
    );
    path
}

/// The sample material shipped with the repository.
pub fn sample_material() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/victorian_wood")
}
