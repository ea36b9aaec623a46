//! The progress line of a single estimate: on a terminal only, after the estimate has run for
//! [`DELAY`], one line on stderr rewritten in place (`\r`) at most every [`EVERY`] and cleared
//! at the end. Piped or redirected stderr gets nothing.

use std::io::{IsTerminal, Write};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use onsager::estimate::progress::ProgressEvent;
use onsager::estimate::{EstimationProblem, MethodRun};
use onsager::estimator::Estimator;
use onsager::model::observation::StateMeasurement;
use onsager::model::Sde;
use onsager::Result;

/// How long an estimate runs before the line appears.
const DELAY: Duration = Duration::from_secs(2);
/// The shortest interval between two updates of the line.
const EVERY: Duration = Duration::from_millis(250);

/// Runs `estimator` on `problem`, with the progress line when stderr is a terminal.
pub fn run_with_progress<S: Sde + ?Sized>(
    estimator: &Estimator,
    problem: &EstimationProblem<'_, S, StateMeasurement>,
) -> Result<MethodRun> {
    if !std::io::stderr().is_terminal() {
        return estimator.run(problem);
    }
    let line = Arc::new(ProgressLine {
        method: estimator.name(),
        start: Instant::now(),
        state: Mutex::new(Shown { last: None }),
    });
    let observer = {
        let line = Arc::clone(&line);
        Arc::new(move |event| line.update(event))
    };
    let run = estimator.run_observed(problem, observer);
    line.clear();
    run
}

/// The line's state.
struct ProgressLine {
    method: &'static str,
    start: Instant,
    state: Mutex<Shown>,
}

/// When the line was last written (`None`: not yet).
struct Shown {
    last: Option<Instant>,
}

impl ProgressLine {
    fn update(&self, event: ProgressEvent) {
        let now = Instant::now();
        let elapsed = now.duration_since(self.start);
        if elapsed < DELAY {
            return;
        }
        let Ok(mut shown) = self.state.try_lock() else { return };
        if shown.last.is_some_and(|t| now.duration_since(t) < EVERY) {
            return;
        }
        shown.last = Some(now);
        let what = match event {
            ProgressEvent::Iteration { iteration, merit } => {
                format!("iteration {iteration}, merit {merit:.6e}")
            }
            _ => String::new(),
        };
        let mut err = std::io::stderr().lock();
        let _ = write!(err, "\r\x1b[K{}: {what} ({:.0} s)", self.method, elapsed.as_secs_f64());
        let _ = err.flush();
    }

    fn clear(&self) {
        let shown = self.state.lock().map(|s| s.last.is_some()).unwrap_or(false);
        if shown {
            let mut err = std::io::stderr().lock();
            let _ = write!(err, "\r\x1b[K");
            let _ = err.flush();
        }
    }
}
