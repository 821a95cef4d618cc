//! Progress on stderr (indicatif) and Ctrl-C cancellation for long solves and renders.

use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use scene::SolveSettings;

use crate::engine::timing;
use solver::SolveControl;

/// A spinner that shows the solve's predicted time from before its first work
/// ([`prediction`](Self::prediction): the model `volrad info` prints), then the iteration,
/// residual and time left at the rate of convergence.
pub struct SolveProgress {
    bar: ProgressBar,
    tolerance: f64,
    max_iterations: usize,
}

impl SolveProgress {
    pub fn start(settings: &SolveSettings, quiet: bool) -> SolveProgress {
        let bar = if quiet {
            ProgressBar::hidden()
        } else {
            let bar = ProgressBar::new_spinner();
            bar.set_style(
                ProgressStyle::with_template("{spinner} [{elapsed_precise}{prefix}] {msg}")
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
            max_iterations: settings.max_iterations,
        }
    }

    /// What the solve calls with its predicted time (`SolveHooks::on_prediction`): shown
    /// beside the elapsed time from then on.
    pub fn prediction(&self) -> Arc<crate::engine::PredictionFn> {
        let bar = self.bar.clone();
        Arc::new(move |predicted: &timing::TimeEstimate| {
            bar.set_prefix(format!(
                ", about {} predicted",
                timing::duration_text(predicted.total())
            ))
        })
    }

    /// A solver control whose progress callback updates this spinner.
    /// The message shows, from the second iteration on, the iterations and time left at the
    /// mean rate of convergence so far.
    pub fn control(&self) -> SolveControl {
        let bar = self.bar.clone();
        let tol = self.tolerance;
        let max_iterations = self.max_iterations;
        // The first report of the current phase: each channel's iterations start again.
        let first: Arc<std::sync::Mutex<Option<(usize, f64, Instant)>>> = Arc::default();
        let phase_first = Arc::clone(&first);
        let phase_bar = self.bar.clone();
        SolveControl::new()
            .with_phase(move |phase| {
                *phase_first.lock().unwrap_or_else(|e| e.into_inner()) = None;
                phase_bar.set_message(format!("{phase}; Ctrl-C cancels"));
            })
            .with_progress(move |iteration, residual| {
                let mut first = first.lock().unwrap_or_else(|e| e.into_inner());
                let start = *first.get_or_insert((iteration, residual, Instant::now()));
                let left = time_left(
                    (start.0, start.1),
                    (iteration, residual),
                    start.2.elapsed(),
                    tol,
                    max_iterations,
                )
                .map(|(n, t)| format!(", about {n} more ({})", timing::duration_text(t)))
                .unwrap_or_default();
                let residual = format!("relative residual {residual:.3e} (target {tol:.1e})");
                bar.set_message(format!(
                    "iteration {iteration}: {residual}{left}; Ctrl-C cancels"
                ));
            })
    }

    pub fn finish(self) {
        self.bar.finish_and_clear();
    }
}

/// Iterations and time left until the residual reaches `tolerance`, at the mean rate of
/// convergence between `first` and `now` (iteration, residual), which took `elapsed`; `None`
/// before there is a rate, or when the residual is not falling. At most the iterations left
/// before `max_iterations`.
fn time_left(
    first: (usize, f64),
    now: (usize, f64),
    elapsed: Duration,
    tolerance: f64,
    max_iterations: usize,
) -> Option<(usize, Duration)> {
    let steps = now.0.checked_sub(first.0).filter(|&n| n > 0)?;
    if !(first.1 > 0.0 && now.1 > 0.0 && tolerance > 0.0) {
        return None;
    }
    let rate = (now.1 / first.1).powf(1.0 / steps as f64);
    if !(rate.is_finite() && rate < 1.0) {
        return None;
    }
    let left = if now.1 <= tolerance {
        0
    } else {
        // Rounded up, but not for the last bit of floating-point noise.
        ((tolerance / now.1).ln() / rate.ln() - 1e-9).ceil() as usize
    };
    let left = left.min(max_iterations.saturating_sub(now.0));
    Some((left, elapsed.mul_f64(left as f64 / steps as f64)))
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_time_left_follows_the_rate_of_convergence() {
        // Residual 1 → 1e-2 over 4 iterations in 2 s: a factor 10 every 2 iterations, so
        // 1e-6 is 8 iterations (4 s) away.
        let (n, t) = time_left((1, 1.0), (5, 1e-2), Duration::from_secs(2), 1e-6, 1000).unwrap();
        assert_eq!(n, 8);
        assert!((t.as_secs_f64() - 4.0).abs() < 1e-9);
        // Capped by the iterations left.
        assert_eq!(
            time_left((1, 1.0), (5, 1e-2), Duration::from_secs(2), 1e-6, 9)
                .unwrap()
                .0,
            4
        );
        // No rate yet, or not converging: no estimate.
        assert!(time_left((1, 1.0), (1, 1.0), Duration::ZERO, 1e-6, 100).is_none());
        assert!(time_left((1, 1.0), (3, 2.0), Duration::from_secs(1), 1e-6, 100).is_none());
        assert_eq!(
            timing::duration_text(Duration::from_secs(200)),
            "3 min 20 s"
        );
    }
}
