//! `onsager estimate --method ekf|eks|ukf|uks|pem|particle`: the baselines.

use rand::rngs::StdRng;
use rand::SeedableRng;

use onsager::estimate::PathEstimate;
use onsager::kalman::{self, KalmanMethod, KalmanOptions, PemOptions};
use onsager::particle::{self, ParticleOptions};
use onsager::{Error, Result};

use super::estimate::{CliProblem, EstimateArgs, Method};

/// Runs a baseline method: `--dt` is the largest integration step (Runge–Kutta for the Kalman
/// methods, Euler–Maruyama for the particle filter), `--particles` the number of particles,
/// `--seed` the particle filter's seed, `--estimate` the parameters of the PEM.
pub fn run(args: &EstimateArgs, problem: &CliProblem<'_>) -> Result<PathEstimate> {
    let mut kalman_options = KalmanOptions::default();
    if let Some(dt) = args.dt {
        kalman_options = kalman_options.with_dt(dt);
    }
    let kalman_method = match args.method {
        Method::Ekf => Some(KalmanMethod::Ekf),
        Method::Eks => Some(KalmanMethod::Eks),
        Method::Ukf => Some(KalmanMethod::Ukf),
        Method::Uks => Some(KalmanMethod::Uks),
        _ => None,
    };
    if args.particles.is_some() && args.method != Method::Particle {
        return Err(Error::InvalidOption {
            name: "--particles".into(),
            reason: "is an option of `--method particle` only".into(),
        });
    }
    if let Some(method) = kalman_method {
        return kalman::estimate(problem, method, &kalman_options);
    }
    match args.method {
        Method::Pem => kalman::pem(problem, &PemOptions::default().with_kalman(kalman_options)),
        Method::Particle => {
            let mut options = ParticleOptions::default();
            if let Some(n) = args.particles {
                options = options.with_particles(n);
            }
            if let Some(dt) = args.dt {
                options = options.with_dt(dt);
            }
            let mut rng = StdRng::seed_from_u64(args.seed);
            particle::estimate(problem, &options, &mut rng)
        }
        other => Err(Error::InvalidOption {
            name: "--method".into(),
            reason: format!("{other:?} is not a baseline method"),
        }),
    }
}
