//! Safe RAII wrapper over the Embree 4 C API.
//!
//! * [`Device`] is a cheap `Clone` (an `Arc` around the `RTCDevice`); every [`Geometry`], [`Scene`] and
//!   [`CommittedScene`] holds one, so the device is released last whatever order handles are dropped in.
//! * Tracing is only possible on a [`CommittedScene`], obtained from [`Scene::commit`] (which consumes the
//!   scene), so an uncommitted or modified-after-commit scene cannot be traced.
//! * Rays with non-finite components, a zero direction or `tnear > tfar` are reported as misses without
//!   being handed to Embree.
//! * Every query passes Embree an extended ray-query context ([`QueryContext`]): with
//!   [`CommittedScene::intersect16_exact`] / [`CommittedScene::intersect1_exact`] it carries the f64 rays
//!   behind the f32 ones ([`ExactRays`], indexed by the Embree ray ID = lane), so an analytic user
//!   geometry solves its surface once, on the exact ray, and leaves the roots for the caller's f64
//!   refinement (Mitsuba 3's split: a cheap preliminary hit, then the exact surface interaction).
use std::cell::Cell;
use std::ffi::{CStr, CString};
use std::sync::Arc;

use super::sys;

/// Embree's `RTC_INVALID_GEOMETRY_ID`: the `geom_id` of a miss.
pub const INVALID_GEOMETRY_ID: u32 = sys::RTC_INVALID_GEOMETRY_ID;

/// Embree's error codes (`enum RTCError`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum EmbreeErrorCode {
    Unknown,
    InvalidArgument,
    InvalidOperation,
    OutOfMemory,
    UnsupportedCpu,
    Cancelled,
    LevelZeroRaytracingSupportMissing,
    /// A code this wrapper does not know (newer Embree).
    Other(u32),
}

impl EmbreeErrorCode {
    fn from_raw(code: sys::RTCError) -> Option<Self> {
        Some(match code {
            sys::RTC_ERROR_NONE => return None,
            sys::RTC_ERROR_UNKNOWN => Self::Unknown,
            sys::RTC_ERROR_INVALID_ARGUMENT => Self::InvalidArgument,
            sys::RTC_ERROR_INVALID_OPERATION => Self::InvalidOperation,
            sys::RTC_ERROR_OUT_OF_MEMORY => Self::OutOfMemory,
            sys::RTC_ERROR_UNSUPPORTED_CPU => Self::UnsupportedCpu,
            sys::RTC_ERROR_CANCELLED => Self::Cancelled,
            sys::RTC_ERROR_LEVEL_ZERO_RAYTRACING_SUPPORT_MISSING => Self::LevelZeroRaytracingSupportMissing,
            other => Self::Other(other),
        })
    }

    /// The C name, e.g. `"RTC_ERROR_INVALID_ARGUMENT"`.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Unknown => "RTC_ERROR_UNKNOWN",
            Self::InvalidArgument => "RTC_ERROR_INVALID_ARGUMENT",
            Self::InvalidOperation => "RTC_ERROR_INVALID_OPERATION",
            Self::OutOfMemory => "RTC_ERROR_OUT_OF_MEMORY",
            Self::UnsupportedCpu => "RTC_ERROR_UNSUPPORTED_CPU",
            Self::Cancelled => "RTC_ERROR_CANCELLED",
            Self::LevelZeroRaytracingSupportMissing => "RTC_ERROR_LEVEL_ZERO_RAYTRACING_SUPPORT_MISSING",
            Self::Other(_) => "RTC_ERROR_(unknown code)",
        }
    }
}

/// An Embree error: the code and Embree's message (`rtcGetDeviceLastErrorMessage`), plus what we were doing.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("Embree {} while {context}: {message}", code.name())]
pub struct EmbreeError {
    pub code: EmbreeErrorCode,
    pub message: String,
    pub context: String,
}

impl EmbreeError {
    fn invalid(context: &str, message: impl Into<String>) -> Self {
        EmbreeError { code: EmbreeErrorCode::InvalidArgument, message: message.into(), context: context.into() }
    }
}

/// Reads (and clears) the error state of `device` (NULL: the thread's device-creation error).
fn take_error(device: sys::RTCDevice, context: &str) -> Result<(), EmbreeError> {
    // SAFETY: both functions accept NULL (thread-local state) or a live device.
    let code = unsafe { sys::rtcGetDeviceError(device) };
    match EmbreeErrorCode::from_raw(code) {
        None => Ok(()),
        Some(code) => {
            let msg = unsafe { sys::rtcGetDeviceLastErrorMessage(device) };
            let message = if msg.is_null() {
                String::new()
            } else {
                // SAFETY: Embree returns a NUL-terminated string valid until the next error.
                unsafe { CStr::from_ptr(msg) }.to_string_lossy().into_owned()
            };
            Err(EmbreeError { code, message, context: context.into() })
        }
    }
}

struct DeviceInner {
    raw: sys::RTCDevice,
}

impl Drop for DeviceInner {
    fn drop(&mut self) {
        // SAFETY: we own one reference, taken in Device::new.
        unsafe { sys::rtcReleaseDevice(self.raw) }
    }
}

// SAFETY: Embree devices are thread-safe (the API may be called from any thread).
unsafe impl Send for DeviceInner {}
unsafe impl Sync for DeviceInner {}

/// An Embree device (`rtcNewDevice`). Clones share it; it is released when the last clone and the last
/// geometry/scene made from it are dropped.
#[derive(Clone)]
pub struct Device {
    inner: Arc<DeviceInner>,
}

impl std::fmt::Debug for Device {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Device").field("raw", &self.inner.raw).finish()
    }
}

impl Device {
    /// `rtcNewDevice(config)`, e.g. `""`, `"threads=1"`, `"verbose=1,isa=avx2"`. A bad config string is an
    /// [`EmbreeError`] carrying Embree's message.
    pub fn new(config: &str) -> Result<Self, EmbreeError> {
        let cfg = CString::new(config)
            .map_err(|_| EmbreeError::invalid("creating the device", format!("config string {config:?} contains a NUL byte")))?;
        // SAFETY: valid NUL-terminated string.
        let raw = unsafe { sys::rtcNewDevice(cfg.as_ptr()) };
        let context = format!("creating the device with config {config:?}");
        if raw.is_null() {
            take_error(std::ptr::null_mut(), &context)?;
            return Err(EmbreeError { code: EmbreeErrorCode::Unknown, message: "rtcNewDevice returned NULL".into(), context });
        }
        let device = Device { inner: Arc::new(DeviceInner { raw }) };
        device.check(&context)?;
        Ok(device)
    }

