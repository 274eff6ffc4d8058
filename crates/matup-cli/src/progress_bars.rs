//! Progress bars (indicatif) drawn from the library's progress callback.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use matup_core::progress::Progress;

/// One bar per stage, with its ETA and the running loss; notes printed above the bars.
pub struct Bars {
    current: Mutex<Option<ProgressBar>>,
    quiet: bool,
    interrupted: Arc<AtomicBool>,
}

impl Bars {
    /// Bars that also watch for Ctrl-C: the first asks the run to stop at the next step (its
    /// checkpoint intact), a second exits at once.
    pub fn new(quiet: bool) -> Self {
        let interrupted = Arc::new(AtomicBool::new(false));
        let flag = interrupted.clone();
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
            eprintln!("\ninterrupted: stopping at the next step (Ctrl-C again to quit now)");
        });
        Bars {
            current: Mutex::new(None),
            quiet,
            interrupted,
        }
    }

    pub fn finish(&self) {
        if let Some(bar) = self.current.lock().unwrap().take() {
            bar.finish();
        }
    }
}

impl Progress for Bars {
    fn stage(&self, name: &str, total: u64) {
        if self.quiet {
            return;
        }
        let mut current = self.current.lock().unwrap();
        if let Some(bar) = current.take() {
            bar.finish();
        }
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        bar.set_style(
            ProgressStyle::with_template(
                "{prefix:>24} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
            )
            .unwrap()
            .progress_chars("=> "),
        );
        bar.set_prefix(name.to_string());
        *current = Some(bar);
    }

    fn advance(&self, done: u64, loss: Option<f64>) {
        if let Some(bar) = &*self.current.lock().unwrap() {
            bar.inc(done);
            if let Some(l) = loss {
                bar.set_message(format!("loss {l:.5}"));
            }
        }
    }

    fn cancelled(&self) -> bool {
        self.interrupted.load(Ordering::SeqCst)
    }

    fn note(&self, message: &str) {
        if self.quiet {
            return;
        }
        match &*self.current.lock().unwrap() {
            Some(bar) => bar.suspend(|| eprintln!("{message}")),
            None => eprintln!("{message}"),
        }
    }
}
