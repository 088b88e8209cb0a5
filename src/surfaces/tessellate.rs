//! Tessellation of a surface's clear aperture into triangles for mesh-based ray tracing (the Embree
//! backend's `mesh` geometry).
//!
//! Vertices lie exactly on the surface (sag-exact, f64). The resolution is a segment count or a maximum
//! chord-sag error: the largest distance, along z, between a triangle and the surface it replaces. The
//! error is *measured* on every triangle (dense barycentric sampling) and the mesh refined until it holds,
//! so the bound is a checked property, not an estimate. The boundary of a circular aperture is a polygon
//! inscribed in the circle ([`tessellate`]) or circumscribed about it ([`tessellate_covering`], what a
//! ray tracer needs: the mesh covers the aperture); its in-plane error is reported separately. The
//! covering mesh decouples the two errors: the boundary's segment count follows the overshoot
//! tolerance, the interior's ring count the chord-sag tolerance, with a graded band between them (a
//! plane: a fine boundary ring and a coarse interior).
//!
//! ```
//! use diffcassi::surfaces::{tessellate, Aperture, MeshResolution, SurfaceShape};
//! let sphere = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
//! let mesh = tessellate(&sphere, &Aperture::circular(12.7), MeshResolution::MaxSagErrorUm(1.0)).unwrap();
//! assert!(mesh.max_sag_error_um <= 1.0);
//! ```
use super::{Aperture, SurfaceShape};

/// How finely to tessellate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MeshResolution {
    /// Circular apertures: `n` rings and 6·n boundary segments; rectangular: an `n` × `n` grid of cells.
    Segments(usize),
    /// The coarsest mesh (fewest segments) whose every triangle is within this chord-sag error (µm).
    MaxSagErrorUm(f64),
}

/// A triangle mesh in the surface's local frame (mm).
#[derive(Clone, Debug, PartialEq)]
pub struct TriangleMesh {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// Largest measured chord-sag error over all triangles (µm).
    pub max_sag_error_um: f64,
    /// Largest in-plane distance between the aperture boundary and the mesh boundary (µm); 0 for
    /// rectangles.
    pub boundary_error_um: f64,
    /// The segment count the mesh was built with: its uniform rings (circular; the boundary has `6·segments`
    /// points, or more in a [`tessellate_covering`] graded band) or grid cells per side (rectangular).
    pub segments: usize,
}

/// Most segments a request may ask for (a 2 × 6·n² triangle mesh beyond this is a misuse, not a mesh).
pub const MAX_SEGMENTS: usize = 4096;

/// Tessellate `shape` over `aperture` (which must be circular or rectangular: the clear aperture). A
/// circular boundary is the polygon *inscribed* in the circle, with `6·n` segments for `n` uniform rings.
pub fn tessellate(shape: &SurfaceShape, aperture: &Aperture, resolution: MeshResolution) -> Result<TriangleMesh, String> {
    let shape = checked(shape, aperture)?;
    match resolution {
        MeshResolution::Segments(n) => build(shape, aperture, segments(n)?),
        MeshResolution::MaxSagErrorUm(tol) => coarsest(tolerance(tol)?, |n| build(shape, aperture, n)),
    }
}

