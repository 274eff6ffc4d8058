//! Claiming a material before working on it, for workers that may overlap on a shared file
//! system (a re-submitted array task, two clusters on one library).
//!
//! A claim is a file `.matup-claim-G` in the material's output folder, G its generation. It
//! is written to a private temporary file and hard-linked into place: a hard link fails when
//! the name exists, atomically, on local file systems and NFS alike (`O_EXCL` is not atomic
//! on old NFS), and the claim is never seen half-written. Its holder touches it every
//! heartbeat. A claim is stale when it was not touched for the timeout, or when its holder
//! ran on this machine and its process is gone; a worker takes a stale claim over by
//! creating generation G + 1, which only one worker can. A holder that sees a newer
//! generation has lost its claim and stops.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, RecvTimeoutError, Sender};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, SystemTime};

use serde::{Deserialize, Serialize};

use matup_core::{Error, Result};

const PREFIX: &str = ".matup-claim-";

/// How claims are kept and judged.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClaimTiming {
    /// A claim not touched for this long is stale and may be taken over.
    pub timeout: Duration,
    /// How often a holder touches its claim (well below `timeout`).
    pub heartbeat: Duration,
}

impl ClaimTiming {
    /// Heartbeats at a tenth of the timeout, so a holder misses ten before it loses a claim.
    pub fn with_timeout(timeout: Duration) -> ClaimTiming {
        ClaimTiming {
            timeout,
            heartbeat: (timeout / 10).max(Duration::from_millis(100)),
        }
    }
}

impl Default for ClaimTiming {
    fn default() -> Self {
        ClaimTiming::with_timeout(Duration::from_secs(600))
    }
}

/// Who holds a claim.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Holder {
    pub host: String,
    pub pid: u32,
}

impl Holder {
    /// This process.
    pub fn this_process() -> Holder {
        Holder {
            host: host_name(),
            pid: std::process::id(),
        }
    }

    /// Whether the holder certainly stopped: it ran on this host and its process is gone.
    /// Elsewhere only the heartbeat can tell.
    fn is_gone(&self) -> bool {
        self.host == host_name() && cfg!(target_os = "linux") && {
            let proc_entry = PathBuf::from(format!("/proc/{}", self.pid));
            !proc_entry.exists()
        }
    }
}

impl std::fmt::Display for Holder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "process {} on {}", self.pid, self.host)
    }
}

/// The host name from the kernel, else the environment (a container's is its pod name).
fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .ok()
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
        .or_else(|| std::env::var("HOSTNAME").ok())
        .or_else(|| std::env::var("COMPUTERNAME").ok())
        .unwrap_or_else(|| "unknown-host".into())
}

/// The outcome of trying to claim a folder.
pub enum Claimed {
    /// This worker holds it until the [`Claim`] is released or dropped.
    Yes(Claim),
    /// A live worker holds it.
    HeldBy(Holder),
}

/// A held claim, touched by a heartbeat thread.
pub struct Claim {
    path: PathBuf,
    /// The next generation's file: it exists once another worker took the claim over.
    takeover: PathBuf,
    lost: Arc<AtomicBool>,
    stop: Option<Sender<()>>,
    heartbeat: Option<JoinHandle<()>>,
}

/// Claims `folder` (created if needed) for this process, taking over a stale claim.
pub fn claim(folder: &Path, timing: ClaimTiming) -> Result<Claimed> {
    std::fs::create_dir_all(folder).map_err(|e| Error::io(folder, e))?;
    let me = Holder::this_process();
    // A few rounds: another worker may create or take over the claim between our look and
    // our link, and then we look again.
    for _ in 0..8 {
        let generation = match newest_claim(folder)? {
            None => 0,
            Some((g, path)) => match read_claim(&path) {
                Some((holder, touched)) => {
                    if is_live(&holder, touched, timing) {
                        return Ok(Claimed::HeldBy(holder));
                    }
                    g + 1
                }
                // Gone since we listed it (released): look again.
                None => continue,
            },
        };
        let path = claim_path(folder, generation);
        if create_claim(&path, &me)? {
            for old in claim_files(folder)? {
                if old.0 < generation {
                    let _ = std::fs::remove_file(&old.1);
                }
            }
            return Ok(Claimed::Yes(Claim::hold(folder, generation, timing)));
        }
    }
    Err(Error::file(
        folder,
        "the claim kept changing hands; too many workers on one material",
    ))
}

