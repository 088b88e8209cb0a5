//! The floor of Embree as the sequential tracer (issue 23 item 5; docs/nonsequential.md, "Fourth pass"):
//! how fast the same packet queries run when our side does (almost) nothing.
//!
//! [`EmbreeTracer::record_queries`](super::EmbreeTracer::record_queries) traces a batch and records
//! every packet query of its walk, per ray: the ray as queried (exact f64 ray, `tnear`, ray mask) and
//! Embree's answer (geometry, f32 distance) — a [`QueryLog`], laid out packet by packet, f32 rays
//! rounded, by [`QueryLog::packets`]. [`FloorScenes::replay`] then issues the *same* `rtcIntersect16`
//! packets (16 consecutive rays of each chunk, a lane in the query while it has a recorded step, as the
//! walk issues them) with a walk that only advances each lane to its next recorded step — no locate, no
//! Snell, no role dispatch, not even building the packet — through
//!
//! * [`FloorCallbacks::Oracle`]: the same scene (same user geometries with the same bounds, one primitive
//!   per surface, the same masks and absorber meshes), but each user geometry's callback only reports the
//!   hit read from the record (shim.cpp `diffcassi_oracle_intersect`, no surface solve): Embree's own
//!   traversal and callback dispatch for this workload, the floor no restructuring of our code can beat;
//! * [`FloorCallbacks::Exact`]: the tracer's real callbacks (the packet-wide f64 lane solve, `answer`),
//!   on the recorded exact rays.
//!
//! Either way every lane's answer is compared with the record (geometry and distance, bit for bit), so the
//! replay is checked to be the walk's workload.
//!
//! ```no_run
//! use diffcassi::prelude::*;
//! use diffcassi::tracer::embree::{EmbreeOptions, EmbreeTracer, FloorCallbacks, FloorScenes, SceneOptions};
//! let sys = SequentialSystem::build(&presets::spec("sp")?)?;
//! let rays = RayBatch::seeded_workload(&sys, 1000, &[450.0, 650.0], 1)?;
//! let (_traced, log) = EmbreeTracer::new(EmbreeOptions::default()).record_queries(&sys, &rays)?;
//! let floor = FloorScenes::new(&sys, &SceneOptions::default())?;
//! let replay = floor.replay(&log.packets(), FloorCallbacks::Oracle);
//! assert_eq!(replay.differing, 0);
//! println!("{} packet queries, {} lane queries", replay.packet_queries, replay.lane_queries);
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::scene::{OpticalScene, SceneOptions};
use super::wrapper::{with_flush_denormals, ExactRay, ExactRays, OracleAnswers, Ray};
use crate::error::Result;
use crate::system::SequentialSystem;
use rayon::prelude::*;

/// One query of one lane of the walk, and Embree's answer.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QueryStep {
    /// The exact ray (global frame, unit direction) the f32 ray rounds.
    pub exact: ExactRay,
    /// Start of the query's interval (mm along the ray).
    pub tnear: f32,
    /// The ray mask (the surface just left excluded).
    pub mask: u32,
    /// The geometry hit (`INVALID_GEOMETRY_ID`: a miss) and the f32 distance Embree returned.
    pub geom_id: u32,
    pub t: f32,
}

impl QueryStep {
    /// The f32 ray of the query, as the walk builds it (`Walk::ray`).
    #[inline]
    fn ray(&self) -> Ray {
        let mut r = Ray::new(self.exact.org.as_vec3().to_array(), self.exact.dir.as_vec3().to_array());
        r.mask = self.mask;
        r.tnear = self.tnear;
        r
    }
}

/// Every query of a traced batch, per ray (batch order), and the chunk size of the trace (its packets are
/// 16 consecutive rays of a chunk).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct QueryLog {
    pub steps: Vec<Vec<QueryStep>>,
    pub chunk_size: usize,
}

impl QueryLog {
    /// Lane queries (one ray in one packet query).
    pub fn lane_queries(&self) -> usize {
        self.steps.iter().map(Vec::len).sum()
    }

