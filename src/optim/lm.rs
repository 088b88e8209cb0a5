use super::loss::{bound_warnings, insensitive_warning, parameter_name, solve_dense, Bounds, Loss, OptimReport};
use crate::error::Result;

/// Levenberg–Marquardt settings.
#[derive(Clone, Debug, PartialEq)]
pub struct LmOptions {
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the loss by less than this fraction.
    pub f_tol: f64,
    /// Stop when every free |∂L/∂x_j|·max(1, |x_j|) is below this.
    pub g_tol: f64,
    /// Stop when the step is below this (relative to 1 + |x|).
    pub x_tol: f64,
    pub initial_lambda: f64,
    /// The parameters' names for the warnings (empty: by index).
    pub names: Vec<String>,
}

impl Default for LmOptions {
    fn default() -> Self {
        LmOptions { max_iterations: 200, f_tol: 1e-15, g_tol: 1e-14, x_tol: 1e-14, initial_lambda: 1e-3, names: Vec::new() }
    }
}

/// Minimise Σ r² by Levenberg–Marquardt: (JᵀJ + λ D) δ = −Jᵀr with D = diag(JᵀJ) (Marquardt scaling,
/// floored), λ ÷3 after a good step and ×10 after a bad one. Bounds: the trial point is clamped, and a
/// parameter at a bound whose gradient pushes outward is held for that step.
pub fn levenberg_marquardt(loss: &mut dyn Loss, x0: &[f64], bounds: &Bounds, opts: &LmOptions) -> Result<OptimReport> {
    let n = x0.len();
    bounds.check(n)?;
    let mut x = x0.to_vec();
    bounds.clamp(&mut x);
    let mut e = loss.evaluate(&x, 0)?;
    e.check(n)?;
    let insensitive = e.insensitive();
    let initial_loss = e.value();
    let mut cost = initial_loss;
    let mut lambda = opts.initial_lambda;
    let mut history = Vec::new();
    let mut warnings = Vec::new();
    if !insensitive.is_empty() {
        warnings.push(insensitive_warning(&opts.names, &insensitive));
    }
    let name = |j: usize| parameter_name(&opts.names, j);
    for (j, span) in e.dependent() {
        let span: Vec<String> = span.into_iter().map(name).collect();
        warnings.push(format!(
            "{} moves the residuals as {} {} (its Jacobian column lies in their span, within {:e} rad): the data determine only a combination of them, not each value",
            name(j),
            span.join(", "),
            if span.len() == 1 { "does" } else { "do" },
            super::loss::DEPENDENT_TOLERANCE
        ));
    }
    let mut stop = "max_iterations".to_string();
    let mut converged = false;
    let mut it = 0;
    while it < opts.max_iterations {
        it += 1;
        let g = e.gradient();
        let m = e.m();
        // Free set: sensitive, and not pinned at a bound by its gradient.
        let free: Vec<usize> = (0..n)
            .filter(|j| !insensitive.contains(j))
            .filter(|&j| !((x[j] <= bounds.lower[j] && g[j] > 0.0) || (x[j] >= bounds.upper[j] && g[j] < 0.0)))
            .collect();
        if free.is_empty() {
            // Say which: a fit whose only parameter has no effect on the loss was reported "all parameters at
            // bounds" while it sat nowhere near one (a held-out battery, round 16).
            let held: Vec<String> = (0..n).filter(|j| !insensitive.contains(j)).map(name).collect();
            let none: Vec<String> = insensitive.iter().map(|&j| name(j)).collect();
            stop = if held.is_empty() {
                format!("nothing to fit: no free parameter affects the loss ({} left unchanged)", none.join(", "))
            } else if none.is_empty() {
                format!("all parameters held at a bound by the gradient ({})", held.join(", "))
            } else {
                format!("nothing to fit: {} held at a bound by the gradient, {} not affecting the loss", held.join(", "), none.join(", "))
            };
            break;
        }
        if free.iter().all(|&j| (g[j] * x[j].abs().max(1.0)).abs() < opts.g_tol * (1.0 + cost)) {
            stop = "gradient below g_tol".into();
            break;
        }
        let nf = free.len();
        let mut a = vec![0.0; nf * nf];
        let mut b = vec![0.0; nf];
        for (p, &jp) in free.iter().enumerate() {
            b[p] = -0.5 * g[jp];
            for (q, &jq) in free.iter().enumerate() {
                a[p * nf + q] = (0..m).map(|i| e.jacobian[i * n + jp] * e.jacobian[i * n + jq]).sum();
            }
        }
        let max_diag = (0..nf).map(|p| a[p * nf + p]).fold(0.0, f64::max);
        let mut accepted = false;
        while lambda < 1e16 {
            let mut ad = a.clone();
            for p in 0..nf {
                ad[p * nf + p] += lambda * a[p * nf + p].max(1e-12 * max_diag);
            }
            let Some(delta) = solve_dense(ad, b.clone(), nf) else {
                lambda *= 10.0;
                continue;
            };
            let mut xt = x.clone();
            for (p, &j) in free.iter().enumerate() {
                xt[j] += delta[p];
            }
            bounds.clamp(&mut xt);
            let trial = match loss.evaluate(&xt, it) {
                Ok(t) if t.check(n).is_ok() => t,
                Ok(t) => {
                    warnings.push(format!("iteration {it}: rejected a trial point ({})", t.check(n).unwrap_err()));
                    lambda *= 10.0;
                    continue;
                }
                Err(err) => {
                    warnings.push(format!("iteration {it}: rejected a trial point ({err})"));
                    lambda *= 10.0;
                    continue;
                }
            };
            let tc = trial.value();
            if tc < cost {
                let step: f64 = free.iter().map(|&j| ((xt[j] - x[j]) / (1.0 + x[j].abs())).abs()).fold(0.0, f64::max);
                let gain = (cost - tc) / cost.max(f64::MIN_POSITIVE);
                x = xt;
                e = trial;
                cost = tc;
                lambda = (lambda / 3.0).max(1e-12);
                accepted = true;
                if gain < opts.f_tol || step < opts.x_tol {
                    stop = "converged (f_tol / x_tol)".into();
                    history.push(cost);
                    converged = true;
                    break;
                }
                break;
            }
            lambda *= 10.0;
        }
        if converged {
            break;
        }
        history.push(cost);
        if !accepted {
            stop = "converged: no further decrease (damping limit)".into();
            break;
        }
    }
    if warnings.len() > 20 {
        let extra = warnings.len() - 20;
        warnings.truncate(20);
        warnings.push(format!("… {extra} more"));
    }
    // Kept out of the truncation: a parameter on its bound is the one warning that must not be cut.
    warnings.extend(bound_warnings(&opts.names, &x, bounds, &insensitive));
    Ok(OptimReport { x, loss: cost, initial_loss, iterations: it, history, insensitive, stop_reason: stop, warnings })
}