/// The claim files of `folder` with their generations.
fn claim_files(folder: &Path) -> Result<Vec<(u64, PathBuf)>> {
    let entries = std::fs::read_dir(folder).map_err(|e| Error::io(folder, e))?;
    Ok(entries
        .filter_map(|e| e.ok())
        .filter_map(|e| {
            let name = e.file_name();
            let generation = name.to_str()?.strip_prefix(PREFIX)?.parse().ok()?;
            Some((generation, e.path()))
        })
        .collect())
}

fn newest_claim(folder: &Path) -> Result<Option<(u64, PathBuf)>> {
    Ok(claim_files(folder)?.into_iter().max_by_key(|c| c.0))
}

/// Whether `folder` holds a claim that is not stale (for the summary: "running").
pub fn live_claim(folder: &Path, timing: ClaimTiming) -> Option<Holder> {
    let (_, path) = newest_claim(folder).ok()??;
    let (holder, touched) = read_claim(&path)?;
    is_live(&holder, touched, timing).then_some(holder)
}

/// Whether a claim last touched at `touched` by `holder` still holds: touched within the
/// timeout, by a process not known to have ended.
fn is_live(holder: &Holder, touched: SystemTime, timing: ClaimTiming) -> bool {
    let age = SystemTime::now()
        .duration_since(touched)
        .unwrap_or_default();
    age < timing.timeout && !holder.is_gone()
}

/// The file of generation `generation` of the claim on `folder`.
fn claim_path(folder: &Path, generation: u64) -> PathBuf {
    folder.join(format!("{PREFIX}{generation}"))
}

/// The holder and last heartbeat of a claim file; `None` when it is gone. A claim whose
/// content cannot be read counts as a foreign holder, judged by its age alone.
fn read_claim(path: &Path) -> Option<(Holder, SystemTime)> {
    let touched = std::fs::metadata(path).ok()?.modified().ok()?;
    let holder = std::fs::read_to_string(path)
        .ok()
        .and_then(|text| serde_json::from_str(&text).ok())
        .unwrap_or(Holder {
            host: "unknown (unreadable claim)".into(),
            pid: 0,
        });
    Some((holder, touched))
}

/// Creates `path` holding `holder`, atomically; false when it exists already.
fn create_claim(path: &Path, holder: &Holder) -> Result<bool> {
    use std::io::Write;
    let folder = path.parent().expect("a claim lives in a folder");
    let mut tmp = tempfile::Builder::new()
        .prefix(".matup-claiming-")
        .tempfile_in(folder)
        .map_err(|e| Error::io(folder, e))?;
    let text = serde_json::to_string(holder).expect("a holder serialises");
    tmp.write_all(text.as_bytes())
        .and_then(|_| tmp.as_file().sync_all())
        .map_err(|e| Error::io(tmp.path(), e))?;
    match std::fs::hard_link(tmp.path(), path) {
        Ok(()) => Ok(true),
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(false),
        Err(e) => Err(Error::io(path, e)),
    }
    // `tmp` is removed when dropped; the claim keeps the linked file.
}

impl Claim {
    fn hold(folder: &Path, generation: u64, timing: ClaimTiming) -> Claim {
        let path = claim_path(folder, generation);
        let takeover = claim_path(folder, generation + 1);
        let lost = Arc::new(AtomicBool::new(false));
        let (stop, stopped) = channel();
        let heartbeat = {
            let (path, takeover, lost) = (path.clone(), takeover.clone(), lost.clone());
            std::thread::spawn(move || loop {
                match stopped.recv_timeout(timing.heartbeat) {
                    Err(RecvTimeoutError::Timeout) => {}
                    _ => return,
                }
                if takeover.exists() || touch(&path).is_err() {
                    lost.store(true, Ordering::SeqCst);
                    return;
                }
            })
        };
        Claim {
            path,
            takeover,
            lost,
            stop: Some(stop),
            heartbeat: Some(heartbeat),
        }
    }

    /// Whether another worker took the claim over (this one stopped heartbeating in time).
    pub fn lost(&self) -> bool {
        self.lost.load(Ordering::SeqCst)
    }

    /// The flag [`Claim::lost`] reads, for a progress callback to cancel the run with.
    pub fn lost_flag(&self) -> Arc<AtomicBool> {
        self.lost.clone()
    }

    /// Stops the heartbeat and removes the claim (unless another worker holds it now).
    pub fn release(mut self) {
        self.stop_heartbeat();
        if !self.takeover.exists() {
            let _ = std::fs::remove_file(&self.path);
        }
    }