    /// The version of the Embree library linked at build time (from the installed headers).
    pub fn embree_version() -> &'static str {
        env!("DIFFCASSI_EMBREE_VERSION")
    }

    /// Whether this Embree build honours ray masks (`RTC_DEVICE_PROPERTY_RAY_MASK_SUPPORTED`; on by
    /// default since Embree 4). The tracer relies on them to skip the surface a ray just left.
    pub fn supports_ray_masks(&self) -> bool {
        // SAFETY: live device; a property query has no side effects.
        unsafe { sys::rtcGetDeviceProperty(self.inner.raw, sys::RTC_DEVICE_PROPERTY_RAY_MASK_SUPPORTED) != 0 }
    }

    /// The raw handle (valid while `self` lives).
    pub fn raw(&self) -> sys::RTCDevice {
        self.inner.raw
    }

    /// Returns (and clears) the device's pending error, if any.
    pub fn check(&self, context: &str) -> Result<(), EmbreeError> {
        take_error(self.inner.raw, context)
    }

    fn same(&self, other: &Device) -> bool {
        Arc::ptr_eq(&self.inner, &other.inner)
    }
}

/// An analytic surface for Embree's user geometry (`RTC_GEOMETRY_TYPE_USER`, one primitive): the
/// callbacks Embree calls during BVH build (`bounds`) and traversal (`intersect`).
pub trait UserGeometry: Send + Sync {
    /// Conservative axis-aligned bounds (lower, upper) of the primitive, scene coordinates.
    fn bounds(&self) -> ([f32; 3], [f32; 3]);
    /// The closest hit of the ray `org + t·dir` with `tnear <= t <= tfar` (t in units of `dir`): its `t`
    /// and a (not necessarily unit) geometric normal, or `None`.
    fn intersect(&self, org: [f32; 3], dir: [f32; 3], tnear: f32, tfar: f32) -> Option<(f32, [f32; 3])>;
    /// The same query when the caller also gave the f64 ray behind the f32 one (`exact`, unit
    /// direction, same start): solve on the exact ray, report the hit's `t` on the f32 ray, and return
    /// the closed-form roots solved (in units of the exact ray) for the caller's refinement. The default,
    /// [`ExactAnswer::Unsupported`], makes the callback fall back to [`Self::intersect`].
    fn intersect_exact(&self, _org: [f32; 3], _dir: [f32; 3], _tnear: f32, _tfar: f32, _exact: &ExactRay) -> ExactAnswer {
        ExactAnswer::Unsupported
    }
    /// [`Self::intersect_exact`] for the `lanes.count` lanes of one callback at once (answer `k` into
    /// `out[k]`): an implementation may solve them together (SIMD lanes) but must give each lane the
    /// answer `intersect_exact` gives it, bit for bit, so packets and single rays agree. The default
    /// answers lane by lane.
    #[allow(clippy::needless_range_loop)] // lanes of several parallel arrays
    fn intersect_exact_lanes(&self, lanes: &UserLanes, out: &mut [ExactAnswer; USER_LANES]) {
        for k in 0..lanes.count {
            out[k] = self.intersect_exact(lanes.org[k], lanes.dir[k], lanes.tnear[k], lanes.tfar[k], &lanes.exact[k]);
        }
    }
}

/// Most lanes a user-geometry callback hands over at once (Embree's widest packet, `rtcIntersect16`).
pub const USER_LANES: usize = 16;

/// The lanes of one user-geometry callback that concern the geometry — valid, and a ray mask sharing a
/// bit with the geometry's — compacted: entry `k` is packet lane `lane[k]`, for `k < count`. Read from
/// Embree's packet in one call (shim.cpp `diffcassi_user_rays16`) instead of one call per lane.
#[derive(Clone, Debug)]
pub struct UserLanes {
    pub count: usize,
    pub lane: [u32; USER_LANES],
    pub org: [[f32; 3]; USER_LANES],
    pub dir: [[f32; 3]; USER_LANES],
    pub tnear: [f32; USER_LANES],
    pub tfar: [f32; USER_LANES],
    /// The ray ID: the caller's lane, which indexes its [`ExactRays`].
    pub id: [u32; USER_LANES],
    /// The exact ray behind each lane (filled when the query carries them).
    pub exact: [ExactRay; USER_LANES],
}

impl UserLanes {
    /// No lanes (the arrays zeroed).
    pub const EMPTY: UserLanes = UserLanes {
        count: 0,
        lane: [0; USER_LANES],
        org: [[0.0; 3]; USER_LANES],
        dir: [[0.0; 3]; USER_LANES],
        tnear: [0.0; USER_LANES],
        tfar: [0.0; USER_LANES],
        id: [0; USER_LANES],
        exact: [ExactRay { org: glam::DVec3::ZERO, dir: glam::DVec3::ZERO }; USER_LANES],
    };
}

/// The f64 ray behind lane `i` of an Embree query (global frame; `dir` unit; Embree's f32 ray is this
/// one rounded).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExactRay {
    pub org: glam::DVec3,
    pub dir: glam::DVec3,
}

/// What [`UserGeometry::intersect_exact`] found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ExactAnswer {
    /// This geometry cannot solve in closed form (e.g. an even asphere): use [`UserGeometry::intersect`].
    Unsupported,
    /// No hit in `[tnear, tfar]`.
    Miss,
    /// A hit at `t` on the f32 ray; `roots` are every root of the figure along the exact ray (ascending,
    /// in units of the exact ray), the hit's among them.
    Hit { t: f32, roots: [Option<f64>; 2] },
}

/// The roots a user geometry solved on lane `i`'s exact ray: those of the geometry that reported the
/// lane's closest hit (`geom_id`; [`INVALID_GEOMETRY_ID`] if no user geometry did).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolvedRoots {
    pub geom_id: u32,
    pub roots: [Option<f64>; 2],
}

impl SolvedRoots {
    pub const NONE: SolvedRoots = SolvedRoots { geom_id: INVALID_GEOMETRY_ID, roots: [None, None] };
}

/// The exact rays of one query (lane `i` = Embree ray ID `i`) and, per lane, the roots solved on them.
/// Queries run on the calling thread, so the callbacks write through `Cell`s.
#[derive(Debug)]
pub struct ExactRays<const K: usize> {
    pub rays: [ExactRay; K],
    pub solved: [Cell<SolvedRoots>; K],
}

