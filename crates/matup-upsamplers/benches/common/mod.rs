//! What the upsamplers' benches share.

use std::time::{Duration, Instant};

/// Median seconds per call of `f`, over at least 3 calls (after one untimed call that builds
/// the plan) or as many as fit in `budget`, whichever is fewer.
pub fn median_seconds(mut f: impl FnMut(), budget: Duration) -> (f64, usize) {
    f();
    let start = Instant::now();
    let mut times = Vec::new();
    while times.len() < 3 && (times.is_empty() || start.elapsed() < budget) {
        let t = Instant::now();
        f();
        times.push(t.elapsed().as_secs_f64());
    }
    times.sort_by(f64::total_cmp);
    (times[times.len() / 2], times.len())
}
