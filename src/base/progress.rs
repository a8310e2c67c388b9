//! Progress reporting. Long work reports to an [`Observer`]; the command line
//! passes [`Bars`] (indicatif bars on stderr), tests and batch code [`Silent`].

use indicatif::{ProgressBar, ProgressStyle};
use std::sync::Mutex;

/// Receives the progress of one piece of work at a time.
pub trait Observer: Sync {
    /// Work named `label` of `total` units starts.
    fn begin(&self, _label: &str, _total: u64) {}
    /// `units` more are done.
    fn advance(&self, _units: u64) {}
    /// The work has ended (finished or stopped).
    fn end(&self) {}
}

/// Reports nothing.
pub struct Silent;

impl Observer for Silent {}

/// One progress bar per piece of work, on stderr.
#[derive(Default)]
pub struct Bars {
    current: Mutex<Option<ProgressBar>>,
}

impl Observer for Bars {
    fn begin(&self, label: &str, total: u64) {
        if let Ok(mut slot) = self.current.lock() {
            *slot = Some(bar(total, label));
        }
    }
    fn advance(&self, units: u64) {
        if let Ok(slot) = self.current.lock() {
            if let Some(pb) = slot.as_ref() {
                pb.inc(units);
            }
        }
    }
    fn end(&self) {
        if let Ok(mut slot) = self.current.lock() {
            if let Some(pb) = slot.take() {
                pb.finish_and_clear();
            }
        }
    }
}

/// The observer for a `show_progress` choice.
pub fn observer(show_progress: bool) -> &'static dyn Observer {
    static BARS: std::sync::OnceLock<Bars> = std::sync::OnceLock::new();
    if show_progress {
        BARS.get_or_init(Bars::default)
    } else {
        &Silent
    }
}

/// A progress bar on stderr; indicatif hides it when stderr is not a terminal
/// (batch jobs), so logs stay clean.
pub fn bar(len: u64, message: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:48} [{elapsed_precise}] {wide_bar} {percent:>3}%")
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb.set_message(message.to_string());
    pb
}
