//! Every progress bar of the binary lives in one `MultiProgress`, so that a command that runs
//! others (`demo`) can keep its own bar across theirs: the steps' bars appear under it and go,
//! the demo's stays on top. Lines printed through [`line`] go above the bars instead of through
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