impl<const K: usize> Default for ExactRays<K> {
    fn default() -> Self {
        ExactRays { rays: [ExactRay::default(); K], solved: std::array::from_fn(|_| Cell::new(SolvedRoots::NONE)) }
    }
}

impl<const K: usize> ExactRays<K> {
    /// The roots of lane `i`, if a user geometry left them for the closest hit on `geom_id`.
    pub fn roots_for(&self, i: usize, geom_id: u32) -> Option<[Option<f64>; 2]> {
        let s = self.solved[i].get();
        (s.geom_id == geom_id && geom_id != INVALID_GEOMETRY_ID).then_some(s.roots)
    }
}

/// Embree's ray-query context extended with the exact rays of the query (null: none). Embree hands the
/// context pointer to every callback, so the extension reaches the user geometry (Embree's documented
/// pattern for per-query user data).
#[repr(C)]
struct QueryContext {
    base: sys::RTCRayQueryContext,
    exact: *const ExactRay,
    solved: *const Cell<SolvedRoots>,
    lanes: u32,
}

impl QueryContext {
    fn new<const K: usize>(exact: Option<&ExactRays<K>>) -> Self {
        let mut base = sys::RTCRayQueryContext::default();
        // SAFETY: initialises the struct exactly as the installed header's rtcInitRayQueryContext does.
        unsafe { sys::diffcassi_rtcInitRayQueryContext(&mut base) };
        match exact {
            Some(e) => QueryContext { base, exact: e.rays.as_ptr(), solved: e.solved.as_ptr(), lanes: K as u32 },
            None => QueryContext { base, exact: std::ptr::null(), solved: std::ptr::null(), lanes: 0 },
        }
    }
}

/// The answers an oracle user geometry ([`Geometry::user_oracle`]) reports, per lane of a 16-wide query
/// (lane `i` = Embree ray ID `i`): the geometry that lane is to hit and the distance along its f32 ray
/// (`INVALID_GEOMETRY_ID`: no user geometry; a triangle geometry or a miss).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct OracleAnswers {
    pub geom_id: [u32; 16],
    pub t: [f32; 16],
}

impl Default for OracleAnswers {
    fn default() -> Self {
        OracleAnswers { geom_id: [INVALID_GEOMETRY_ID; 16], t: [f32::INFINITY; 16] }
    }
}

/// Embree's ray-query context extended with the oracle's answers; the same layout as
/// `DiffcassiOracleContext` in shim.cpp, which reads it in `diffcassi_oracle_intersect`.
#[repr(C)]
struct OracleContext {
    base: sys::RTCRayQueryContext,
    geom_id: *const u32,
    t: *const f32,
}

impl OracleContext {
    fn new(answers: &OracleAnswers) -> Self {
        let mut base = sys::RTCRayQueryContext::default();
        // SAFETY: initialises the struct exactly as the installed header's rtcInitRayQueryContext does.
        unsafe { sys::diffcassi_rtcInitRayQueryContext(&mut base) };
        OracleContext { base, geom_id: answers.geom_id.as_ptr(), t: answers.t.as_ptr() }
    }
}

/// What `geometryUserPtr` points at: kept alive by every [`Geometry`] and [`Scene`] that uses it.
struct UserSlot {
    object: Arc<dyn UserGeometry>,
    mask: u32,
}

/// A committed Embree geometry (`RTCGeometry`): a triangle mesh or an analytic user geometry.
pub struct Geometry {
    raw: sys::RTCGeometry,
    device: Device,
    user: Option<Arc<UserSlot>>,
}

// SAFETY: a committed geometry is immutable here; Embree objects may be released from any thread.
unsafe impl Send for Geometry {}
unsafe impl Sync for Geometry {}

impl Drop for Geometry {
    fn drop(&mut self) {
        // SAFETY: we own one reference (rtcNewGeometry); scenes that attached it hold their own.
        unsafe { sys::rtcReleaseGeometry(self.raw) }
    }
}

impl Geometry {
    /// A triangle mesh (`RTC_GEOMETRY_TYPE_TRIANGLE`) from `vertices` and `indices` (copied into
    /// Embree-owned, correctly padded buffers), committed. Indices must be < `vertices.len()`.
    pub fn triangle_mesh(device: &Device, vertices: &[[f32; 3]], indices: &[[u32; 3]]) -> Result<Self, EmbreeError> {
        const CTX: &str = "creating a triangle mesh";
        if vertices.is_empty() || indices.is_empty() {
            return Err(EmbreeError::invalid(CTX, "a triangle mesh needs at least one vertex and one triangle"));
        }
        if let Some((i, t)) = indices.iter().enumerate().find(|(_, t)| t.iter().any(|&k| k as usize >= vertices.len())) {
            return Err(EmbreeError::invalid(CTX, format!("triangle {i} {t:?} indexes past the {} vertices", vertices.len())));
        }
        if let Some(i) = vertices.iter().position(|v| v.iter().any(|c| !c.is_finite())) {
            return Err(EmbreeError::invalid(CTX, format!("vertex {i} {:?} is not finite", vertices[i])));
        }
        // SAFETY: live device; the geometry is owned by `geom` from here on (released on every error path).
        let raw = unsafe { sys::rtcNewGeometry(device.raw(), sys::RTC_GEOMETRY_TYPE_TRIANGLE) };
        if raw.is_null() {
            device.check(CTX)?;
            return Err(EmbreeError { code: EmbreeErrorCode::Unknown, message: "rtcNewGeometry returned NULL".into(), context: CTX.into() });
        }
        let geom = Geometry { raw, device: device.clone(), user: None };
        unsafe {
            let vb = sys::rtcSetNewGeometryBuffer(raw, sys::RTC_BUFFER_TYPE_VERTEX, 0, sys::RTC_FORMAT_FLOAT3, 12, vertices.len());
            device.check(CTX)?;
            if vb.is_null() {
                return Err(EmbreeError { code: EmbreeErrorCode::OutOfMemory, message: "no vertex buffer".into(), context: CTX.into() });
            }
            // SAFETY: Embree allocated vertices.len() items of 12 bytes (plus padding).
            std::ptr::copy_nonoverlapping(vertices.as_ptr() as *const f32, vb as *mut f32, vertices.len() * 3);
            let ib = sys::rtcSetNewGeometryBuffer(raw, sys::RTC_BUFFER_TYPE_INDEX, 0, sys::RTC_FORMAT_UINT3, 12, indices.len());
            device.check(CTX)?;
            if ib.is_null() {
                return Err(EmbreeError { code: EmbreeErrorCode::OutOfMemory, message: "no index buffer".into(), context: CTX.into() });
            }
            std::ptr::copy_nonoverlapping(indices.as_ptr() as *const u32, ib as *mut u32, indices.len() * 3);
            sys::rtcCommitGeometry(raw);
        }
        device.check(CTX)?;
        Ok(geom)
    }

