//! The recording lane trace: [`LANES`] rays through a path with the production lane kernel
//! ([`super::block::trace_block`], the same operations and results, bit for bit the scalar kernel), keeping
//! at every step the per-lane state a reverse (adjoint) sweep needs — a structure of arrays, one
//! [`StepLanes`] per path step ([`LaneTape`]). It is the lane twin of
//! [`crate::diff::adjoint::AdjointPlan::trace`]; [`crate::diff::adjoint_lanes`] sweeps the tape backwards.
//!
//! ```
//! use diffcassi::tracer::simd::{trace_block_recording, Block, LaneTape, LANES};
//! use diffcassi::tracer::SimdLevel;
//! use glam::DVec3;
//! let sys = diffcassi::system::SequentialSystem::build(&diffcassi::presets::spec("sp")?)?;
//! let n = sys.indices(520.0)?;
//! let mut b = Block::default();
//! b.set(0, DVec3::ZERO, DVec3::Z);
//! let mut tape = LaneTape::default();
//! trace_block_recording(SimdLevel::detect(), &sys, &[n.as_slice(); LANES], &mut b, &mut tape);
//! assert!(b.result(0).is_ok());
//! assert!(tape.steps().len() >= 3); // one state per path step
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::block::{trace_block, Block, StepRecorder};
use super::lanes::{Lf, L3, LANES};
use super::{at_level, LaneKernel, SimdLevel};
use crate::system::{PathStep, SequentialSystem};

/// One path step's state for every lane (lanes that stopped earlier hold meaningless values).
#[derive(Clone, Copy, Debug)]
pub struct StepLanes {
    /// p − o and d in the previous frame (before the frame change).
    pub pr: L3,
    pub d0: L3,
    /// The incoming unit direction, the hit point, its unit normal (as `intersect` gives it) and the
    /// distance from the frame-changed origin, in the step's frame.
    pub d: L3,
    pub q: L3,
    pub normal: L3,
    pub t: Lf,
}

/// The per-step states of one block's trace (reused from block to block: no allocation once grown).
/// After a trace, [`LaneTape::steps`] holds the steps traced (all of the path when any lane arrived).
#[derive(Clone, Debug, Default)]
pub struct LaneTape {
    /// Storage for the longest trace so far; the first `len` are this trace's.
    states: Vec<StepLanes>,
    len: usize,
}

impl LaneTape {
    /// The states of the steps traced, in path order.
    #[inline]
    pub fn steps(&self) -> &[StepLanes] {
        &self.states[..self.len]
    }
}

#[inline(always)]
fn store3(dst: &mut L3, v: &L3) {
    (dst.x, dst.y, dst.z) = (v.x, v.y, v.z);
}

impl StepRecorder<f64, LANES> for LaneTape {
    #[inline(always)]
    fn record(&mut self, s: usize, pr: &L3, d0: &L3, d: &L3, q: &L3, normal: &L3, t: &Lf) {
        // `Recording` empties the tape before each trace and steps arrive in order: step s is kept at s,
        // in place (no state built and copied: each lane array is stored from where the trace has it).
        debug_assert_eq!(s, self.len);
        if s == self.states.len() {
            let z = L3 { x: Lf::splat(0.0), y: Lf::splat(0.0), z: Lf::splat(0.0) };
            self.states.push(StepLanes { pr: z, d0: z, d: z, q: z, normal: z, t: Lf::splat(0.0) });
        }
        let st = &mut self.states[s];
        store3(&mut st.pr, pr);
        store3(&mut st.d0, d0);
        store3(&mut st.d, d);
        store3(&mut st.q, q);
        store3(&mut st.normal, normal);
        st.t = *t;
        self.len = s + 1;
    }
}

struct Recording<'a> {
    path: &'a [PathStep],
    n: &'a [&'a [f64]; LANES],
    b: &'a mut Block,
    tape: &'a mut LaneTape,
}

impl LaneKernel for Recording<'_> {
    type Output = ();
    #[inline(always)]
    fn run(self) {
        self.tape.len = 0;
        trace_block(self.path, self.n, self.b, self.tape)
    }
}

/// Trace the live lanes of `b` (unit directions, loaded with [`Block::set`]) through `sys` at `level`,
/// `n[k]` lane k's indices, keeping each step's state in `tape`. The block's results are those of
/// [`super::trace_block`] (the same code).
pub fn trace_block_recording(level: SimdLevel, sys: &SequentialSystem, n: &[&[f64]; LANES], b: &mut Block, tape: &mut LaneTape) {
    at_level(level, Recording { path: &sys.path, n, b, tape })
}
