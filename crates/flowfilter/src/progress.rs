//! Progress of long commands: an indicatif bar on a terminal, plain lines at every tenth in
//! logs and CI.

use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;

/// A progress bar over `total` items; when stderr is not a terminal (logs, CI) indicatif draws
/// nothing and [`advance`] prints a plain line at every tenth instead.
pub fn bar(total: usize, unit: &str) -> ProgressBar {
    let bar = ProgressBar::new(total as u64);
    bar.set_style(
        ProgressStyle::with_template(&format!("{{msg}} [{{bar:40}}] {{pos}}/{{len}} {unit}, {{elapsed}}, eta {{eta}}"))
            .expect("valid template"),
    );
    bar
}

/// Move the bar to `done` items (called from worker threads, in any order).
pub fn advance(bar: &ProgressBar, done: usize) {
    let (before, len) = (bar.position(), bar.length().unwrap_or(0));
    bar.set_position(before.max(done as u64));
    let tenth = len.div_ceil(10).max(1);
    if !std::io::stderr().is_terminal() && (done as u64) / tenth > before / tenth {
        eprintln!("{}: {done}/{len}", bar.message());
    }
}

/// A spinner with the elapsed time for one long step (`message`): drawn on a terminal; in logs
/// and CI one plain line says the step started. Finish it with `finish_and_clear`.
pub fn spinner(message: String) -> ProgressBar {
    if !std::io::stderr().is_terminal() {
        eprintln!("{message} ...");
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new_spinner();
    bar.set_style(ProgressStyle::with_template("{spinner} {msg} {elapsed}").expect("valid template"));
    bar.set_message(message);
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}
