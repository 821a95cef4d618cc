//! Progress on stderr (indicatif) and Ctrl-C cancellation for long solves.

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
                    eprintln!("\ncancelling the solve (Ctrl-C again to quit at once)");
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
