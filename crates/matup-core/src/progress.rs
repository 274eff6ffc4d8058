//! Progress reporting: libraries call a [`Progress`]; the CLI draws bars from it.

/// Receives progress from long-running library calls. Every method has an empty default.
pub trait Progress: Sync {
    /// A stage begins; `total` units of work (0 when unknown).
    fn stage(&self, _name: &str, _total: u64) {}
    /// `done` more units of the current stage are finished; `loss` is the running loss.
    fn advance(&self, _done: u64, _loss: Option<f64>) {}
    /// The network's call in progress has run `done` of its `total` tiles (a finer step
    /// within the current stage; each call counts from the start).
    fn tiles(&self, _done: u64, _total: u64) {}
    /// A note for the user (what was skipped, detected, resumed).
    fn note(&self, _message: &str) {}
    /// Whether the caller wants the work to stop (Ctrl-C); training checks it every step and
    /// stops with [`Error::Cancelled`](crate::Error::Cancelled), its last checkpoint intact;
    /// upscaling checks it at every tile of a network.
    fn cancelled(&self) -> bool {
        false
    }
}

/// Reports nowhere.
pub struct Silent;
impl Progress for Silent {}
