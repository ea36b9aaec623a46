// The double-well record of the action and closure benchmarks (`benches/action.rs`,
// `benches/closure.rs`), shared through `include!`: D = 0.5, x(0) = −1, y ~ N(x(k), 0.2²) at
// k = 1, …, 40 (seed 0), with a flat prior on D ≥ 0 and x0 ~ N(−1, 0.2²).

struct Record {
    obs: onsager::model::observation::StateMeasurement,
    data: onsager::data::Dataset,
    priors: [onsager::model::prior::Prior; 1],
    x0: [onsager::model::prior::Prior; 1],
}

impl Record {
    fn new() -> Self {
        use onsager::model::observation::{Noise, StateMeasurement};
        use onsager::model::prior::Prior;
        use onsager::simulate::{sample_measurements_at, simulate, SimulateOptions};
        use rand::SeedableRng;
        let sigma = onsager::model::Param::Fixed(0.2);
        let obs = StateMeasurement::new(vec![0], vec!["y".into()], Noise::Gaussian { sigma });
        let mut rng = rand::rngs::StdRng::seed_from_u64(0);
        let dw = onsager::model::library::DoubleWell;
        let path = simulate(&dw, &[0.5], &[-1.0], &[], &SimulateOptions::new(0.0, 40.0, 0.005), &mut rng)
            .expect("simulation");
        let times: Vec<f64> = (1..=40).map(|k| k as f64).collect();
        let data = sample_measurements_at(&obs, &[0.5], &path, 1, &times, &mut rng).expect("measurements");
        Record {
            obs,
            data,
            priors: [Prior::flat().with_bounds(0.0, f64::INFINITY)],
            x0: [Prior::gaussian(-1.0, 0.2)],
        }
    }

    fn problem(
        &self,
    ) -> onsager::estimate::EstimationProblem<
        '_,
        onsager::model::library::DoubleWell,
        onsager::model::observation::StateMeasurement,
    > {
        onsager::estimate::EstimationProblem {
            sde: &onsager::model::library::DoubleWell,
            observation: &self.obs,
            theta: &[0.5],
            theta_prior: &self.priors,
            estimate: &[],
            x0_prior: &self.x0,
            z0_prior: &[],
            data: &self.data,
            t0: 0.0,
            seed: 0,
        }
    }
}