    /// An analytic user geometry (one primitive) whose bounds and intersections come from `object`,
    /// committed with geometry mask `mask` (a ray hits it only if `ray.mask & mask != 0`).
    pub fn user(device: &Device, object: Arc<dyn UserGeometry>, mask: u32) -> Result<Self, EmbreeError> {
        const CTX: &str = "creating a user geometry";
        let (lo, hi) = object.bounds();
        if !(lo.iter().chain(&hi).all(|c| c.is_finite()) && lo.iter().zip(&hi).all(|(l, h)| l <= h)) {
            return Err(EmbreeError::invalid(CTX, format!("bounds {lo:?}..{hi:?} are not finite and ordered")));
        }
        // SAFETY: live device; owned by `geom` from here on.
        let raw = unsafe { sys::rtcNewGeometry(device.raw(), sys::RTC_GEOMETRY_TYPE_USER) };
        if raw.is_null() {
            device.check(CTX)?;
            return Err(EmbreeError { code: EmbreeErrorCode::Unknown, message: "rtcNewGeometry returned NULL".into(), context: CTX.into() });
        }
        let slot = Arc::new(UserSlot { object, mask });
        let geom = Geometry { raw, device: device.clone(), user: Some(slot.clone()) };
        // SAFETY: the user pointer stays valid while any Geometry/Scene holding `slot` lives, and Embree
        // only calls back while a scene using this geometry is alive.
        unsafe {
            sys::rtcSetGeometryUserPrimitiveCount(raw, 1);
            sys::rtcSetGeometryUserData(raw, Arc::as_ptr(&slot) as *mut std::ffi::c_void);
            sys::rtcSetGeometryBoundsFunction(raw, Some(user_bounds), std::ptr::null_mut());
            sys::rtcSetGeometryIntersectFunction(raw, Some(user_intersect));
            sys::rtcSetGeometryMask(raw, mask);
            sys::rtcCommitGeometry(raw);
        }
        device.check(CTX)?;
        Ok(geom)
    }

    /// The user geometry of [`Self::user`] (same bounds from `object`, same mask) whose intersect callback
    /// is the shim's oracle (`diffcassi_oracle_intersect`): it solves nothing and reports the hits the
    /// query's [`OracleAnswers`] name ([`CommittedScene::intersect16_oracle`]). Crate-private: only that
    /// query may be run on a scene holding one, and it only on such scenes (each callback reads its own
    /// extension of the query context).
    pub(crate) fn user_oracle(device: &Device, object: Arc<dyn UserGeometry>, mask: u32) -> Result<Self, EmbreeError> {
        let geom = Self::user(device, object, mask)?;
        // SAFETY: live geometry we own, not attached yet; the oracle callback only reads its arguments and
        // the OracleContext every `intersect16_oracle` passes.
        unsafe {
            sys::rtcSetGeometryIntersectFunction(geom.raw, Some(sys::diffcassi_oracle_intersect));
            sys::rtcCommitGeometry(geom.raw);
        }
        geom.device.check("creating an oracle user geometry")?;
        Ok(geom)
    }

    /// Sets the geometry mask (a ray hits this geometry only if `ray.mask & mask != 0`) and recommits.
    pub fn with_mask(self, mask: u32) -> Result<Self, EmbreeError> {
        // SAFETY: live geometry, not yet attached anywhere we would race with (we own it).
        unsafe {
            sys::rtcSetGeometryMask(self.raw, mask);
            sys::rtcCommitGeometry(self.raw);
        }
        self.device.check("setting a geometry mask")?;
        Ok(self)
    }

    pub fn raw(&self) -> sys::RTCGeometry {
        self.raw
    }
}

/// Embree's bounds callback for [`Geometry::user`].
unsafe extern "C" fn user_bounds(args: *const sys::RTCBoundsFunctionArguments) {
    // SAFETY: Embree passes valid arguments; geometryUserPtr is the UserSlot set in Geometry::user.
    let a = &*args;
    let slot = &*(a.geometryUserPtr as *const UserSlot);
    let (lo, hi) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| slot.object.bounds()))
        .unwrap_or(([0.0; 3], [0.0; 3]));
    let b = &mut *a.bounds_o;
    b.lower_x = lo[0];
    b.lower_y = lo[1];
    b.lower_z = lo[2];
    b.upper_x = hi[0];
    b.upper_y = hi[1];
    b.upper_z = hi[2];
}

/// Embree's intersect callback for [`Geometry::user`]: the valid lanes whose mask matches the geometry's are
/// read in one shim call, answered together ([`UserGeometry::intersect_exact_lanes`] when the query
/// carries the exact rays, else [`UserGeometry::intersect`] lane by lane), and a closer hit within
/// [tnear, tfar] is committed through the shim.
#[allow(clippy::needless_range_loop)] // lanes of several parallel arrays
unsafe extern "C" fn user_intersect(args: *const sys::RTCIntersectFunctionNArguments) {
    // SAFETY: Embree passes valid arguments with `N` lanes; geometryUserPtr is our UserSlot.
    let a = &*args;
    let slot = &*(a.geometryUserPtr as *const UserSlot);
    // Every query of this wrapper passes a QueryContext (see `CommittedScene::query_args`).
    let ctx = &*(a.context as *const QueryContext);
    let mut q = UserLanes::EMPTY;
    let mut start = 0u32;
    while start < a.N {
        let n = sys::diffcassi_user_rays16(
            args,
            start,
            slot.mask,
            q.lane.as_mut_ptr(),
            q.org.as_mut_ptr() as *mut f32,
            q.dir.as_mut_ptr() as *mut f32,
            q.tnear.as_mut_ptr(),
            q.tfar.as_mut_ptr(),
            q.id.as_mut_ptr(),
        ) as usize;
        start += USER_LANES as u32;
        if n == 0 {
            continue;
        }
        q.count = n;
        // The exact rays of these lanes, when the caller gave them (the ray ID is the caller's lane).
        let exact = !ctx.exact.is_null() && q.id[..n].iter().all(|&id| id < ctx.lanes);
        let mut answers = [ExactAnswer::Unsupported; USER_LANES];
        if exact {
            for k in 0..n {
                q.exact[k] = *ctx.exact.add(q.id[k] as usize);
            }
            if std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| slot.object.intersect_exact_lanes(&q, &mut answers))).is_err() {
                answers = [ExactAnswer::Miss; USER_LANES];
            }
        }
        for k in 0..n {
            let (tnear, tfar) = (q.tnear[k], q.tfar[k]);
            let hit = match answers[k] {
                ExactAnswer::Hit { t, roots } => Some((t, [0.0; 3], Some(roots))),
                ExactAnswer::Miss => None,
                ExactAnswer::Unsupported => std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| slot.object.intersect(q.org[k], q.dir[k], tnear, tfar)))
                    .ok()
                    .flatten()
                    .map(|(t, ng)| (t, ng, None)),
            };
            if let Some((t, ng, roots)) = hit {
                if t >= tnear && t <= tfar {
                    sys::diffcassi_user_report_hit(args, q.lane[k], t, ng[0], ng[1], ng[2]);
                    // The last report on a lane is its closest hit so far (Embree shrank tfar to it).
                    if exact {
                        (*ctx.solved.add(q.id[k] as usize)).set(match roots {
                            Some(roots) => SolvedRoots { geom_id: a.geomID, roots },
                            None => SolvedRoots::NONE,
                        });
                    }
                }
            }
        }
    }
}

