//! Progress on stderr (indicatif) and Ctrl-C cancellation for long solves and renders.

use std::sync::{Arc, OnceLock};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use scene::SolveSettings;
use solver::SolveControl;

/// A spinner that shows the iteration and residual of the running solve.
pub struct SolveProgress {
    bar: ProgressBar,
    tolerance: f64,
}

impl SolveProgress {
    pub fn start(settings: &SolveSettings, quiet: bool) -> SolveProgress {
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            let bar = ProgressBar::new_spinner();
            bar.set_style(
                ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
                    .unwrap_or_else(|_| ProgressStyle::default_spinner()),
            );
            bar.enable_steady_tick(Duration::from_millis(200));
            bar.set_message(format!(
                "solving ({}); Ctrl-C cancels",
                settings.method.name()
            ));
            bar
        };
        SolveProgress {
            bar,
            tolerance: settings.tolerance,
        }
    }

    /// A solver control whose progress callback updates this spinner.
    pub fn control(&self) -> SolveControl {
        let bar = self.bar.clone();
        let tol = self.tolerance;
        SolveControl::new().with_progress(move |iteration, residual| {
            bar.set_message(format!(
                "iteration {iteration}: relative residual {residual:.3e} (target {tol:.1e}); Ctrl-C cancels"
            ));
        })
    }

    pub fn finish(self) {
        self.bar.finish_and_clear();
    }
}

/// The control the Ctrl-C handler cancels; replaced by each new solve.
static CURRENT: OnceLock<std::sync::Mutex<Option<Arc<SolveControl>>>> = OnceLock::new();

/// Makes Ctrl-C cancel `control` (the solve stops at its next iteration and reports it).
/// A second Ctrl-C exits at once.
pub fn cancel_on_ctrl_c(control: Arc<SolveControl>) {
    let slot = CURRENT.get_or_init(|| {
        let _ = ctrlc::set_handler(|| {
            let slot = CURRENT
                .get()
                .and_then(|m| m.lock().ok().and_then(|g| g.clone()));
            match slot {
                Some(c) if !c.is_cancelled() => {
                    eprintln!("\ncancelling (Ctrl-C again to quit at once)");
                    c.cancel();
                }
                _ => std::process::exit(130),
            }
        });
        std::sync::Mutex::new(None)
    });
    if let Ok(mut g) = slot.lock() {
        *g = Some(control);
    }
}

/// A bar over the rows of a long render (path tracing), with an estimate of the time left;
/// Ctrl-C cancels it through a [`SolveControl`] as it does a solve.
pub struct RowsProgress {
    bar: ProgressBar,
    control: Arc<SolveControl>,
}

impl RowsProgress {
    pub fn start(rows: u64, what: &str, quiet: bool) -> RowsProgress {
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            let bar = ProgressBar::new(rows);
            bar.set_style(
                ProgressStyle::with_template(
                    "{spinner} [{elapsed_precise}] {msg} {bar:30} {pos}/{len} rows, {eta} left",
                )
                .unwrap_or_else(|_| ProgressStyle::default_bar()),
            );
            bar.set_message(format!("{what}; Ctrl-C cancels"));
            bar.enable_steady_tick(Duration::from_millis(200));
            bar
        };
        let control = Arc::new(SolveControl::new());
        cancel_on_ctrl_c(control.clone());
        RowsProgress { bar, control }
    }

    /// Records `rows` finished; `false` once Ctrl-C asked to stop.
    pub fn update(&self, rows: u64) -> bool {
        self.bar.set_position(rows);
        !self.control.is_cancelled()
    }

    pub fn finish(self) {
        self.bar.finish_and_clear();
    }
}
