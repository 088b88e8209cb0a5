use crate::error::{Error, Result};

/// Residuals and Jacobian at a point: L = Σ rᵢ², ∇L = 2 Jᵀ r.
#[derive(Clone, Debug, PartialEq)]
pub struct Evaluation {
    pub residuals: Vec<f64>,
    /// m × n, row-major: `jacobian[i * n + j]` = ∂rᵢ/∂x_j.
    pub jacobian: Vec<f64>,
    pub n: usize,
}

impl Evaluation {
    pub fn new(residuals: Vec<f64>, jacobian: Vec<f64>, n: usize) -> Self {
        Evaluation { residuals, jacobian, n }
    }
    pub fn m(&self) -> usize {
        self.residuals.len()
    }
    /// L = Σ rᵢ².
    pub fn value(&self) -> f64 {
        self.residuals.iter().map(|r| r * r).sum()
    }
    /// ∇L = 2 Jᵀ r.
    pub fn gradient(&self) -> Vec<f64> {
        let mut g = vec![0.0; self.n];
        for (i, r) in self.residuals.iter().enumerate() {
            for j in 0..self.n {
                g[j] += 2.0 * self.jacobian[i * self.n + j] * r;
            }
        }
        g
    }
    /// Shape and finiteness check; the error names the first bad entry.
    pub fn check(&self, n: usize) -> Result<()> {
        if self.n != n || self.jacobian.len() != self.residuals.len() * n {
            return Err(Error::invalid(format!(
                "loss returned {} residuals with a {}-entry Jacobian for {n} parameters",
                self.residuals.len(),
                self.jacobian.len()
            )));
        }
        if let Some(i) = self.residuals.iter().position(|r| !r.is_finite()) {
            return Err(Error::invalid(format!("loss residual {i} is {} (not finite)", self.residuals[i])));
        }
        if let Some(e) = self.jacobian.iter().position(|r| !r.is_finite()) {
            return Err(Error::invalid(format!("loss gradient ∂r{}/∂x{} is {} (not finite)", e / n, e % n, self.jacobian[e])));
        }
        Ok(())
    }
    /// Parameters whose Jacobian column is identically zero.
    pub fn insensitive(&self) -> Vec<usize> {
        (0..self.n).filter(|&j| (0..self.m()).all(|i| self.jacobian[i * self.n + j] == 0.0)).collect()
    }
}

/// A merit function: residuals and Jacobian at `x`; `iteration` lets terms change with the iteration
/// (the paper's glass-distance weight grows with it).
pub trait Loss {
    fn evaluate(&mut self, x: &[f64], iteration: usize) -> Result<Evaluation>;
}

impl<F: FnMut(&[f64], usize) -> Result<Evaluation>> Loss for F {
    fn evaluate(&mut self, x: &[f64], iteration: usize) -> Result<Evaluation> {
        self(x, iteration)
    }
}

/// Box bounds lower ≤ x ≤ upper (±∞ allowed).
#[derive(Clone, Debug, PartialEq)]
pub struct Bounds {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

impl Bounds {
    pub fn unbounded(n: usize) -> Self {
        Bounds { lower: vec![f64::NEG_INFINITY; n], upper: vec![f64::INFINITY; n] }
    }
    pub fn new(lower: Vec<f64>, upper: Vec<f64>) -> Result<Self> {
        if lower.len() != upper.len() {
            return Err(Error::invalid(format!("bounds: {} lower vs {} upper values", lower.len(), upper.len())));
        }
        for (i, (l, u)) in lower.iter().zip(&upper).enumerate() {
            if l.is_nan() || u.is_nan() || l > u {
                return Err(Error::invalid(format!("bounds of parameter {i}: [{l}, {u}] is empty or NaN")));
            }
        }
        Ok(Bounds { lower, upper })
    }
    pub fn clamp(&self, x: &mut [f64]) {
        for (j, v) in x.iter_mut().enumerate() {
            *v = v.clamp(self.lower[j], self.upper[j]);
        }
    }
    pub(crate) fn check(&self, n: usize) -> Result<()> {
        if n == 0 {
            return Err(Error::invalid("optimisation with no free parameters"));
        }
        if self.lower.len() != n || self.upper.len() != n {
            return Err(Error::invalid(format!("bounds for {} parameters, {n} free", self.lower.len())));
        }
        Ok(())
    }
}

/// Outcome of an optimisation: the best point seen and how it went.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct OptimReport {
    pub x: Vec<f64>,
    pub loss: f64,
    pub initial_loss: f64,
    pub iterations: usize,
    /// Loss after each iteration.
    pub history: Vec<f64>,
    /// Parameters the loss does not depend on (zero Jacobian column at the start): left unchanged.
    pub insensitive: Vec<usize>,
    pub stop_reason: String,
    pub warnings: Vec<String>,
}

/// Solve A x = b (n × n, row-major) by Gaussian elimination with partial pivoting; `None` if singular.
pub(crate) fn solve_dense(mut a: Vec<f64>, mut b: Vec<f64>, n: usize) -> Option<Vec<f64>> {
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i * n + c].abs().total_cmp(&a[j * n + c].abs()))?;
        if !(a[p * n + c].abs() > 0.0) {
            return None;
        }
        if p != c {
            for k in 0..n {
                a.swap(p * n + k, c * n + k);
            }
            b.swap(p, c);
        }
        for r in c + 1..n {
            let f = a[r * n + c] / a[c * n + c];
            if f != 0.0 {
                for k in c..n {
                    a[r * n + k] -= f * a[c * n + k];
                }
                b[r] -= f * b[c];
            }
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|k| a[r * n + k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r * n + r];
    }
    x.iter().all(|v| v.is_finite()).then_some(x)
}
