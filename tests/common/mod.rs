//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use matup::Map;

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

/// The largest absolute difference between two maps of one shape.
pub fn max_abs_diff(a: &Map, b: &Map) -> f32 {
    assert_eq!(
        (a.width(), a.height(), a.channels()),
        (b.width(), b.height(), b.channels())
    );
    a.data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}
