// The large banded test problem of the NLP solver, shared by its unit tests
// (`src/nlp/tests.rs`) and its benchmark (`benches/nlp.rs`) through `include!`: the
// includer brings `NlpProblem` into scope.

/// Discretised double-well smoothing: states x₀..x_K, noises w₀..w_{K−1},
/// x_{k+1} = x_k + h (x_k − x_k³) + h w_k (K equality constraints), minimise
/// ½ h Σ w_k² + ½ Σ_{k ∈ obs} (y_k − x_k)² / r with an observation every `stride` steps.
/// Variables are ordered (x₀..x_K, w₀..w_{K−1}).
struct DoubleWell {
    k: usize,
    h: f64,
    r: f64,
    stride: usize,
    y: Vec<f64>,
}

impl DoubleWell {
    fn new(k: usize) -> Self {
        let h = 0.05;
        // deterministic observations switching between the wells, with a deterministic
        // pseudo-random perturbation
        let y = (0..=k)
            .map(|i| {
                let t = i as f64 * h;
                (3.0 * (0.02 * t).sin()).tanh() + 0.5 * ((i as f64) * 12.9898).sin()
            })
            .collect();
        Self { k, h, r: 0.1, stride: 20, y }
    }
    fn observed(&self, i: usize) -> bool {
        i.is_multiple_of(self.stride)
    }
}

impl NlpProblem for DoubleWell {
    fn num_variables(&self) -> usize {
        2 * self.k + 1
    }
    fn num_constraints(&self) -> usize {
        self.k
    }
    fn initial_point(&self, w: &mut [f64]) {
        // all states in the left well, no noise: far from the smoothed path, which visits
        // both wells
        let k = self.k;
        w[..=k].fill(-1.0);
        w[k + 1..].fill(0.0);
    }
    fn objective(&mut self, w: &[f64]) -> f64 {
        let (x, nz) = w.split_at(self.k + 1);
        let mut f = 0.5 * self.h * nz.iter().map(|v| v * v).sum::<f64>();
        for i in (0..=self.k).filter(|&i| self.observed(i)) {
            f += 0.5 * (self.y[i] - x[i]).powi(2) / self.r;
        }
        f
    }
    fn gradient(&mut self, w: &[f64], grad: &mut [f64]) {
        let k = self.k;
        grad.fill(0.0);
        for i in (0..=k).filter(|&i| self.observed(i)) {
            grad[i] = (w[i] - self.y[i]) / self.r;
        }
        for j in 0..k {
            grad[k + 1 + j] = self.h * w[k + 1 + j];
        }
    }
    fn constraints(&mut self, w: &[f64], c: &mut [f64]) {
        let k = self.k;
        for j in 0..k {
            let x = w[j];
            c[j] = w[j + 1] - x - self.h * (x - x * x * x) - self.h * w[k + 1 + j];
        }
    }
    fn jacobian_structure(&self) -> Vec<(u32, u32)> {
        let k = self.k;
        (0..k as u32).flat_map(|j| [(j, j), (j, j + 1), (j, k as u32 + 1 + j)]).collect()
    }
    fn jacobian_values(&mut self, w: &[f64], values: &mut [f64]) {
        for j in 0..self.k {
            let x = w[j];
            values[3 * j] = -1.0 - self.h * (1.0 - 3.0 * x * x);
            values[3 * j + 1] = 1.0;
            values[3 * j + 2] = -self.h;
        }
    }
    fn hessian_structure(&self) -> Vec<(u32, u32)> {
        (0..2 * self.k as u32 + 1).map(|i| (i, i)).collect()
    }
    fn hessian_values(&mut self, w: &[f64], s: f64, lambda: &[f64], values: &mut [f64]) {
        let k = self.k;
        for i in 0..=k {
            let mut v = if self.observed(i) { s / self.r } else { 0.0 };
            if i < k {
                // ∂²c_i/∂x_i² = 6 h x_i
                v += lambda[i] * 6.0 * self.h * w[i];
            }
            values[i] = v;
        }
        for j in 0..k {
            values[k + 1 + j] = s * self.h;
        }
    }
}
