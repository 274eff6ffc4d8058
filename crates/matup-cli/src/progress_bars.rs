//! Progress bars (indicatif) drawn from the library's progress callbacks.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use matup_apps::batch::{BatchProgress, Handled};
use matup_core::progress::Progress;

/// Every bar's look: its name, the bar, the count, the time, the ETA and a message.
fn bar_style() -> ProgressStyle {
    ProgressStyle::with_template(
        "{prefix:>24} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta} {msg}",
    )
    .unwrap()
    .progress_chars("=> ")
}

/// One bar per stage, with its ETA and the running loss; notes printed above the bars.
pub struct Bars {
    current: Mutex<Option<ProgressBar>>,
    quiet: bool,
    interrupted: Arc<AtomicBool>,
    /// Where the bars are drawn: stderr, below a batch's bar when there is one.
    multi: MultiProgress,
    /// Clear a stage's bar when the next begins (in a batch), rather than leave it as a log.
    clear_finished: bool,
    /// Where stderr is no terminal (a log file, a cluster job) bars are hidden: each stage is
    /// logged as lines instead, unless `None` (a batch logs its materials, not their stages).
    log: Option<Mutex<StageLog>>,
}

/// What the progress lines of a log need: when the run and the stage began, the stage's
/// count, and when the last line was written.
struct StageLog {
    run_start: Instant,
    stage: String,
    stage_start: Instant,
    done: u64,
    total: u64,
    last_line: Instant,
}

/// A stage's progress is logged at most this often, and when it ends.
const LOG_EVERY: Duration = Duration::from_secs(30);

impl StageLog {
    fn new() -> Self {
        let now = Instant::now();
        StageLog {
            run_start: now,
            stage: String::new(),
            stage_start: now,
            done: 0,
            total: 0,
            last_line: now,
        }
    }

    /// The line for stage `name` starting, and starts counting it.
    fn start(&mut self, name: &str, total: u64) -> String {
        let now = Instant::now();
        (self.stage, self.stage_start, self.done, self.total) = (name.to_string(), now, 0, total);
        self.last_line = now;
        let steps = if total > 1 {
            format!(" ({total} steps)")
        } else {
            String::new()
        };
        format!("[{}] {name}: started{steps}", clock(now - self.run_start))
    }

    /// `done` more steps of the stage; a line when it ends or [`LOG_EVERY`] has passed, with
    /// the time the stage has taken and an estimate of what it has left.
    fn advance(&mut self, done: u64) -> Option<String> {
        self.done += done;
        let now = Instant::now();
        let finished = self.total > 0 && self.done >= self.total;
        if !finished && now - self.last_line < LOG_EVERY {
            return None;
        }
        self.last_line = now;
        let taken = now - self.stage_start;
        let at = clock(now - self.run_start);
        if finished {
            return Some(format!("[{at}] {}: done in {}", self.stage, clock(taken)));
        }
        let left = match self.done {
            0 => String::new(),
            done if self.total > done => {
                let per_step = taken.as_secs_f64() / done as f64;
                let left = Duration::from_secs_f64(per_step * (self.total - done) as f64);
                format!(", about {} left", clock(left))
            }
            _ => String::new(),
        };
        Some(format!(
            "[{at}] {}: {}/{} after {}{left}",
            self.stage,
            self.done,
            self.total,
            clock(taken)
        ))
    }
}

/// A duration as h:mm:ss, or m:ss under an hour.
fn clock(d: Duration) -> String {
    let s = d.as_secs();
    match s / 3600 {
        0 => format!("{}:{:02}", s / 60, s % 60),
        h => format!("{h}:{:02}:{:02}", s / 60 % 60, s % 60),
    }
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
        let target = if quiet {
            ProgressDrawTarget::hidden()
        } else {
            ProgressDrawTarget::stderr()
        };
        let multi_hidden = target.is_hidden();
        Bars {
            current: Mutex::new(None),
            quiet,
            interrupted,
            multi: MultiProgress::with_draw_target(target),
            clear_finished: false,
            log: (!quiet && multi_hidden).then(|| Mutex::new(StageLog::new())),
        }
    }

    pub fn finish(&self) {
        if let Some(bar) = self.current.lock().unwrap().take() {
            if self.clear_finished {
                bar.finish_and_clear();
            } else {
                bar.finish();
            }
        }
    }

    /// Prints a line above the bars.
    pub fn note_now(&self, message: &str) {
        if self.quiet {
            return;
        }
        // Bars are hidden where stderr is no terminal (a log file, a cluster job), and a
        // hidden MultiProgress prints nothing: notes go straight to stderr there.
        if self.multi.is_hidden() {
            eprintln!("{message}");
        } else {
            let _ = self.multi.println(message);
        }
    }
}

impl Progress for Bars {
    fn stage(&self, name: &str, total: u64) {
        if self.quiet {
            return;
        }
        if let Some(log) = &self.log {
            eprintln!("{}", log.lock().unwrap().start(name, total));
        }
        let mut current = self.current.lock().unwrap();
        match current.take() {
            Some(bar) if self.clear_finished => bar.finish_and_clear(),
            Some(bar) => bar.finish(),
            None => {}
        }
        let bar = self.multi.add(ProgressBar::new(total));
        bar.set_style(bar_style());
        bar.set_prefix(name.to_string());
        *current = Some(bar);
    }

    fn advance(&self, done: u64, loss: Option<f64>) {
        if let Some(line) = (self.log.as_ref()).and_then(|log| log.lock().unwrap().advance(done)) {
            eprintln!("{line}");
        }
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
        self.note_now(message)
    }
}

/// A batch: one bar over the materials with its ETA and the current material's name, the
/// current material's stage bar below it.
pub struct BatchBars {
    stages: Bars,
    materials: ProgressBar,
}

impl BatchBars {
    pub fn new(quiet: bool) -> Self {
        let stages = Bars {
            clear_finished: true,
            log: None,
            ..Bars::new(quiet)
        };
        let materials = stages.multi.add(ProgressBar::new(0));
        materials.set_style(bar_style());
        materials.set_prefix("materials");
        BatchBars { stages, materials }
    }

    pub fn finish(&self) {
        self.stages.finish();
        self.materials.finish();
    }

    pub fn note_now(&self, message: &str) {
        self.stages.note_now(message)
    }
}

impl Progress for BatchBars {
    fn stage(&self, name: &str, total: u64) {
        self.stages.stage(name, total)
    }
    fn advance(&self, done: u64, loss: Option<f64>) {
        self.stages.advance(done, loss)
    }
    fn cancelled(&self) -> bool {
        self.stages.cancelled()
    }
    fn note(&self, _message: &str) {
        // A material's notes (tileability, selection) are in its run.json; printed for every
        // material of a library they would bury the failures.
    }
}

impl BatchProgress for BatchBars {
    fn materials(&self, count: usize) {
        self.materials.set_length(count as u64);
    }

    fn material_started(&self, name: &str) {
        self.materials.set_message(name.to_string());
    }

    fn material_done(&self, handled: &Handled) {
        self.materials.inc(1);
        if let Some(detail) = handled.outcome.detail() {
            self.note_now(&format!(
                "{}: {} ({detail})",
                handled.material,
                handled.outcome.label()
            ));
        }
    }
}
