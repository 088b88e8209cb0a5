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
    /// Convergence criterion (Adam has no stopping test of its own: it runs its cosine schedule to the end).
    /// A run that ends on its iteration count is *converged* when its best loss fell by at most this fraction
    /// over the second half of the iterations — where the schedule anneals the step from half to
    /// `final_fraction` of the initial — and its last loss is within this fraction of the best; else it ends
    /// at its iteration limit, and a warning says so. See [`adam`].
    pub converged_fall: f64,
}

impl Default for AdamOptions {
    fn default() -> Self {
        AdamOptions { iterations: 500, learning_rate: vec![1e-2], final_fraction: 1e-3, beta1: 0.9, beta2: 0.999, epsilon: 1e-12, names: Vec::new(), converged_fall: 0.05 }
    }
}

/// Minimise Σ r² by Adam; x is projected onto the bounds after each step; the best point seen is returned.
/// A non-finite gradient stops the run with a warning (the best point so far is kept).
///
/// The stop reason says whether the run converged: Adam always runs its schedule to the end, so convergence
/// is judged on the loss history. The best loss after the run is compared with the best loss up to the middle
/// iteration (the start for a single iteration); a fall of more than [`AdamOptions::converged_fall`] of the
/// final best (or of 10⁻¹² of the initial loss, for a loss that reaches zero) means the run was still descending
/// when the step annealed away; and a loss where the schedule ends more than that fraction above the best
/// point seen means it was still oscillating (momentum overshoot). Either is "iteration limit", with a warning
/// naming the figure, instead of "converged".
/// Measured on `design amici` (round 21): the default 400 iterations fall 0.01–1.3 % over their second half
/// for the default seed and seeds 1, 2, 3, 7, 42 and 12345, while 1 and 200 iterations fall 26 % and 7800 %;
/// 30 iterations found their best (1.1e8, against 1.25e4 at 400) in the first half and end 108 % above it.
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
    // The loss where the schedule ended (after the last step), for the convergence test below.
    let mut end = history.last().copied().unwrap_or(initial_loss);
    if stop == "iterations done" {
        if let Ok(ev) = loss.evaluate(&x, done) {
            if ev.check(n).is_ok() {
                end = ev.value();
                if ev.value() < best {
                    best = ev.value();
                    best_x = x.clone();
                }
            }
        }
    }
    if stop == "iterations done" {
        // The history holds the loss before each step; `best` includes the point after the last one.
        let mid = history.len() / 2;
        let before = history.iter().take(mid + 1).copied().fold(initial_loss, f64::min);
        let fall = before - best;
        // Where the schedule ended above its best point (momentum overshoot, oscillation): not settled.
        let above = end - best;
        let scale = best.max(1e-12 * initial_loss);
        let tol = opts.converged_fall * scale;
        let pct = |v: f64| 100.0 * v / scale.max(f64::MIN_POSITIVE);
        let limit = 100.0 * opts.converged_fall;
        if fall > tol {
            stop = format!("iteration limit: best loss still falling ({before:.3e} → {best:.3e} over the second half of {done} iterations)");
            warnings.push(format!(
                "stopped at the iteration limit ({done}) without converging: the best loss fell {:.1} % over the second half of the iterations ({before:.4e} → {best:.4e}; converged means at most {limit:.0} %); raise the iteration count",
                pct(fall)
            ));
        } else if !(above <= tol) {
            stop = format!("iteration limit: not settled (the last loss {end:.3e} is above the best {best:.3e} after {done} iterations)");
            warnings.push(format!(
                "stopped at the iteration limit ({done}) without converging: the loss ends {:.1} % above the best point seen ({end:.4e} against {best:.4e}; converged means at most {limit:.0} %), still oscillating; raise the iteration count",
                pct(above)
            ));
        } else {
            stop = format!("converged: the best loss fell {:.2} % over the second half of {done} iterations and ends within {:.2} % of it (at most {limit:.0} % each)", pct(fall), pct(above));
        }
    }
    // A parameter that ends on its bound is named (a held-out battery, round 16).
    warnings.extend(super::loss::bound_warnings(&opts.names, &best_x, bounds, &insensitive));
    Ok(OptimReport { x: best_x, loss: best, initial_loss, iterations: done, history, insensitive, stop_reason: stop, warnings })
}