struct SceneHandle {
    raw: sys::RTCScene,
    _device: Device,
}

impl Drop for SceneHandle {
    fn drop(&mut self) {
        // SAFETY: we own one reference (rtcNewScene); it releases the attached geometries' references.
        unsafe { sys::rtcReleaseScene(self.raw) }
    }
}

// SAFETY: see Geometry; a CommittedScene is only read (rtcIntersect* is thread-safe on a committed scene).
unsafe impl Send for SceneHandle {}
unsafe impl Sync for SceneHandle {}

/// A scene being built. Attach geometries, then [`Scene::commit`] it to trace.
pub struct Scene {
    handle: SceneHandle,
    user_slots: Vec<Arc<UserSlot>>,
}

impl Scene {
    pub fn new(device: &Device) -> Result<Self, EmbreeError> {
        // SAFETY: live device.
        let raw = unsafe { sys::rtcNewScene(device.raw()) };
        if raw.is_null() {
            device.check("creating a scene")?;
            return Err(EmbreeError { code: EmbreeErrorCode::Unknown, message: "rtcNewScene returned NULL".into(), context: "creating a scene".into() });
        }
        Ok(Scene { handle: SceneHandle { raw, _device: device.clone() }, user_slots: Vec::new() })
    }

    /// Attaches `geometry` (the scene keeps its own reference, so `geometry` may be dropped afterwards) and
    /// returns its geometry ID (the `geom_id` of hits on it).
    pub fn attach(&mut self, geometry: &Geometry) -> Result<u32, EmbreeError> {
        if !self.handle._device.same(&geometry.device) {
            return Err(EmbreeError::invalid("attaching a geometry", "the geometry belongs to another device"));
        }
        // SAFETY: both live and from the same device.
        let id = unsafe { sys::rtcAttachGeometry(self.handle.raw, geometry.raw) };
        self.handle._device.check("attaching a geometry")?;
        if let Some(slot) = &geometry.user {
            self.user_slots.push(slot.clone());
        }
        Ok(id)
    }

    /// `RTC_SCENE_FLAG_ROBUST`: watertight triangle intersection (no ray slips between two triangles
    /// sharing an edge) at some speed cost. Needed by optical meshes, where rays on symmetry planes hit
    /// mesh edges exactly.
    pub fn set_robust(&mut self) -> Result<(), EmbreeError> {
        // SAFETY: live, uncommitted scene.
        unsafe { sys::rtcSetSceneFlags(self.handle.raw, sys::RTC_SCENE_FLAG_ROBUST) };
        self.handle._device.check("setting RTC_SCENE_FLAG_ROBUST")
    }

    /// `rtcCommitScene`: builds the BVH. Consumes the scene, so it can no longer be modified.
    pub fn commit(self) -> Result<CommittedScene, EmbreeError> {
        // SAFETY: live scene.
        unsafe { sys::rtcCommitScene(self.handle.raw) };
        self.handle._device.check("committing the scene")?;
        Ok(CommittedScene { handle: self.handle, _user_slots: self.user_slots })
    }
}

/// A ray: origin, direction (need not be normalised; `t` is in units of `dir`), and the `[tnear, tfar]`
/// interval.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Ray {
    pub org: [f32; 3],
    pub dir: [f32; 3],
    pub tnear: f32,
    pub tfar: f32,
    /// Ray mask: only geometries with `geometry mask & mask != 0` are hit (all by default).
    pub mask: u32,
}

impl Ray {
    pub fn new(org: [f32; 3], dir: [f32; 3]) -> Self {
        Ray { org, dir, tnear: 0.0, tfar: f32::INFINITY, mask: u32::MAX }
    }

    /// Whether Embree may be given this ray (finite origin and direction, non-zero direction,
    /// `0 <= tnear <= tfar`, no NaN).
    pub fn is_valid(&self) -> bool {
        self.org.iter().chain(&self.dir).all(|c| c.is_finite())
            && self.dir.iter().any(|&c| c != 0.0)
            && self.tnear >= 0.0
            && self.tnear <= self.tfar // false for NaN
    }
}

/// The result of one ray. On a miss `geom_id == INVALID_GEOMETRY_ID`, `t` is infinite and the rest zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    pub t: f32,
    pub geom_id: u32,
    pub prim_id: u32,
    /// Unnormalised geometric normal (for triangles `(v1 - v0) × (v2 - v0)`... as Embree defines it);
    /// zero for a user geometry that answered an exact query ([`CommittedScene::intersect16_exact`]: the
    /// caller's refinement computes the exact normal).
    pub ng: [f32; 3],
    pub u: f32,
    pub v: f32,
}

impl Hit {
    pub const MISS: Hit = Hit { t: f32::INFINITY, geom_id: INVALID_GEOMETRY_ID, prim_id: INVALID_GEOMETRY_ID, ng: [0.0; 3], u: 0.0, v: 0.0 };

    pub fn is_hit(&self) -> bool {
        self.geom_id != INVALID_GEOMETRY_ID
    }
}

#[repr(C, align(64))]
struct Valid16([i32; 16]);

fn intersect_args() -> sys::RTCIntersectArguments {
    let mut args = sys::RTCIntersectArguments::default();
    // SAFETY: initialises the struct exactly as the installed header's rtcInitIntersectArguments does.
    unsafe { sys::diffcassi_rtcInitIntersectArguments(&mut args) };
    args
}

