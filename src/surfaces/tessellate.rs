//! Tessellation of a surface's clear aperture into triangles for mesh-based ray tracing (the Embree
//! backend's `mesh` geometry).
//!
//! Vertices lie exactly on the surface (sag-exact, f64). The resolution is a segment count or a maximum
//! chord-sag error: the largest distance, along z, between a triangle and the surface it replaces. The
//! error is *measured* on every triangle (dense barycentric sampling) and the mesh refined until it holds,
//! so the bound is a checked property, not an estimate. The boundary of a circular aperture is a polygon
//! inscribed in the circle; its in-plane error is reported separately.
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
    /// The segment count the mesh was built with.
    pub segments: usize,
}

/// Most segments a request may ask for (a 2 × 6·n² triangle mesh beyond this is a misuse, not a mesh).
pub const MAX_SEGMENTS: usize = 4096;

/// Tessellate `shape` over `aperture` (which must be circular or rectangular: the clear aperture).
pub fn tessellate(shape: &SurfaceShape, aperture: &Aperture, resolution: MeshResolution) -> Result<TriangleMesh, String> {
    match *aperture {
        Aperture::None => return Err("tessellation needs a finite clear aperture (circular or rectangular), got none".into()),
        _ => aperture.validate()?,
    }
    if let SurfaceShape::Paraxial { .. } = shape {
        // An ideal lens is a plane: tessellate it as one.
        return tessellate(&SurfaceShape::Plane, aperture, resolution);
    }
    match resolution {
        MeshResolution::Segments(n) => {
            if n == 0 || n > MAX_SEGMENTS {
                return Err(format!("mesh segments = {n}: must be in 1..={MAX_SEGMENTS}"));
            }
            build(shape, aperture, n)
        }
        MeshResolution::MaxSagErrorUm(tol) => {
            if !(tol.is_finite() && tol > 0.0) {
                return Err(format!("max chord-sag error {tol} µm: must be finite and > 0"));
            }
            let (mut n, mut failing) = (1usize, 0usize);
            loop {
                let mesh = build(shape, aperture, n)?;
                if mesh.max_sag_error_um <= tol {
                    // Bisect between the last failing count and this one for the coarsest mesh that holds.
                    let (mut lo, mut hi, mut best) = (failing, n, mesh);
                    while hi - lo > 1 {
                        let mid = lo + (hi - lo) / 2;
                        let m = build(shape, aperture, mid)?;
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
    let mut vertices = Vec::new();
    let mut triangles = Vec::new();
    let boundary_error_um;
    match *aperture {
        Aperture::Circular { semi_diameter_mm: r, min_radius_mm, decenter_x_mm: cx, decenter_y_mm: cy } => {
            // Rings k = 0..=n at radius r·k/n (or from the obscuration outward), ring k holding 6k points
            // (ring 0: the centre) — a near-uniform triangulation of the disk.
            let r0 = min_radius_mm;
            let ring_start = |k: usize| if r0 > 0.0 { k * 6 * n.max(1) } else if k == 0 { 0 } else { 1 + 3 * k * (k - 1) };
            for k in 0..=n {
                let rk = r0 + (r - r0) * k as f64 / n as f64;
                let m = if r0 > 0.0 { 6 * n } else { 6 * k };
                if m == 0 {
                    vertices.push(vertex(shape, cx, cy)?);
                    continue;
                }
                for j in 0..m {
                    let a = std::f64::consts::TAU * j as f64 / m as f64;
                    vertices.push(vertex(shape, cx + rk * a.cos(), cy + rk * a.sin())?);
                }
            }
            for k in 0..n {
                let (inner, outer) = (ring_start(k), ring_start(k + 1));
                let (mi, mo) = if r0 > 0.0 { (6 * n, 6 * n) } else { (6 * k, 6 * (k + 1)) };
                if mi == 0 {
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
            let m = 6 * n;
            boundary_error_um = 1e3 * r * (1.0 - (std::f64::consts::PI / m as f64).cos());
        }
        Aperture::Rectangular { half_width_x_mm: hx, half_width_y_mm: hy, decenter_x_mm: cx, decenter_y_mm: cy } => {
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
            boundary_error_um = 0.0;
        }
        Aperture::None => unreachable!("checked by tessellate"),
    }
    let max_sag_error_um = 1e3 * triangles.iter().map(|t| chord_sag(shape, &vertices, t)).fold(0.0, f64::max);
    Ok(TriangleMesh { vertices, triangles, max_sag_error_um, boundary_error_um, segments: n })
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
}
