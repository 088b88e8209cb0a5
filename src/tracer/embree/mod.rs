//! Embree 4.3 backend (feature `embree`, on by default): raw bindings generated from the installed headers
//! ([`sys`], with compile-time layout checks against the C compiler), a small safe RAII wrapper
//! ([`Device`], [`Geometry`], [`Scene`] → [`CommittedScene`], [`with_flush_denormals`]), the scene of solids
//! built from a sequential system ([`OpticalScene`]) and the non-sequential [`EmbreeTracer`] implementing
//! [`Tracer`](super::Tracer), and the floor benchmark's replay of its queries ([`FloorScenes`]).
mod floor;
mod next_hit;
mod scene;
pub mod sys;
mod tracer;
mod wrapper;

pub use floor::{FloorCallbacks, FloorScenes, PacketLog, QueryLog, QueryStep, ReplayStats};
pub use next_hit::EmbreeNextHit;
pub use scene::*;
pub use tracer::*;
pub use wrapper::*;
