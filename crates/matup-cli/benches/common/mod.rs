//! What the benches read from `matup`'s reports.

/// Seconds in the stages whose name ends with `suffix`, over every level (0 for none), from a
/// run's `run.json` (`timings`).
pub fn stage(report: &serde_json::Value, suffix: &str) -> f64 {
    (report["timings"].as_array().into_iter().flatten())
        .filter(|t| t[0].as_str().is_some_and(|s| s.ends_with(suffix)))
        .filter_map(|t| t[1].as_f64())
        .sum()
}
