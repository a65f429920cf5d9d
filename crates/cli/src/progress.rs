//! Every progress bar of the binary lives in one `MultiProgress`, so that a command that runs
//! others (`demo`) can keep its own bar across theirs: the steps' bars appear under it and go,
//! the demo's stays on top. Lines printed through [`line()`] go above the bars instead of through
//! them.

use indicatif::{MultiProgress, ProgressBar};
use std::sync::OnceLock;

fn multi() -> &'static MultiProgress {
    static MULTI: OnceLock<MultiProgress> = OnceLock::new();
    MULTI.get_or_init(MultiProgress::new)
}

/// A new bar of `len` steps, drawn with the others (below those already there).
pub fn bar(len: u64) -> ProgressBar {
    multi().add(ProgressBar::new(len))
}

/// A bar drawn above every other, for a command's overall progress.
pub fn top_bar(len: u64) -> ProgressBar {
    multi().insert(0, ProgressBar::new(len))
}

/// A line of text on stderr, above the bars. Where stderr is not a terminal the bars are hidden
/// (and so is `MultiProgress::println`): the line is written plainly, so that logs keep it.
pub fn line(text: &str) {
    if multi().is_hidden() {
        eprintln!("{text}");
    } else {
        let _ = multi().println(text);
    }
}

/// One labelled step of a command's work: on a terminal a bar that says what it counts
/// (`rendering the test views [00:00:12] ████░░ 120/480 rows (eta 36s)`); in a log (stderr not
/// a terminal, where bars are hidden) a line when it starts, at each quarter and when it ends,
/// so that a log says what the command was doing and for how long.
pub struct Step {
    bar: ProgressBar,
    label: String,
    len: u64,
    start: std::time::Instant,
    /// Quarters already logged (only where the bar is hidden).
    logged: std::sync::atomic::AtomicU64,
}

impl Step {
    /// A step of `len` `unit`s (`len` 0: a step without a count, shown as a spinner).
    pub fn new(label: &str, len: u64, unit: &str) -> Step {
        let bar = bar(len);
        let template = if len == 0 {
            format!("{{spinner}} {label} [{{elapsed_precise}}]")
        } else {
            format!("{label} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} {unit} (eta {{eta}})")
        };
        bar.set_style(indicatif::ProgressStyle::with_template(&template).expect("valid template"));
        if len == 0 {
            bar.enable_steady_tick(std::time::Duration::from_millis(200));
        }
        if multi().is_hidden() {
            if len == 0 {
                eprintln!("{label}…");
            } else {
                eprintln!("{label}: {len} {unit}…");
            }
        }
        Step {
            bar,
            label: label.to_string(),
            len,
            start: std::time::Instant::now(),
            logged: std::sync::atomic::AtomicU64::new(0),
        }
    }

    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        if self.len > 0 && multi().is_hidden() {
            let quarter = (4 * self.bar.position() / self.len).min(3);
            let before = self.logged.fetch_max(quarter, std::sync::atomic::Ordering::Relaxed);
            if quarter > before {
                eprintln!(
                    "{}: {}% ({:.0} s)",
                    self.label,
                    25 * quarter,
                    self.start.elapsed().as_secs_f64()
                );
            }
        }
    }

    /// The step is done: the bar goes, a log gets its time.
    pub fn finish(self) {
        self.bar.finish_and_clear();
        if multi().is_hidden() {
            eprintln!("{}: done in {:.1} s", self.label, self.start.elapsed().as_secs_f64());
        }
    }
}