/// A committed scene: immutable, `Send + Sync`, traceable from many threads at once.
pub struct CommittedScene {
    // Field order = drop order: the Embree scene is released before the user data it may call into.
    handle: SceneHandle,
    _user_slots: Vec<Arc<UserSlot>>,
}

impl CommittedScene {
    /// `rtcIntersect1`: the closest hit of `ray` in `[tnear, tfar]`.
    pub fn intersect1(&self, ray: &Ray) -> Hit {
        self.intersect1_exact(ray, None)
    }

    /// [`Self::intersect1`] with the f64 ray behind `ray` (`exact.rays[0]`): analytic user geometries
    /// solve on it and leave their roots in `exact.solved[0]` (see [`ExactRays`]).
    pub fn intersect1_exact(&self, ray: &Ray, exact: Option<&ExactRays<1>>) -> Hit {
        if let Some(e) = exact {
            e.solved[0].set(SolvedRoots::NONE);
        }
        if !ray.is_valid() {
            return Hit::MISS;
        }
        let mut rh = sys::RTCRayHit::default();
        rh.ray.org_x = ray.org[0];
        rh.ray.org_y = ray.org[1];
        rh.ray.org_z = ray.org[2];
        rh.ray.dir_x = ray.dir[0];
        rh.ray.dir_y = ray.dir[1];
        rh.ray.dir_z = ray.dir[2];
        rh.ray.tnear = ray.tnear;
        rh.ray.tfar = ray.tfar;
        rh.ray.mask = ray.mask;
        rh.hit.geomID = INVALID_GEOMETRY_ID;
        rh.hit.primID = INVALID_GEOMETRY_ID;
        rh.hit.instID = [INVALID_GEOMETRY_ID; 1];
        rh.ray.id = 0;
        let mut ctx = QueryContext::new(exact);
        let mut args = intersect_args();
        args.context = &mut ctx.base;
        // SAFETY: committed scene, properly aligned and initialised ray/hit and arguments; `ctx` (and the
        // exact rays it points at) outlive the call.
        unsafe { sys::rtcIntersect1(self.handle.raw, &mut rh, &mut args) };
        if rh.hit.geomID == INVALID_GEOMETRY_ID {
            return Hit::MISS;
        }
        Hit {
            t: rh.ray.tfar,
            geom_id: rh.hit.geomID,
            prim_id: rh.hit.primID,
            ng: [rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z],
            u: rh.hit.u,
            v: rh.hit.v,
        }
    }

    /// `rtcIntersect16`: lanes with `valid[i] == false` (or an invalid ray, see [`Ray::is_valid`]) are not
    /// traced and come back as [`Hit::MISS`].
    pub fn intersect16(&self, rays: &[Ray; 16], valid: &[bool; 16]) -> [Hit; 16] {
        self.intersect16_with(rays, valid, false)
    }

    /// [`Self::intersect16`] with the `RTC_RAY_QUERY_FLAG_COHERENT` hint when `coherent` (rays of one
    /// bundle: similar origins and directions).
    pub fn intersect16_with(&self, rays: &[Ray; 16], valid: &[bool; 16], coherent: bool) -> [Hit; 16] {
        self.intersect16_exact(rays, valid, coherent, None)
    }

    /// [`Self::intersect16_with`] with the f64 rays behind the lanes (`exact.rays[i]` for lane `i`):
    /// analytic user geometries solve on them and leave their roots in `exact.solved[i]` (see
    /// [`ExactRays`]); the f32 results are those of [`Self::intersect16_with`] up to the rounding of the
    /// reported distance (solved on the exact ray instead of the rounded one).
    #[allow(clippy::needless_range_loop)] // lanes of several parallel arrays
    pub fn intersect16_exact(&self, rays: &[Ray; 16], valid: &[bool; 16], coherent: bool, exact: Option<&ExactRays<16>>) -> [Hit; 16] {
        if let Some(e) = exact {
            // Only the geometry IDs: a lane's roots are read only under a matching ID.
            // SAFETY: `Cell::as_ptr` of a cell this thread owns; no reference into it exists.
            e.solved.iter().for_each(|c| unsafe { (*c.as_ptr()).geom_id = INVALID_GEOMETRY_ID });
        }
        let mut ctx = QueryContext::new(exact);
        self.intersect16_in(rays, valid, coherent, &mut ctx.base)
    }

    /// `rtcIntersect16` (incoherent) over a scene whose user geometries were made with
    /// [`Geometry::user_oracle`]: their callback reports, on lane `i`, the hit `answers` gives it (geometry
    /// `answers.geom_id[i]` at `answers.t[i]`) without solving anything. Triangle geometries are
    /// intersected by Embree as usual. What a query costs with no surface solve: Embree's traversal and
    /// callback dispatch (the floor of docs/nonsequential.md, "Fourth pass").
    pub(crate) fn intersect16_oracle(&self, rays: &[Ray; 16], valid: &[bool; 16], answers: &OracleAnswers) -> [Hit; 16] {
        let mut ctx = OracleContext::new(answers);
        self.intersect16_in(rays, valid, false, &mut ctx.base)
    }