/// Tessellate `shape` so that the mesh **covers** its clear aperture — what a ray tracer that must hit
/// the mesh wherever it hits the exact patch needs. A circular aperture's boundary is the polygon
/// *circumscribed* about the circle (vertices at r / cos(π/m), heights on the figure), which overshoots
/// the circle by r(1/cos(π/m) − 1): the *boundary error* ([`TriangleMesh::boundary_error_um`]).
///
/// * `Segments(n)`: `n` uniform rings and `6·n` boundary segments (the mesh of [`tessellate`] with its
///   outer ring moved out).
/// * `MaxSagErrorUm(tol)`: the two errors are decoupled. The boundary gets the fewest segments `m` (a
///   multiple of 6) whose overshoot is ≤ `tol`; the interior gets the fewest uniform rings `n` whose
///   measured chord-sag error (on the final mesh, boundary included) is ≤ `tol`. Where the boundary needs
///   more than `6·n` segments (always on a plane, whose chord-sag error is 0 at one ring), the outermost
///   ring spacing is replaced by a *graded band*: rings whose point counts grow geometrically (ratio ≤ 2)
///   from `6·n` to `m`, their widths shrinking in proportion, so the triangles stay near-isotropic and
///   their number follows the boundary (≈ 3·m on a plane) instead of `6·(m/6)²`.
///
/// Where the figure is undefined just outside the aperture (a conic at its domain's edge) the inscribed
/// polygon is kept (and reported as the boundary error). Rectangles are covered exactly: as [`tessellate`].
///
/// ```
/// use diffcassi::surfaces::{tessellate_covering, Aperture, MeshResolution, SurfaceShape};
/// let m = tessellate_covering(&SurfaceShape::Plane, &Aperture::circular(25.0), MeshResolution::MaxSagErrorUm(1.0)).unwrap();
/// assert!(m.boundary_error_um <= 1.0 && m.triangles.len() < 1500); // a uniform 354-gon disk: 20 886
/// ```
pub fn tessellate_covering(shape: &SurfaceShape, aperture: &Aperture, resolution: MeshResolution) -> Result<TriangleMesh, String> {
    let shape = checked(shape, aperture)?;
    let Aperture::Circular { semi_diameter_mm: r, .. } = *aperture else { return tessellate(shape, aperture, resolution) };
    match resolution {
        MeshResolution::Segments(n) => {
            let n = segments(n)?;
            build_circular(shape, aperture, n, 6 * n, true)
        }
        MeshResolution::MaxSagErrorUm(tol) => {
            let tol = tolerance(tol)?;
            // Overshoot r(1/cos(π/m) − 1) ≤ tol  ⇔  π/m ≤ acos(1 / (1 + tol/r)).
            let half_step = (1.0 / (1.0 + tol * 1e-3 / r)).acos();
            let m = 6.0 * (std::f64::consts::PI / half_step / 6.0).ceil();
            if !(m.is_finite() && m <= (6 * MAX_SEGMENTS) as f64) {
                return Err(format!(
                    "a boundary overshoot of {tol} µm on a {r} mm semi-diameter needs more than {} boundary segments",
                    6 * MAX_SEGMENTS
                ));
            }
            let m = m as usize;
            coarsest(tol, |n| build_circular(shape, aperture, n, m.max(6 * n), true))
        }
    }
}

/// The aperture checked, and an ideal lens replaced by the plane it is.
fn checked<'a>(shape: &'a SurfaceShape, aperture: &Aperture) -> Result<&'a SurfaceShape, String> {
    match *aperture {
        Aperture::None => return Err("tessellation needs a finite clear aperture (circular or rectangular), got none".into()),
        Aperture::CircularObscuration { .. } => {
            return Err("tessellation needs a finite clear aperture (circular or rectangular); a circular obscuration bounds nothing (it passes every ray outside it)".into())
        }
        _ => aperture.validate()?,
    }
    // An ideal lens is a plane: tessellate it as one.
    static PLANE: SurfaceShape = SurfaceShape::Plane;
    Ok(if let SurfaceShape::Paraxial { .. } = shape { &PLANE } else { shape })
}

fn segments(n: usize) -> Result<usize, String> {
    if n == 0 || n > MAX_SEGMENTS {
        return Err(format!("mesh segments = {n}: must be in 1..={MAX_SEGMENTS}"));
    }
    Ok(n)
}

fn tolerance(tol: f64) -> Result<f64, String> {
    if !(tol.is_finite() && tol > 0.0) {
        return Err(format!("max chord-sag error {tol} µm: must be finite and > 0"));
    }
    Ok(tol)
}

/// The mesh of the fewest segments `n` whose measured chord-sag error is ≤ `tol` µm: doubling (or a
/// jump by the error's square root, chord sag falling as 1/n²), then bisection.
fn coarsest(tol: f64, build: impl Fn(usize) -> Result<TriangleMesh, String>) -> Result<TriangleMesh, String> {
    let (mut n, mut failing) = (1usize, 0usize);
    loop {
        let mesh = build(n)?;
        if mesh.max_sag_error_um <= tol {
            // Bisect between the last failing count and this one for the coarsest mesh that holds.
            let (mut lo, mut hi, mut best) = (failing, n, mesh);
            while hi - lo > 1 {
                let mid = lo + (hi - lo) / 2;
                let m = build(mid)?;
                if m.max_sag_error_um <= tol {
                    hi = mid;
                    best = m;
                } else {
                    lo = mid;
                }
            }
            return Ok(best);
        }
        failing = n;
        // Chord sag falls as 1/n²: jump close to the needed count, at least doubling.
        let factor = (mesh.max_sag_error_um / tol).sqrt().ceil() as usize;
        n = (n * factor.max(2)).min(MAX_SEGMENTS + 1);
        if n > MAX_SEGMENTS {
            return Err(format!(
                "a chord-sag error of {tol} µm needs more than {MAX_SEGMENTS} segments on this surface (at {} the error is {:.3e} µm)",
                mesh.segments, mesh.max_sag_error_um
            ));
        }
    }
}

