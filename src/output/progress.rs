//! The progress bar of runs and studies: drawn on stderr only for runs longer than a second and
//! never with `--quiet`. Solvers see it only as a [`crate::backend::Progress`] callback.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

pub struct ProgressReporter {
    bar: ProgressBar,
    started: Instant,
    quiet: bool,
    shown: AtomicBool,
}

impl ProgressReporter {
    /// A bar counting to `total` `unit`s (e.g. "member-intervals").
    pub fn new(total: u64, unit: &str, quiet: bool) -> ProgressReporter {
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::hidden());
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{{elapsed_precise}} [{{bar:40}}] {{pos}}/{{len}} {unit}, eta {{eta}}"
            ))
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        ProgressReporter {
            bar,
            started: Instant::now(),
            quiet,
            shown: AtomicBool::new(false),
        }
    }

    /// Counts `n` more units done (callable from worker threads).
    pub fn inc(&self, n: u64) {
        self.bar.inc(n);
        if !self.quiet
            && self.started.elapsed() > Duration::from_secs(1)
            && !self.shown.swap(true, Ordering::Relaxed)
        {
            self.bar.set_draw_target(ProgressDrawTarget::stderr());
        }
    }

    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}
