//! Optimisers over a least-squares merit function: [`adam`] (as the reference paper) and a bounded
//! [`levenberg_marquardt`] (Gauss–Newton with Marquardt damping), sharing the [`Loss`] API.
//!
//! A [`Loss`] returns residuals r(x) and their Jacobian J = ∂r/∂x; the merit is L = Σ rᵢ² and its
//! gradient 2Jᵀr. Any user merit function fits: weight a term by multiplying its residual by √w, and a
//! non-negative scalar term ℓ(x) is the residual √ℓ. Bounds are boxes; both optimisers keep x inside
//! (Adam by projection, Levenberg–Marquardt by holding parameters at an active bound).
//!
//! Degenerate problems are reported, not crashed on: no parameters is an error; a parameter with an
//! identically zero Jacobian column is listed in [`OptimReport::insensitive`] and left unchanged; a
//! non-finite residual or gradient at the start is an error naming the entry, and later a non-finite
//! trial point is rejected like a bad step.
//!
//! ```
//! use diffcassi::optim::{levenberg_marquardt, Bounds, Evaluation, LmOptions};
//! // Rosenbrock as residuals (1 − x, 10 (y − x²)).
//! let mut loss = |x: &[f64], _it: usize| -> diffcassi::Result<Evaluation> {
//!     Ok(Evaluation::new(vec![1.0 - x[0], 10.0 * (x[1] - x[0] * x[0])], vec![-1.0, 0.0, -20.0 * x[0], 10.0], 2))
//! };
//! let r = levenberg_marquardt(&mut loss, &[-1.2, 1.0], &Bounds::unbounded(2), &LmOptions::default())?;
//! assert!((r.x[0] - 1.0).abs() < 1e-8 && (r.x[1] - 1.0).abs() < 1e-8);
//! # Ok::<(), diffcassi::Error>(())
//! ```
mod adam;
mod lm;
mod loss;

pub use adam::*;
pub use lm::*;
pub use loss::*;
