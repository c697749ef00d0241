//! Progress bars for long stages (hidden when stderr is not a terminal or in tests).

use indicatif::{ProgressBar, ProgressStyle};

/// A progress bar over `len` items labelled `stage`; hidden unless stderr is a terminal.
pub fn bar(len: u64, stage: &str) -> ProgressBar {
    let pb = if std::io::IsTerminal::is_terminal(&std::io::stderr()) {
        ProgressBar::new(len)
    } else {
        ProgressBar::hidden()
    };
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>12} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb.set_prefix(stage.to_string());
    pb
}

/// A progress bar over `len_bytes` bytes labelled `stage` (a file read front to back).
pub fn bytes_bar(len_bytes: u64, stage: &str) -> ProgressBar {
    let pb = bar(len_bytes, stage);
    pb.set_style(
        ProgressStyle::with_template(
            "{prefix:>12} [{bar:40}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> "),
    );
    pb
}
