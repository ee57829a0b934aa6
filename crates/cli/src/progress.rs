//! How a long simulation shows that it is alive: a bar on a terminal, a line every few seconds
//! when stderr is a file or a pipe (CI logs, `2>&1 | tee`), nothing with `--quiet`. The
//! bring-up of a large segment comes first and has no cycles to count, so its phase and frames
//! are shown until the cycles start.

use ecsync_lab::run::BringupProgress;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal as _;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Seconds between two progress lines when stderr is not a terminal.
const LINE_EVERY: Duration = Duration::from_secs(5);

/// The progress of a comparison: `total` cycles over `runs` bring-ups.
pub struct Progress {
    bar: ProgressBar,
    /// Lines instead of a bar (stderr is not a terminal).
    lines: bool,
    quiet: bool,
    what: String,
    total: u64,
    runs: u32,
    started: Instant,
    last_line: Option<Instant>,
}

impl Progress {
    /// A bar (or lines) for `total` cycles of `what`; `quiet`: nothing at all.
    pub fn new(quiet: bool, what: String, total: u64, runs: u32) -> Self {
        let lines = !std::io::stderr().is_terminal();
        let bar = if quiet || lines {
            ProgressBar::hidden()
        } else {
            let b = ProgressBar::new(total);
            b.set_style(
                ProgressStyle::with_template(
                    "{spinner} {msg} [{bar:40}] {percent:>3}% {human_pos}/{human_len} cycles, {per_sec}, eta {eta}",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar())
                .progress_chars("=> "),
            );
            b
        };
        Progress {
            bar,
            lines,
            quiet,
            what,
            total,
            runs,
            started: Instant::now(),
            last_line: None,
        }
    }

    /// Shows `done` cycles, or while none is done the bring-ups' phase and frames.
    pub fn update(&mut self, done: u64, up: &BringupProgress) {
        let runs_up = up.runs_up.load(Ordering::Relaxed);
        let bringing_up = done == 0 && runs_up < self.runs;
        let msg = if bringing_up {
            format!(
                "bring-up: {}, {} frames, {runs_up} of {} up",
                up.phase().map_or("starting", |p| p.name()),
                up.frames.load(Ordering::Relaxed),
                ecsync_lab::scenario::plural(u64::from(self.runs), "run", "runs"),
            )
        } else {
            self.what.clone()
        };
        if !self.lines {
            self.bar.set_message(msg);
            self.bar.set_position(done);
            return;
        }
        if self.quiet || self.last_line.is_some_and(|t| t.elapsed() < LINE_EVERY) {
            return;
        }
        self.last_line = Some(Instant::now());
        let secs = self.started.elapsed().as_secs_f64();
        if bringing_up {
            eprintln!("ecsync: {secs:.0} s, {msg}");
        } else {
            let pct = 100.0 * done as f64 / self.total.max(1) as f64;
            let eta = if done > 0 {
                format!(
                    ", eta {:.0} s",
                    secs * (self.total - done.min(self.total)) as f64 / done as f64
                )
            } else {
                String::new()
            };
            eprintln!(
                "ecsync: {secs:.0} s, {msg}: {pct:.0} % ({done} of {} cycles){eta}",
                self.total
            );
        }
    }

    /// Prints `line` without tearing the bar.
    pub fn say(&self, line: &str) {
        self.bar.suspend(|| eprintln!("{line}"));
    }

    /// Removes the bar.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
