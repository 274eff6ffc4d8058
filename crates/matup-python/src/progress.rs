//! Progress to a Python callback, and Ctrl-C from Python: a run asks [`Progress::cancelled`]
//! between its stages, maps and the network's calls, and stops where Python has a
//! `KeyboardInterrupt` pending.

use std::sync::{Arc, Mutex};

use pyo3::prelude::*;

use matup::core::progress::Progress;

/// The first exception Python raised during a run (`KeyboardInterrupt`, or one from a
/// callback or the network), kept to be raised again, traceback and all, once the run stops.
#[derive(Clone, Default)]
pub struct Raised(Arc<Mutex<Option<PyErr>>>);

impl Raised {
    pub fn keep(&self, e: PyErr) {
        let mut slot = self.lock().unwrap_or_else(|p| p.into_inner());
        slot.get_or_insert(e);
    }

    pub fn is_set(&self) -> bool {
        self.lock().unwrap_or_else(|p| p.into_inner()).is_some()
    }

    pub fn lock(&self) -> std::sync::LockResult<std::sync::MutexGuard<'_, Option<PyErr>>> {
        self.0.lock()
    }
}

/// A run's progress: each event handed to `callback(kind, text, count, number)` — `("stage",
/// name, total, None)`, `("advance", "", done, loss)`, `("tiles", "", done, total)` (the tiles
/// of the network's call in progress) or `("note", message, 0, None)`.
pub struct PyProgress {
    callback: Option<Py<PyAny>>,
    raised: Raised,
}

impl PyProgress {
    pub fn new(callback: Option<Py<PyAny>>) -> PyProgress {
        PyProgress {
            callback,
            raised: Raised::default(),
        }
    }

    pub fn raised(&self) -> Raised {
        self.raised.clone()
    }

    /// `number` is the loss (a float or `None`), or for tiles their total.
    fn call<N>(&self, kind: &str, text: &str, count: u64, number: N)
    where
        N: for<'py> IntoPyObject<'py> + Copy,
    {
        let Some(callback) = &self.callback else {
            return;
        };
        if self.raised.is_set() {
            return;
        }
        Python::attach(|py| {
            if let Err(e) = callback.call1(py, (kind, text, count, number)) {
                self.raised.keep(e);
            }
        });
    }
}

impl Progress for PyProgress {
    fn stage(&self, name: &str, total: u64) {
        self.call("stage", name, total, None::<f64>);
    }

    fn advance(&self, done: u64, loss: Option<f64>) {
        self.call("advance", "", done, loss);
    }

    fn tiles(&self, done: u64, total: u64) {
        self.call("tiles", "", done, total);
    }

    fn note(&self, message: &str) {
        self.call("note", message, 0, None::<f64>);
    }

    /// Python's pending signals (Ctrl-C is `KeyboardInterrupt`), or an exception already
    /// raised by a callback: either stops the run.
    fn cancelled(&self) -> bool {
        if self.raised.is_set() {
            return true;
        }
        Python::attach(|py| match py.check_signals() {
            Ok(()) => false,
            Err(e) => {
                self.raised.keep(e);
                true
            }
        })
    }
}
