//! What the iterative solvers share, below them in the import graph: their settings ([`config`]), their
//! result ([`record`]), the data term ([`data_term`]: the preconditioner, residual norms, input checks), the
//! stopping rules ([`stopping`]) and the noise level they compare with ([`noise`]), the prior step
//! ([`prior_step`]) and the bookkeeping of one run ([`run`]). The solvers ([`super::gap`], [`super::admm`])
//! import these modules; the dispatcher [`super::solver`] imports the solvers and re-exports these types
//! (`recon::solver::SolverConfig` and the rest keep their paths). Nothing here imports a solver or the
//! dispatcher: `scripts/check_import_cycles.py` checks that src/recon has no import circle
//! (tests/recon_import_graph.rs).
pub mod config;
pub mod data_term;
pub mod noise;
pub mod prior_step;
pub mod record;
pub mod run;
pub mod stopping;