    /// The packet query under the ray-query context `ctx` (the base of an extended context that outlives
    /// the call).
    #[allow(clippy::needless_range_loop)] // lanes of several parallel arrays
    fn intersect16_in(&self, rays: &[Ray; 16], valid: &[bool; 16], coherent: bool, ctx: &mut sys::RTCRayQueryContext) -> [Hit; 16] {
        let mut out = [Hit::MISS; 16];
        let mut mask = Valid16([0; 16]);
        // RTCRayHit16 is 64-byte aligned by its bindgen type (checked against C in sys.rs).
        let mut rh = sys::RTCRayHit16::default();
        for i in 0..16 {
            let r = &rays[i];
            mask.0[i] = if valid[i] && r.is_valid() { -1 } else { 0 };
            rh.ray.org_x[i] = r.org[0];
            rh.ray.org_y[i] = r.org[1];
            rh.ray.org_z[i] = r.org[2];
            // Coherent traversal: a lane whose direction has a component 0 < |c| < 1e-12 (f64 rounding
            // residue of a ray in a symmetry plane, e.g. 8.7e-19 after SP's ideal lens) makes Embree 4.3's
            // per-octant frustum lose the hits of *other* lanes of its packet (docs/nonsequential.md,
            // "Embree's coherent flag"); as exact zeros they do not. The change of direction is below
            // 1e-12 rad, far under f32's resolution of the ray.
            let dir = if coherent { r.dir.map(|c| if c.abs() < 1e-12 { 0.0 } else { c }) } else { r.dir };
            rh.ray.dir_x[i] = dir[0];
            rh.ray.dir_y[i] = dir[1];
            rh.ray.dir_z[i] = dir[2];
            rh.ray.tnear[i] = if mask.0[i] != 0 { r.tnear } else { 0.0 };
            rh.ray.tfar[i] = if mask.0[i] != 0 { r.tfar } else { -1.0 };
            rh.ray.mask[i] = r.mask;
            rh.ray.id[i] = i as u32;
            rh.hit.geomID[i] = INVALID_GEOMETRY_ID;
            rh.hit.primID[i] = INVALID_GEOMETRY_ID;
            rh.hit.instID[0][i] = INVALID_GEOMETRY_ID;
        }
        if mask.0.iter().all(|&m| m == 0) {
            return out;
        }
        debug_assert_eq!((&rh as *const sys::RTCRayHit16 as usize) % 64, 0);
        let mut args = intersect_args();
        args.context = ctx;
        if coherent {
            args.flags = sys::RTC_RAY_QUERY_FLAG_COHERENT;
        }
        // SAFETY: committed scene; valid mask and ray/hit packet 64-byte aligned and initialised; `ctx`
        // (and the exact rays or oracle answers it points at) outlive the call.
        unsafe { sys::rtcIntersect16(mask.0.as_ptr(), self.handle.raw, &mut rh, &mut args) };
        for i in 0..16 {
            if mask.0[i] != 0 && rh.hit.geomID[i] != INVALID_GEOMETRY_ID {
                out[i] = Hit {
                    t: rh.ray.tfar[i],
                    geom_id: rh.hit.geomID[i],
                    prim_id: rh.hit.primID[i],
                    ng: [rh.hit.Ng_x[i], rh.hit.Ng_y[i], rh.hit.Ng_z[i]],
                    u: rh.hit.u[i],
                    v: rh.hit.v[i],
                };
            }
        }
        out
    }

    pub fn raw(&self) -> sys::RTCScene {
        self.handle.raw
    }
}

/// Runs `f` with the x86 MXCSR flush-to-zero (FTZ) and denormals-are-zero (DAZ) bits set on the current
/// thread, as Embree recommends for performance, and restores the previous MXCSR afterwards (also on
/// panic). On other architectures `f` just runs.
pub fn with_flush_denormals<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    {
        struct Restore(u32);
        impl Drop for Restore {
            fn drop(&mut self) {
                mxcsr::set(self.0);
            }
        }
        let old = mxcsr::get();
        let _restore = Restore(old);
        mxcsr::set(old | mxcsr::FTZ | mxcsr::DAZ);
        f()
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        f()
    }
}

/// Direct MXCSR access (`stmxcsr`/`ldmxcsr`; the `_mm_getcsr` intrinsics are deprecated in Rust).
#[cfg(target_arch = "x86_64")]
pub mod mxcsr {
    /// Flush to zero (bit 15).
    pub const FTZ: u32 = 1 << 15;
    /// Denormals are zero (bit 6).
    pub const DAZ: u32 = 1 << 6;

    pub fn get() -> u32 {
        let mut v: u32 = 0;
        // SAFETY: stores MXCSR to a local; SSE is baseline on x86_64.
        unsafe { core::arch::asm!("stmxcsr [{}]", in(reg) &mut v, options(nostack, preserves_flags)) };
        v
    }