fn vertex(shape: &SurfaceShape, x: f64, y: f64) -> Result<[f64; 3], String> {
    let z = shape.sag(x, y);
    if !z.is_finite() {
        return Err(format!("the surface is not defined at ({x}, {y}) mm inside the aperture (beyond the conic's domain)"));
    }
    Ok([x, y, z])
}

fn build(shape: &SurfaceShape, aperture: &Aperture, n: usize) -> Result<TriangleMesh, String> {
    match *aperture {
        Aperture::Circular { .. } => build_circular(shape, aperture, n, 6 * n, false),
        Aperture::Rectangular { half_width_x_mm: hx, half_width_y_mm: hy, decenter_x_mm: cx, decenter_y_mm: cy } => {
            let mut vertices = Vec::new();
            let mut triangles = Vec::new();
            for j in 0..=n {
                for i in 0..=n {
                    let x = cx - hx + 2.0 * hx * i as f64 / n as f64;
                    let y = cy - hy + 2.0 * hy * j as f64 / n as f64;
                    vertices.push(vertex(shape, x, y)?);
                }
            }
            let id = |i: usize, j: usize| (j * (n + 1) + i) as u32;
            for j in 0..n {
                for i in 0..n {
                    triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
                    triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
                }
            }
            Ok(finish(shape, vertices, triangles, 0.0, n))
        }
        Aperture::None | Aperture::CircularObscuration { .. } => unreachable!("checked by tessellate"),
    }
}

/// The rings of a circular aperture from the centre (or the obscuration) outward, as (radius, points);
/// the centre is one point at radius 0. `n` uniform rings of width (r − r0)/n, ring k holding 6k points
/// (6n each on an annulus) — a near-uniform triangulation; with `boundary` > 6n, the last ring is
/// replaced by the graded band of [`tessellate_covering`] ending in `boundary` points at r.
fn rings(r0: f64, r: f64, n: usize, boundary: usize) -> Vec<(f64, usize)> {
    let uniform = |k: usize| (r0 + (r - r0) * k as f64 / n as f64, if r0 > 0.0 { 6 * n } else if k == 0 { 1 } else { 6 * k });
    if boundary <= 6 * n {
        return (0..=n).map(uniform).collect();
    }
    let mut out: Vec<(f64, usize)> = (0..n).map(uniform).collect();
    // Point counts 6n·q^j, j = 0..=J, with ratio q ≤ 2 reaching `boundary` at j = J; the ring widths
    // before them fall as q^−j (the points' spacing) and sum to the uniform ring width.
    let ratio = boundary as f64 / (6 * n) as f64;
    let steps = ratio.log2().ceil().max(1.0) as i32;
    let q = ratio.powf(1.0 / steps as f64);
    let widths: Vec<f64> = (0..=steps).map(|j| q.powi(-j)).collect();
    let total: f64 = widths.iter().sum();
    let (start, width) = (out[n - 1].0, (r - r0) / n as f64);
    let mut acc = 0.0;
    for j in 0..=steps {
        acc += widths[j as usize];
        let (radius, points) = if j == steps { (r, boundary) } else { (start + width * acc / total, ((6 * n) as f64 * q.powi(j)).round() as usize) };
        out.push((radius, points));
    }
    out
}

