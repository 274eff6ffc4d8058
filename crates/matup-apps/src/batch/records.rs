//! What a material's run leaves in its output folder for the batch to read back: `run.json`
//! when it finished, `error.json` when it failed, each valid only for the settings it names.

use std::path::Path;
use std::time::{SystemTime, UNIX_EPOCH};

use serde::{Deserialize, Serialize};

/// The record of a failed material, `error.json` in its output folder.
pub(super) const FAILURE_FILE: &str = "error.json";

#[derive(Serialize, Deserialize)]
pub(super) struct Failure {
    pub(super) error: String,
    pub(super) settings_fingerprint: Option<String>,
    /// Seconds since the Unix epoch, to the microsecond: a rerun that begins within the second
    /// its run failed in must still read the failure as its run's, not one of its own batch's.
    /// (Whole seconds, as earlier records hold, read as they are.)
    pub(super) failed_at: f64,
}

impl Failure {
    /// Whether another worker of the batch that began at `began` recorded it.
    pub(super) fn failed_since(&self, began: SystemTime) -> bool {
        self.failed_at >= unix_seconds(began)
    }
}

pub(super) fn unix_seconds(t: SystemTime) -> f64 {
    t.duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64())
}

/// The failure recorded in `folder` for these settings.
pub(super) fn read_failure(folder: &Path, fingerprint: &str) -> Option<Failure> {
    let text = std::fs::read_to_string(folder.join(FAILURE_FILE)).ok()?;
    let failure: Failure = serde_json::from_str(&text).ok()?;
    (failure.settings_fingerprint.as_deref() == Some(fingerprint)).then_some(failure)
}

/// What the summary reads from a finished run's `run.json`.
#[derive(Deserialize)]
pub(super) struct Finished {
    pub(super) settings_fingerprint: Option<String>,
    pub(super) total_seconds: Option<f64>,
    pub(super) final_loss: Option<f64>,
    #[serde(default)]
    pub(super) skipped: Vec<String>,
    pub(super) tileable: Option<bool>,
    pub(super) input_size: Option<[usize; 2]>,
    pub(super) output_size: Option<[usize; 2]>,
}

/// The finished run in `folder`, when it ran with these settings.
pub(super) fn read_result(folder: &Path, fingerprint: &str) -> Option<Finished> {
    let text = std::fs::read_to_string(folder.join("run.json")).ok()?;
    let finished: Finished = serde_json::from_str(&text).ok()?;
    (finished.settings_fingerprint.as_deref() == Some(fingerprint)).then_some(finished)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    #[test]
    fn a_failure_in_the_second_a_rerun_begins_is_the_earlier_runs() {
        let at = |ms: u64| UNIX_EPOCH + Duration::from_millis(ms);
        let failure = |failed_at| Failure {
            error: "bad".into(),
            settings_fingerprint: Some("f".into()),
            failed_at,
        };
        let recorded = failure(unix_seconds(at(1_700_000_000_300)));
        assert!(!recorded.failed_since(at(1_700_000_000_600)));
        assert!(recorded.failed_since(at(1_700_000_000_100)));
        // Through its file, and a record of whole seconds as earlier versions wrote.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FAILURE_FILE);
        std::fs::write(&path, serde_json::to_vec(&recorded).unwrap()).unwrap();
        let read = read_failure(dir.path(), "f").unwrap();
        assert!(!read.failed_since(at(1_700_000_000_600)));
        let whole = r#"{"error": "bad", "settings_fingerprint": "f", "failed_at": 1700000000}"#;
        std::fs::write(&path, whole).unwrap();
        assert_eq!(
            read_failure(dir.path(), "f").unwrap().failed_at,
            1_700_000_000.0
        );
    }
}