    pub fn set(v: u32) {
        // SAFETY: loads a value derived from the current MXCSR (only FTZ/DAZ toggled).
        unsafe { core::arch::asm!("ldmxcsr [{}]", in(reg) &v, options(nostack, readonly, preserves_flags)) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::mem::{align_of, size_of};

    /// Unit right triangle (0,0,0)-(1,0,0)-(0,1,0) in z = 0 (geometry 0) and a unit quad (two triangles)
    /// in z = 2 spanning [2,3]×[0,1] (geometry 1).
    fn scene() -> (Device, CommittedScene, u32, u32) {
        let device = Device::new("threads=1").unwrap();
        let tri = Geometry::triangle_mesh(&device, &[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]], &[[0, 1, 2]]).unwrap();
        let quad = Geometry::triangle_mesh(
            &device,
            &[[2., 0., 2.], [3., 0., 2.], [3., 1., 2.], [2., 1., 2.]],
            &[[0, 1, 2], [0, 2, 3]],
        )
        .unwrap();
        let mut s = Scene::new(&device).unwrap();
        let t = s.attach(&tri).unwrap();
        let q = s.attach(&quad).unwrap();
        drop((tri, quad)); // the scene keeps its own references
        (device, s.commit().unwrap(), t, q)
    }

    fn down(x: f32, y: f32) -> Ray {
        Ray::new([x, y, 5.0], [0.0, 0.0, -1.0])
    }

    #[test]
    fn layouts_match_embree_4_3() {
        assert_eq!(Device::embree_version().split('.').take(2).collect::<Vec<_>>(), ["4", "3"]);
        assert_eq!(size_of::<sys::RTCRayHit>(), 96);
        assert_eq!(align_of::<sys::RTCRayHit>(), 16);
        assert_eq!(size_of::<sys::RTCRayHit16>(), sys::c_layout::C_SIZEOF_RTCRayHit16);
        assert_eq!(align_of::<sys::RTCRayHit16>(), 64);
        assert_eq!(size_of::<sys::RTCRayQueryContext>(), sys::c_layout::C_SIZEOF_RTCRayQueryContext);
        assert_eq!(size_of::<sys::RTCIntersectArguments>(), sys::c_layout::C_SIZEOF_RTCIntersectArguments);
        let a = intersect_args();
        assert_eq!(a.flags, sys::RTC_RAY_QUERY_FLAG_INCOHERENT);
        assert!(a.context.is_null() && a.filter.is_none() && a.intersect.is_none());
    }

    fn check_tri(h: &Hit, tri: u32, x: f32, y: f32) {
        assert_eq!(h.geom_id, tri);
        assert_eq!(h.prim_id, 0);
        assert!((h.t - 5.0).abs() < 1e-6, "{h:?}");
        // (v1 - v0) × (v2 - v0) = +z; u, v barycentrics = (x, y) here.
        assert!(h.ng[0].abs() < 1e-6 && h.ng[1].abs() < 1e-6 && h.ng[2] > 0.0, "{h:?}");
        assert!((h.u - x).abs() < 1e-6 && (h.v - y).abs() < 1e-6, "{h:?}");
    }

    fn check_quad(h: &Hit, quad: u32, prim: u32) {
        assert_eq!(h.geom_id, quad);
        assert_eq!(h.prim_id, prim);
        assert!((h.t - 3.0).abs() < 1e-6, "{h:?}");
        assert!(h.ng[2] > 0.0 && h.ng[0].abs() < 1e-6 && h.ng[1].abs() < 1e-6, "{h:?}");
    }

    #[test]
    fn intersect1_hits_misses_and_rejects_nan() {
        let (_d, s, tri, quad) = scene();
        check_tri(&s.intersect1(&down(0.25, 0.25)), tri, 0.25, 0.25);
        check_quad(&s.intersect1(&down(2.8, 0.2)), quad, 0);
        check_quad(&s.intersect1(&down(2.2, 0.8)), quad, 1);
        let miss = s.intersect1(&down(0.8, 0.8)); // beyond the hypotenuse
        assert_eq!(miss.geom_id, INVALID_GEOMETRY_ID);
        assert!(!miss.is_hit() && miss.t.is_infinite());
        let mut short = down(0.25, 0.25);
        short.tfar = 4.0;
        assert!(!s.intersect1(&short).is_hit());
        for bad in [
            Ray::new([f32::NAN, 0.2, 5.0], [0.0, 0.0, -1.0]),
            Ray::new([0.2, 0.2, 5.0], [0.0, f32::NAN, -1.0]),
            Ray::new([0.2, 0.2, 5.0], [0.0, 0.0, 0.0]),
            Ray { tfar: f32::NAN, ..down(0.2, 0.2) },
            Ray::new([0.2, 0.2, f32::INFINITY], [0.0, 0.0, -1.0]),
        ] {
            assert_eq!(s.intersect1(&bad), Hit::MISS);
        }
    }

    #[test]
    fn intersect16_matches_intersect1_and_honours_valid_mask() {
        let (_d, s, tri, quad) = scene();
        let mut rays = [down(0.8, 0.8); 16];
        rays[0] = down(0.25, 0.25);
        rays[1] = down(2.8, 0.2);
        rays[2] = down(2.2, 0.8);
        rays[3] = down(0.1, 0.6);
        rays[4] = Ray::new([f32::NAN; 3], [0.0, 0.0, -1.0]);
        rays[5] = down(0.25, 0.25); // hit, but masked out below
        rays[15] = down(0.5, 0.25);
        let mut valid = [true; 16];
        valid[5] = false;
        let hits = with_flush_denormals(|| s.intersect16(&rays, &valid));
        check_tri(&hits[0], tri, 0.25, 0.25);
        check_quad(&hits[1], quad, 0);
        check_quad(&hits[2], quad, 1);
        check_tri(&hits[3], tri, 0.1, 0.6);
        check_tri(&hits[15], tri, 0.5, 0.25);
        assert_eq!(hits[4], Hit::MISS);
        assert_eq!(hits[5], Hit::MISS);
        for (i, h) in hits.iter().enumerate() {
            if valid[i] {
                assert_eq!(*h, s.intersect1(&rays[i]), "lane {i}");
            }
        }
        assert!(s.intersect16(&rays, &[false; 16]).iter().all(|h| *h == Hit::MISS));
    }

    #[test]
    fn bad_config_is_an_error_with_embree_message() {
        // Embree 4.3 ignores unknown keys and ISA names, but rejects a malformed value.
        let e = Device::new("threads=abc").unwrap_err();
        assert_eq!(e.code, EmbreeErrorCode::Unknown, "{e}");
        assert!(e.message.contains("integer expected"), "{e:?}");
        let text = e.to_string();
        assert!(text.contains("RTC_ERROR_UNKNOWN") && text.contains("threads=abc"), "{text}");
        let e = Device::new("a\0b").unwrap_err();
        assert_eq!(e.code, EmbreeErrorCode::InvalidArgument);
        assert!(Device::new("threads=1").is_ok());
    }

    #[test]
    fn bad_mesh_is_an_error_not_ub() {
        let d = Device::new("").unwrap();
        assert!(Geometry::triangle_mesh(&d, &[[0.0; 3]; 3], &[[0, 1, 3]]).is_err());
        assert!(Geometry::triangle_mesh(&d, &[[f32::NAN; 3]; 3], &[[0, 1, 2]]).is_err());
        let other = Device::new("").unwrap();
        let g = Geometry::triangle_mesh(&other, &[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], &[[0, 1, 2]]).unwrap();
        assert!(Scene::new(&d).unwrap().attach(&g).is_err());
    }

    #[test]
    fn drop_order_does_not_matter() {
        // Device first, then scene and geometry.
        let (d, s, _, _) = scene();
        drop(d);
        assert!(s.intersect1(&down(0.25, 0.25)).is_hit());
        drop(s);
        // Scene first, geometry after, device last; and an uncommitted scene dropped before its device.
        let d = Device::new("").unwrap();
        let g = Geometry::triangle_mesh(&d, &[[0.0; 3], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], &[[0, 1, 2]]).unwrap();
        let mut s = Scene::new(&d).unwrap();
        s.attach(&g).unwrap();
        let c = s.commit().unwrap();
        let u = Scene::new(&d).unwrap();
        drop(d);
        drop(c);
        drop(u);
        drop(g);
    }

    #[test]
    fn committed_scene_is_shareable_across_threads() {
        let (_d, s, tri, _) = scene();
        std::thread::scope(|sc| {
            for _ in 0..2 {
                sc.spawn(|| check_tri(&s.intersect1(&down(0.25, 0.25)), tri, 0.25, 0.25));
            }
        });
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn flush_denormals_sets_and_restores_mxcsr() {
        // Valgrind does not emulate MXCSR.FTZ/DAZ (it ignores the bits and warns), so nothing to check there.
        if std::env::var("LD_PRELOAD").is_ok_and(|p| p.contains("vgpreload")) {
            eprintln!("SKIP flush_denormals_sets_and_restores_mxcsr: running under valgrind");
            return;
        }
        let before = mxcsr::get();
        let (inside, tiny) = with_flush_denormals(|| {
            let x = std::hint::black_box(f32::MIN_POSITIVE);
            (mxcsr::get(), std::hint::black_box(x / 4.0))
        });
        assert_eq!(inside & (mxcsr::FTZ | mxcsr::DAZ), mxcsr::FTZ | mxcsr::DAZ);
        assert_eq!(tiny, 0.0);
        assert_eq!(mxcsr::get(), before);
        let r = std::panic::catch_unwind(|| with_flush_denormals(|| panic!("boom")));
        assert!(r.is_err());
        assert_eq!(mxcsr::get(), before);
    }
}
