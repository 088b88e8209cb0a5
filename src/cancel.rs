//! Stopping a long computation early: a [`Cancel`] token, handed to a render ([`crate::render::Renderer::with_cancel`],
//! polled before each scene row of every plane it traces), an operator build (the exact operator traces through
//! the same renderer) or a solve ([`crate::recon::pipeline::run_solver`], polled before each iteration's prior
//! step). A cancelled computation returns [`crate::Error::Interrupted`] at its next poll and nothing else: no
//! partial result, nothing changed that a following call reads (every poll sits between units of work that
//! write only their own buffers), so the next call gives the same numbers as a fresh one.
//!
//! The token is per call (no global flag): two calls running at once on different threads each have their own,
//! and cancelling one leaves the other running. Polling reads one atomic; it does not change what is computed,
//! so an uncancelled run is bit-identical to one without a token, for any thread count.
//!
//! ```
//! use diffcassi::cancel::Cancel;
//! let c = Cancel::new();
//! assert!(c.check().is_ok());
//! c.cancel();
//! assert!(matches!(c.check(), Err(diffcassi::Error::Interrupted)));
//! ```
use crate::error::{Error, Result};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// A cancellation request shared between the caller (who may [`Cancel::cancel`]) and the computation (which
/// polls [`Cancel::check`]). Clones share the request. `Default` is a fresh, uncancelled token.
#[derive(Clone, Debug, Default)]
pub struct Cancel(Arc<AtomicBool>);

impl Cancel {
    pub fn new() -> Self {
        Self::default()
    }

    /// Ask the computation holding this token (or a clone) to stop at its next poll. Cannot be undone.
    pub fn cancel(&self) {
        self.0.store(true, Ordering::SeqCst);
    }

    pub fn is_cancelled(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }

    /// `Err(Error::Interrupted)` once cancelled: the poll of a long loop.
    #[inline]
    pub fn check(&self) -> Result<()> {
        if self.is_cancelled() {
            Err(Error::Interrupted)
        } else {
            Ok(())
        }
    }
}

/// [`Cancel::check`] of an optional token (`None`: never cancelled).
#[inline]
pub fn check(c: Option<&Cancel>) -> Result<()> {
    c.map_or(Ok(()), Cancel::check)
}