/// A circular aperture (disk or annulus) meshed on [`rings`]; `cover`: the outer ring moved onto the
/// circumscribed polygon (kept inscribed where the figure is undefined there).
fn build_circular(shape: &SurfaceShape, aperture: &Aperture, n: usize, boundary: usize, cover: bool) -> Result<TriangleMesh, String> {
    let Aperture::Circular { semi_diameter_mm: r, min_radius_mm: r0, decenter_x_mm: cx, decenter_y_mm: cy } = *aperture else { unreachable!("circular apertures only") };
    let rings = rings(r0, r, n, boundary);
    let mut vertices = Vec::new();
    let mut starts = Vec::with_capacity(rings.len());
    for &(rk, m) in &rings {
        starts.push(vertices.len());
        if m == 1 {
            vertices.push(vertex(shape, cx, cy)?);
            continue;
        }
        for j in 0..m {
            let a = std::f64::consts::TAU * j as f64 / m as f64;
            vertices.push(vertex(shape, cx + rk * a.cos(), cy + rk * a.sin())?);
        }
    }
    let mut triangles = Vec::new();
    for k in 0..rings.len() - 1 {
        let (inner, outer) = (starts[k], starts[k + 1]);
        let (mi, mo) = (rings[k].1, rings[k + 1].1);
        if mi == 1 {
            for j in 0..mo {
                triangles.push([inner as u32, (outer + j) as u32, (outer + (j + 1) % mo) as u32]);
            }
            continue;
        }
        // Walk both rings by angle, always advancing the one whose next point comes first.
        let (mut i, mut o) = (0usize, 0usize);
        while i < mi || o < mo {
            let ai = (i + 1) as f64 / mi as f64;
            let ao = (o + 1) as f64 / mo as f64;
            if o < mo && (i >= mi || ao <= ai) {
                triangles.push([(inner + i % mi) as u32, (outer + o) as u32, (outer + (o + 1) % mo) as u32]);
                o += 1;
            } else {
                triangles.push([(inner + i) as u32, (outer + o % mo) as u32, (inner + (i + 1) % mi) as u32]);
                i += 1;
            }
        }
    }
    let m = boundary;
    let mut boundary_error_um = 1e3 * r * (1.0 - (std::f64::consts::PI / m as f64).cos());
    if cover {
        // The outer ring (the last m vertices) scaled by 1/cos(π/m) about the centre, on the figure.
        let out = 1.0 / (std::f64::consts::PI / m as f64).cos();
        let start = vertices.len() - m;
        let moved: Option<Vec<[f64; 3]>> = vertices[start..]
            .iter()
            .map(|v| {
                let (x, y) = (cx + (v[0] - cx) * out, cy + (v[1] - cy) * out);
                let z = shape.sag(x, y);
                z.is_finite().then_some([x, y, z])
            })
            .collect();
        if let Some(moved) = moved {
            vertices[start..].copy_from_slice(&moved);
            boundary_error_um = 1e3 * r * (out - 1.0);
        }
    }
    Ok(finish(shape, vertices, triangles, boundary_error_um, n))
}

fn finish(shape: &SurfaceShape, vertices: Vec<[f64; 3]>, triangles: Vec<[u32; 3]>, boundary_error_um: f64, n: usize) -> TriangleMesh {
    let max_sag_error_um = 1e3 * triangles.iter().map(|t| chord_sag(shape, &vertices, t)).fold(0.0, f64::max);
    TriangleMesh { vertices, triangles, max_sag_error_um, boundary_error_um, segments: n }
}

