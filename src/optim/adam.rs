use super::loss::{insensitive_warning, Bounds, Loss, OptimReport};
use crate::error::{Error, Result};

/// Adam settings (Kingma & Ba), with a cosine-annealed step as in the reference paper's optimiser.
#[derive(Clone, Debug, PartialEq)]
pub struct AdamOptions {
    pub iterations: usize,
    /// Step size per parameter (parameter units); length 1 applies to all.
    pub learning_rate: Vec<f64>,
    /// Final step as a fraction of the initial (cosine annealing); 1 = constant.
    pub final_fraction: f64,
    pub beta1: f64,
    pub beta2: f64,
    pub epsilon: f64,
    /// The parameters' names for the warnings (empty: by index).
    pub names: Vec<String>,
}

impl Default for AdamOptions {
    fn default() -> Self {
        AdamOptions { iterations: 500, learning_rate: vec![1e-2], final_fraction: 1e-3, beta1: 0.9, beta2: 0.999, epsilon: 1e-12, names: Vec::new() }
    }
}

/// Minimise Σ r² by Adam; x is projected onto the bounds after each step; the best point seen is returned.
/// A non-finite gradient stops the run with a warning (the best point so far is kept).
pub fn adam(loss: &mut dyn Loss, x0: &[f64], bounds: &Bounds, opts: &AdamOptions) -> Result<OptimReport> {
    let n = x0.len();
    bounds.check(n)?;
    let lr: Vec<f64> = match opts.learning_rate.len() {
        1 => vec![opts.learning_rate[0]; n],
        l if l == n => opts.learning_rate.clone(),
        l => return Err(Error::invalid(format!("Adam: {l} learning rates for {n} parameters"))),
    };
    let mut x = x0.to_vec();
    bounds.clamp(&mut x);
    let e0 = loss.evaluate(&x, 0)?;
    e0.check(n)?;
    let insensitive = e0.insensitive();
    let initial_loss = e0.value();
    let (mut m, mut v) = (vec![0.0; n], vec![0.0; n]);
    let (mut best_x, mut best) = (x.clone(), initial_loss);
    let mut history = Vec::with_capacity(opts.iterations);
    let mut warnings = Vec::new();
    if !insensitive.is_empty() {
        warnings.push(insensitive_warning(&opts.names, &insensitive));
    }
    let mut stop = "iterations done".to_string();
    let mut e = e0;
    let mut done = 0;
    for it in 0..opts.iterations {
        if it > 0 {
            match loss.evaluate(&x, it).and_then(|e| e.check(n).map(|_| e)) {
                Ok(ev) => e = ev,
                Err(err) => {
                    warnings.push(format!("iteration {it}: {err}; stopped at the best point so far"));
                    stop = "non-finite loss or gradient".into();
                    break;
                }
            }
        }
        let value = e.value();
        if value < best {
            best = value;
            best_x = x.clone();
        }
        history.push(value);
        let g = e.gradient();
        let t = (it + 1) as i32;
        let progress = it as f64 / opts.iterations.max(1) as f64;
        let anneal = opts.final_fraction + (1.0 - opts.final_fraction) * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        for j in 0..n {
            if insensitive.contains(&j) {
                continue;
            }
            m[j] = opts.beta1 * m[j] + (1.0 - opts.beta1) * g[j];
            v[j] = opts.beta2 * v[j] + (1.0 - opts.beta2) * g[j] * g[j];
            let mh = m[j] / (1.0 - opts.beta1.powi(t));
            let vh = v[j] / (1.0 - opts.beta2.powi(t));
            x[j] -= lr[j] * anneal * mh / (vh.sqrt() + opts.epsilon);
        }
        bounds.clamp(&mut x);
        done = it + 1;
    }
    if stop == "iterations done" {
        if let Ok(ev) = loss.evaluate(&x, done) {
            if ev.check(n).is_ok() && ev.value() < best {
                best = ev.value();
                best_x = x.clone();
            }
        }
    }
    // A parameter that ends on its bound is named (a held-out battery, round 16).
    warnings.extend(super::loss::bound_warnings(&opts.names, &best_x, bounds, &insensitive));
    Ok(OptimReport { x: best_x, loss: best, initial_loss, iterations: done, history, insensitive, stop_reason: stop, warnings })
}