    fn stop_heartbeat(&mut self) {
        drop(self.stop.take());
        if let Some(h) = self.heartbeat.take() {
            let _ = h.join();
        }
    }
}

impl Drop for Claim {
    fn drop(&mut self) {
        self.stop_heartbeat();
    }
}

/// Sets the modification time of `path` to now (the heartbeat).
fn touch(path: &Path) -> std::io::Result<()> {
    File::options()
        .write(true)
        .open(path)?
        .set_modified(SystemTime::now())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn timing(ms: u64) -> ClaimTiming {
        ClaimTiming {
            timeout: Duration::from_millis(ms),
            heartbeat: Duration::from_millis(ms / 10),
        }
    }

    fn foreign_claim(folder: &Path, generation: u64, age: Duration) -> PathBuf {
        let path = folder.join(format!("{PREFIX}{generation}"));
        let holder = Holder {
            host: "another-node".into(),
            pid: 1,
        };
        std::fs::write(&path, serde_json::to_string(&holder).unwrap()).unwrap();
        File::options()
            .write(true)
            .open(&path)
            .unwrap()
            .set_modified(SystemTime::now() - age)
            .unwrap();
        path
    }

    #[test]
    fn one_claim_at_a_time() {
        let dir = tempfile::tempdir().unwrap();
        let Claimed::Yes(first) = claim(dir.path(), timing(60_000)).unwrap() else {
            panic!("an unclaimed folder is claimed")
        };
        match claim(dir.path(), timing(60_000)).unwrap() {
            Claimed::HeldBy(h) => assert_eq!(h, Holder::this_process()),
            Claimed::Yes(_) => panic!("a live claim is not taken twice"),
        }
        first.release();
        assert!(claim_files(dir.path()).unwrap().is_empty());
        assert!(matches!(
            claim(dir.path(), timing(60_000)).unwrap(),
            Claimed::Yes(_)
        ));
    }

    #[test]
    fn a_fresh_foreign_claim_is_respected_and_a_stale_one_taken_over() {
        let dir = tempfile::tempdir().unwrap();
        foreign_claim(dir.path(), 0, Duration::from_secs(5));
        match claim(dir.path(), timing(60_000)).unwrap() {
            Claimed::HeldBy(h) => assert_eq!(h.host, "another-node"),
            Claimed::Yes(_) => panic!("a claim touched 5 s ago is live for a 60 s timeout"),
        }
        foreign_claim(dir.path(), 0, Duration::from_secs(120));
        let Claimed::Yes(claim) = claim(dir.path(), timing(60_000)).unwrap() else {
            panic!("a claim untouched for 120 s is stale")
        };
        let files = claim_files(dir.path()).unwrap();
        assert_eq!(files.len(), 1, "the stale claim is removed");
        assert_eq!(files[0].0, 1, "taken over as the next generation");
        claim.release();
    }

    #[test]
    fn a_dead_local_process_loses_its_claim_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        let holder = Holder {
            host: host_name(),
            pid,
        };
        std::fs::write(
            dir.path().join(format!("{PREFIX}0")),
            serde_json::to_string(&holder).unwrap(),
        )
        .unwrap();
        let claimed = claim(dir.path(), timing(600_000)).unwrap();
        assert_eq!(
            matches!(claimed, Claimed::Yes(_)),
            cfg!(target_os = "linux"),
            "a claim of an exited process on this host is stale (where /proc tells)"
        );
    }

    #[test]
    fn the_heartbeat_keeps_a_claim_and_a_takeover_is_noticed() {
        let dir = tempfile::tempdir().unwrap();
        let Claimed::Yes(held) = claim(dir.path(), timing(400)).unwrap() else {
            panic!()
        };
        std::thread::sleep(Duration::from_millis(1000));
        // Well past the timeout, the heartbeat kept it live.
        assert!(live_claim(dir.path(), timing(400)).is_some());
        assert!(!held.lost());
        // Another worker that judged it stale creates the next generation.
        foreign_claim(dir.path(), 1, Duration::ZERO);
        std::thread::sleep(Duration::from_millis(300));
        assert!(held.lost(), "the holder sees the newer generation");
        held.release();
        assert!(
            dir.path().join(format!("{PREFIX}1")).exists(),
            "releasing a lost claim leaves the new holder's"
        );
    }
}