    /// The queries as the walk issued them, packet by packet, ready to hand to Embree: query `j` of a
    /// packet holds its lanes with more than `j` steps, each at its step `j`, the f32 rays already rounded
    /// (so a replay's own work is as close to none as possible).
    pub fn packets(&self) -> PacketLog {
        let chunk = self.chunk_size.max(16);
        let mut packets = Vec::new();
        for c in self.steps.chunks(chunk) {
            for lanes in c.chunks(16) {
                let depth = lanes.iter().map(Vec::len).max().unwrap_or(0);
                let queries = (0..depth)
                    .map(|j| {
                        let mut q = PacketQuery { rays: [Ray::new([0.0; 3], [0.0, 0.0, 1.0]); 16], valid: [false; 16], answers: OracleAnswers::default(), exact: [ExactRay::default(); 16] };
                        for (k, steps) in lanes.iter().enumerate() {
                            if let Some(s) = steps.get(j) {
                                (q.rays[k], q.valid[k], q.exact[k]) = (s.ray(), true, s.exact);
                                (q.answers.geom_id[k], q.answers.t[k]) = (s.geom_id, s.t);
                            }
                        }
                        q
                    })
                    .collect();
                packets.push(queries);
            }
        }
        PacketLog { packets, packets_per_chunk: chunk.div_ceil(16) }
    }
}

/// One recorded packet query: the f32 rays, the valid lanes, the recorded answers and the exact rays.
#[derive(Clone, Debug)]
struct PacketQuery {
    rays: [Ray; 16],
    valid: [bool; 16],
    answers: OracleAnswers,
    exact: [ExactRay; 16],
}

/// A [`QueryLog`] laid out packet by packet ([`QueryLog::packets`]), what [`FloorScenes::replay`] issues.
#[derive(Clone, Debug)]
pub struct PacketLog {
    packets: Vec<Vec<PacketQuery>>,
    /// Packets per rayon task (the trace's chunk of rays / 16).
    packets_per_chunk: usize,
}

/// Which callbacks answer a replay's queries.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FloorCallbacks {
    /// No query at all: the replay's own cost (reading the recorded packets), which the other two
    /// include besides Embree. Nothing is compared (`differing` stays 0).
    NoQuery,
    /// Report the recorded hit (no surface solve).
    Oracle,
    /// The tracer's analytic user geometry on the recorded exact rays.
    Exact,
}

/// What a replay did: packet queries issued, lanes queried, lanes whose answer differs from the record.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ReplayStats {
    pub packet_queries: usize,
    pub lane_queries: usize,
    pub differing: usize,
}

impl std::ops::Add for ReplayStats {
    type Output = ReplayStats;
    fn add(self, o: ReplayStats) -> ReplayStats {
        ReplayStats { packet_queries: self.packet_queries + o.packet_queries, lane_queries: self.lane_queries + o.lane_queries, differing: self.differing + o.differing }
    }
}

/// The tracer's scene of a system with its real callbacks, and the same scene with oracle callbacks.
pub struct FloorScenes {
    exact: OpticalScene,
    oracle: OpticalScene,
}

impl FloorScenes {
    /// Both scenes of `system` (analytic user geometry: `options.representation` must be
    /// [`SurfaceRepresentation::User`](super::SurfaceRepresentation::User)).
    pub fn new(system: &SequentialSystem, options: &SceneOptions) -> Result<Self> {
        Ok(FloorScenes { exact: OpticalScene::build(system, options)?, oracle: OpticalScene::build_oracle(system, options)? })
    }

    /// Replay `log`'s queries through `callbacks`, in parallel over the trace's chunks (as the tracer).
    pub fn replay(&self, log: &PacketLog, callbacks: FloorCallbacks) -> ReplayStats {
        log.packets
            .par_chunks(log.packets_per_chunk.max(1))
            .map(|c| with_flush_denormals(|| c.iter().map(|packet| self.replay_packet(packet, callbacks)).fold(ReplayStats::default(), |a, b| a + b)))
            .reduce(ReplayStats::default, |a, b| a + b)
    }

    /// One packet's queries, in order; each lane's answer is compared with the record.
    fn replay_packet(&self, queries: &[PacketQuery], callbacks: FloorCallbacks) -> ReplayStats {
        let mut stats = ReplayStats::default();
        let mut exact = ExactRays::<16>::default();
        for q in queries {
            stats.packet_queries += 1;
            stats.lane_queries += q.valid.iter().filter(|v| **v).count();
            let hits = match callbacks {
                FloorCallbacks::NoQuery => {
                    std::hint::black_box(q);
                    continue;
                }
                FloorCallbacks::Oracle => self.oracle.scene.intersect16_oracle(&q.rays, &q.valid, &q.answers),
                FloorCallbacks::Exact => {
                    exact.rays = q.exact;
                    self.exact.scene.intersect16_exact(&q.rays, &q.valid, false, Some(&exact))
                }
            };
            for k in (0..16).filter(|k| q.valid[*k]) {
                stats.differing += (hits[k].geom_id != q.answers.geom_id[k] || hits[k].t.to_bits() != q.answers.t[k].to_bits()) as usize;
            }
        }
        stats
    }
}