/// Largest |surface − triangle| along z over a barycentric sampling of the triangle (mm). With 12
/// subdivisions per edge the sampling error on the quadratic chord deviation is below 1 % of it.
fn chord_sag(shape: &SurfaceShape, v: &[[f64; 3]], t: &[u32; 3]) -> f64 {
    const S: usize = 12;
    let (a, b, c) = (v[t[0] as usize], v[t[1] as usize], v[t[2] as usize]);
    let mut worst: f64 = 0.0;
    for i in 0..=S {
        for j in 0..=(S - i) {
            let (u, w) = (i as f64 / S as f64, j as f64 / S as f64);
            let s = 1.0 - u - w;
            let p = [0, 1, 2].map(|k| s * a[k] + u * b[k] + w * c[k]);
            worst = worst.max((shape.sag(p[0], p[1]) - p[2]).abs());
        }
    }
    worst
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Independent check of a mesh: vertices on the surface, every triangle within `tol_um` of it (sampled
    /// more densely than the builder does), a consistent orientation (normals toward +z), and full coverage
    /// of the aperture polygon's area.
    fn check(shape: &SurfaceShape, mesh: &TriangleMesh, tol_um: f64, area_expected: f64) {
        for v in &mesh.vertices {
            assert!((shape.sag(v[0], v[1]) - v[2]).abs() < 1e-12);
        }
        let mut area = 0.0;
        for t in &mesh.triangles {
            let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
            let cross_z = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            assert!(cross_z > 0.0, "triangle {t:?} is degenerate or clockwise");
            area += 0.5 * cross_z;
            for i in 0..=30 {
                for j in 0..=(30 - i) {
                    let (u, w) = (i as f64 / 30.0, j as f64 / 30.0);
                    let s = 1.0 - u - w;
                    let p = [0, 1, 2].map(|k| s * a[k] + u * b[k] + w * c[k]);
                    let e = 1e3 * (shape.sag(p[0], p[1]) - p[2]).abs();
                    assert!(e <= tol_um * 1.02, "chord error {e} µm > {tol_um} µm");
                }
            }
        }
        assert!((area - area_expected).abs() < 1e-9 * area_expected.max(1.0), "area {area} vs {area_expected}");
    }

    #[test]
    fn sphere_meets_the_chord_sag_bound() {
        let s = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
        for tol in [10.0, 1.0, 0.1] {
            let m = tessellate(&s, &Aperture::circular(12.7), MeshResolution::MaxSagErrorUm(tol)).unwrap();
            assert!(m.max_sag_error_um <= tol);
            let poly = 0.5 * (6 * m.segments) as f64 * 12.7f64.powi(2) * (std::f64::consts::TAU / (6 * m.segments) as f64).sin();
            check(&s, &m, tol, poly);
        }
    }

    #[test]
    fn the_mesh_is_the_coarsest_that_meets_the_bound() {
        let s = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
        let m = tessellate(&s, &Aperture::circular(12.7), MeshResolution::MaxSagErrorUm(1.0)).unwrap();
        let coarser = tessellate(&s, &Aperture::circular(12.7), MeshResolution::Segments(m.segments - 1)).unwrap();
        assert!(coarser.max_sag_error_um > 1.0, "{} segments would do", m.segments - 1);
    }

    #[test]
    fn asphere_and_rectangle() {
        let s = SurfaceShape::EvenAsphere { curvature: 0.02, conic: -1.0, coefficients: vec![1e-4, -2e-7] };
        let ap = Aperture::Rectangular { half_width_x_mm: 6.0, half_width_y_mm: 4.0, decenter_x_mm: 1.0, decenter_y_mm: 0.0 };
        let m = tessellate(&s, &ap, MeshResolution::MaxSagErrorUm(0.5)).unwrap();
        check(&s, &m, 0.5, 96.0); // 12 mm × 8 mm
        assert_eq!(m.boundary_error_um, 0.0);
    }

    #[test]
    fn planes_and_tiny_curvature_need_one_segment() {
        for s in [SurfaceShape::Plane, SurfaceShape::Conic { curvature: 1e-12, conic: 0.0 }, SurfaceShape::Paraxial { focal_length: 50.0 }] {
            let m = tessellate(&s, &Aperture::circular(5.0), MeshResolution::MaxSagErrorUm(0.01)).unwrap();
            assert_eq!(m.segments, 1, "{s:?}");
            assert_eq!(m.triangles.len(), 6);
        }
    }

    #[test]
    fn annulus_covers_its_area() {
        let s = SurfaceShape::Conic { curvature: 0.01, conic: 0.0 };
        let ap = Aperture::Circular { semi_diameter_mm: 5.0, min_radius_mm: 2.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 };
        let m = tessellate(&s, &ap, MeshResolution::Segments(8)).unwrap();
        let k = 48.0;
        let poly = |r: f64| 0.5 * k * r * r * (std::f64::consts::TAU / k).sin();
        check(&s, &m, m.max_sag_error_um, poly(5.0) - poly(2.0));
    }

    #[test]
    fn misuse_is_an_error() {
        let s = SurfaceShape::Plane;
        let ap = Aperture::circular(5.0);
        assert!(tessellate(&s, &ap, MeshResolution::Segments(0)).unwrap_err().contains("segments = 0"));
        assert!(tessellate(&s, &ap, MeshResolution::Segments(1_000_000_000)).unwrap_err().contains("1000000000"));
        assert!(tessellate(&s, &ap, MeshResolution::MaxSagErrorUm(f64::NAN)).is_err());
        assert!(tessellate(&s, &ap, MeshResolution::MaxSagErrorUm(0.0)).is_err());
        assert!(tessellate(&s, &Aperture::None, MeshResolution::Segments(4)).is_err());
        // A hemisphere-steep request that cannot be met within MAX_SEGMENTS is refused, not looped on.
        let steep = SurfaceShape::Conic { curvature: 1.0 / 5.0, conic: 0.0 };
        assert!(tessellate(&steep, &Aperture::circular(4.999), MeshResolution::MaxSagErrorUm(1e-9)).is_err());
        // Aperture beyond the sphere's domain.
        assert!(tessellate(&steep, &Aperture::circular(6.0), MeshResolution::Segments(4)).unwrap_err().contains("not defined"));
    }

    /// Whether the point (x, y) lies in the xy projection of some triangle (barycentric, with a
    /// tolerance of 1e-12 relative).
    fn covered(mesh: &TriangleMesh, x: f64, y: f64) -> bool {
        mesh.triangles.iter().any(|t| {
            let [a, b, c] = t.map(|k| mesh.vertices[k as usize]);
            let d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            let u = ((x - a[0]) * (c[1] - a[1]) - (y - a[1]) * (c[0] - a[0])) / d;
            let v = ((b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0])) / d;
            u >= -1e-12 && v >= -1e-12 && u + v <= 1.0 + 1e-12
        })
    }

    /// The area of the polygon with `m` sides circumscribed about a circle of radius `r`.
    fn circumscribed(m: usize, r: f64) -> f64 {
        let big = r / (std::f64::consts::PI / m as f64).cos();
        0.5 * m as f64 * big * big * (std::f64::consts::TAU / m as f64).sin()
    }

    /// The covering mesh of a circular aperture: triangles ccw and within the chord-sag bound, their
    /// projected areas summing to the circumscribed m-gon's (so they tile it without overlap), the boundary
    /// overshoot within `tol_um`, and points sampled over the whole aperture (rim included) covered.
    /// Returns m.
    fn check_covering(shape: &SurfaceShape, mesh: &TriangleMesh, r: f64, r0: f64, tol_um: f64) -> usize {
        let rho = |v: &[f64; 3]| v[0].hypot(v[1]);
        let m = mesh.vertices.iter().filter(|v| rho(v) > r).count();
        assert!(mesh.boundary_error_um <= tol_um, "overshoot {} µm > {tol_um} µm", mesh.boundary_error_um);
        assert!((mesh.boundary_error_um - 1e3 * r * (1.0 / (std::f64::consts::PI / m as f64).cos() - 1.0)).abs() < 1e-9);
        let hole = if r0 > 0.0 { 0.5 * (6 * mesh.segments) as f64 * r0 * r0 * (std::f64::consts::TAU / (6 * mesh.segments) as f64).sin() } else { 0.0 };
        check(shape, mesh, tol_um, circumscribed(m, r) - hole);
        for i in 0..=40 {
            let p = r0 + (r - r0) * i as f64 / 40.0;
            for j in 0..97 {
                let a = std::f64::consts::TAU * (j as f64 + 0.37) / 97.0;
                assert!(covered(mesh, p * a.cos(), p * a.sin()), "({p} mm, {a} rad) not covered");
            }
        }
        m
    }

    #[test]
    fn a_covering_plane_has_a_fine_boundary_and_a_coarse_interior() {
        // r = 25 mm at 1 µm: a 354-gon overshoots by ≤ 1 µm. Uniform rings up to that boundary (the covering
        // mesh before issue 23's follow-up) took 59 rings, 6·59² = 20 886 triangles; the graded band needs
        // ≈ 3 per boundary segment.
        for shape in [SurfaceShape::Plane, SurfaceShape::Paraxial { focal_length: 50.0 }] {
            let mesh = tessellate_covering(&shape, &Aperture::circular(25.0), MeshResolution::MaxSagErrorUm(1.0)).unwrap();
            let m = check_covering(&SurfaceShape::Plane, &mesh, 25.0, 0.0, 1.0);
            assert_eq!(m, 354);
            assert_eq!(mesh.segments, 1);
            assert!(mesh.triangles.len() <= 4 * m, "{} triangles for a {m}-gon", mesh.triangles.len());
            assert!(mesh.triangles.len() <= 1500, "{} triangles", mesh.triangles.len());
        }
        // A finer tolerance refines the boundary only.
        let fine = tessellate_covering(&SurfaceShape::Plane, &Aperture::circular(25.0), MeshResolution::MaxSagErrorUm(0.1)).unwrap();
        let m = check_covering(&SurfaceShape::Plane, &fine, 25.0, 0.0, 0.1);
        assert!(fine.triangles.len() <= 4 * m && m >= 1110, "{} triangles, {m} boundary segments", fine.triangles.len());
    }

    #[test]
    fn covering_curved_surfaces_meet_both_tolerances() {
        let sphere = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
        let asphere = SurfaceShape::EvenAsphere { curvature: 0.02, conic: -1.0, coefficients: vec![1e-4, -2e-7] };
        for (shape, r) in [(&sphere, 12.7), (&asphere, 8.0), (&SurfaceShape::Conic { curvature: 1e-3, conic: 0.0 }, 20.0)] {
            for tol in [10.0, 1.0, 0.1] {
                let mesh = tessellate_covering(shape, &Aperture::circular(r), MeshResolution::MaxSagErrorUm(tol)).unwrap();
                let m = check_covering(shape, &mesh, r, 0.0, tol);
                // Never more than the uniform rings would need for the same boundary.
                let n = mesh.segments.max(m.div_ceil(6));
                assert!(mesh.triangles.len() <= 6 * n * n, "{shape:?} {tol} µm: {} triangles", mesh.triangles.len());
            }
        }
        // Weak curvature (R = 1 m over 20 mm) at 1 µm: few rings, the boundary from the overshoot.
        let weak_shape = SurfaceShape::Conic { curvature: 1e-3, conic: 0.0 };
        let weak = tessellate_covering(&weak_shape, &Aperture::circular(20.0), MeshResolution::MaxSagErrorUm(1.0)).unwrap();
        let m = check_covering(&weak_shape, &weak, 20.0, 0.0, 1.0);
        let uniform = 6 * m.div_ceil(6).pow(2);
        assert!(3 * weak.segments < m / 6 && 4 * weak.triangles.len() < uniform, "{} rings, {} triangles, {m}-gon", weak.segments, weak.triangles.len());
    }

    #[test]
    fn covering_by_segments_is_the_inscribed_mesh_moved_out() {
        let s = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
        let ap = Aperture::circular(12.7);
        let (a, b) = (tessellate(&s, &ap, MeshResolution::Segments(7)).unwrap(), tessellate_covering(&s, &ap, MeshResolution::Segments(7)).unwrap());
        assert_eq!(a.triangles, b.triangles);
        assert_eq!(a.vertices[..a.vertices.len() - 42], b.vertices[..b.vertices.len() - 42]);
        check_covering(&s, &b, 12.7, 0.0, b.boundary_error_um.max(b.max_sag_error_um));
        // An annulus: only its outer boundary moves.
        let ring = Aperture::Circular { semi_diameter_mm: 5.0, min_radius_mm: 2.0, decenter_x_mm: 0.0, decenter_y_mm: 0.0 };
        let c = tessellate_covering(&SurfaceShape::Plane, &ring, MeshResolution::MaxSagErrorUm(0.5)).unwrap();
        check_covering(&SurfaceShape::Plane, &c, 5.0, 2.0, 0.5);
    }

    #[test]
    fn covering_keeps_the_inscribed_ring_where_the_figure_ends() {
        // A hemisphere-like conic whose domain ends at 5 mm: the circumscribed ring would leave it.
        let s = SurfaceShape::Conic { curvature: 1.0 / 5.0, conic: 0.0 };
        let m = tessellate_covering(&s, &Aperture::circular(4.9999), MeshResolution::Segments(4)).unwrap();
        assert!(m.vertices.iter().all(|v| v[0].hypot(v[1]) <= 4.9999 + 1e-12 && v[2].is_finite()));
        assert!(tessellate_covering(&s, &Aperture::None, MeshResolution::Segments(4)).is_err());
        assert!(tessellate_covering(&s, &Aperture::circular(4.0), MeshResolution::MaxSagErrorUm(-1.0)).unwrap_err().contains("-1"));
    }
}
