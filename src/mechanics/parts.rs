//! Mounts generated from a [`SequentialSystem`]: a **lens tube** per lens group (a thick-walled cylinder
//! around the group's clear apertures), the **prism holder** (a rectangular sleeve around each prism
//! solid, open along the beam), the **detector housing** (a rectangular sleeve in front of the detector and
//! a back plate) and a **baffle** (an annulus in front of the first lens group). Every part is a closed,
//! consistently wound (outward normals), manifold solid.
//!
//! The envelope of the optics comes from the *rims*: each path surface's clear semi-diameter (the larger
//! of Zemax's and the automatic one of the system's fields mirrored to all quadrants, or the explicit
//! aperture's extent) sampled at [`RIM_SAMPLES`] angles on the surface's figure, in global coordinates.
//! Parts clear the rims by [`GenerateOptions::clearance_mm`] so that a ray inside every clear aperture
//! never meets a mount (tested on SP and AP); the beam between two coaxial apertures lies in the convex
//! hull of their rims, hence inside a tube around both.
//!
//! The mesh resolution (`segments`, the polygon vertices around a tube) sets the triangle count and
//! nothing else: the envelope is the same at every resolution.
use super::{Part, PartKind, TriMesh};
use crate::analysis::mirrored_semi_diameters;
use crate::error::{Error, Result};
use crate::geometry::Frame;
use crate::spec::SurfaceModel;
use crate::surfaces::{Aperture, SurfaceShape};
use crate::system::SequentialSystem;
use glam::{DMat3, DVec3};
use std::f64::consts::TAU;

/// Angles at which a rim is sampled to find the envelope.
pub const RIM_SAMPLES: usize = 96;

/// How mounts are generated.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GenerateOptions {
    /// Polygon vertices around a tube or sleeve (≥ 8); axial rings and plate grids follow from it.
    pub segments: usize,
    /// Gap between a clear aperture's rim and the inner wall of its mount, mm.
    pub clearance_mm: f64,
    /// Wall thickness of every part, mm.
    pub wall_mm: f64,
    /// Radial width of the baffle, mm.
    pub baffle_width_mm: f64,
    /// Depth of the detector housing in front of the detector, mm (less when the last surface is closer).
    pub housing_depth_mm: f64,
    pub surface: SurfaceModel,
}

impl Default for GenerateOptions {
    fn default() -> Self {
        GenerateOptions { segments: 16, clearance_mm: 0.5, wall_mm: 1.0, baffle_width_mm: 5.0, housing_depth_mm: 10.0, surface: SurfaceModel::Absorbing }
    }
}

/// Unit axis angle below which two surface normals count as parallel (0.5°).
const PARALLEL_COS: f64 = 0.999_961_923_064_171_4;

/// A solid element of the path: consecutive surfaces with glass between them (or one ideal lens).
struct Element {
    surfaces: Vec<usize>,
    prism: bool,
}

/// The clear semi-diameter of every surface (index = surface), mm.
fn clear_radii(system: &SequentialSystem) -> Result<Vec<f64>> {
    let auto = mirrored_semi_diameters(system)?;
    Ok(system
        .surfaces
        .iter()
        .map(|s| {
            let a = auto.iter().find(|(i, _)| *i == s.index).map(|(_, v)| *v).unwrap_or(0.0);
            let explicit = match s.aperture {
                Aperture::Circular { semi_diameter_mm, decenter_x_mm, decenter_y_mm, .. } => semi_diameter_mm + decenter_x_mm.hypot(decenter_y_mm),
                Aperture::Rectangular { half_width_x_mm, half_width_y_mm, decenter_x_mm, decenter_y_mm } => {
                    (half_width_x_mm + decenter_x_mm.abs()).hypot(half_width_y_mm + decenter_y_mm.abs())
                }
                // The obscuring disc or ring is part of the surface's hardware: it reaches at least its outer radius.
                Aperture::CircularObscuration { max_radius_mm, decenter_x_mm, decenter_y_mm, .. } => max_radius_mm + decenter_x_mm.hypot(decenter_y_mm),
                Aperture::None => 0.0,
            };
            s.semi_diameter_mm.unwrap_or(0.0).max(a).max(explicit)
        })
        .collect())
}

/// The rim of surface `s` (radius `r`) on its figure, global coordinates.
fn rim(system: &SequentialSystem, s: usize, r: f64) -> Vec<DVec3> {
    let surf = &system.surfaces[s];
    (0..RIM_SAMPLES)
        .map(|i| {
            let a = TAU * i as f64 / RIM_SAMPLES as f64;
            let (x, y) = (r * a.cos(), r * a.sin());
            let z = surf.shape.as_ref().map(|sh| sh.sag(x, y)).filter(|z| z.is_finite()).unwrap_or(0.0);
            surf.frame.point_to_global(DVec3::new(x, y, z))
        })
        .collect()
}

fn elements(system: &SequentialSystem) -> Vec<Element> {
    let path: Vec<usize> = system.path.iter().map(|p| p.surface).collect();
    let mut out: Vec<Element> = Vec::new();
    let mut cur: Option<Vec<usize>> = None;
    for &s in &path[..path.len().saturating_sub(1)] {
        let glass_after = !system.surfaces[s].medium_after.is_air();
        match cur.as_mut() {
            Some(e) => {
                e.push(s);
                if !glass_after {
                    out.push(Element { surfaces: cur.take().unwrap(), prism: false });
                }
            }
            None if glass_after => cur = Some(vec![s]),
            None if matches!(system.surfaces[s].shape, Some(SurfaceShape::Paraxial { .. })) => out.push(Element { surfaces: vec![s], prism: false }),
            None => {}
        }
    }
    for e in &mut out {
        let z0 = system.surfaces[e.surfaces[0]].frame.rotation.z_axis;
        e.prism = e.surfaces.iter().any(|&s| system.surfaces[s].frame.rotation.z_axis.dot(z0).abs() < PARALLEL_COS);
    }
    out
}

/// A frame with origin `o` and z along `axis` (x chosen from the global axis least parallel to it).
fn frame_along(o: DVec3, axis: DVec3) -> Frame {
    let z = axis.normalize();
    let helper = if z.x.abs() < 0.9 { DVec3::X } else { DVec3::Y };
    let x = (helper - z * helper.dot(z)).normalize();
    Frame::new(o, DMat3::from_cols(x, z.cross(x), z))
}

/// A closed ring solid between an inner and an outer closed polygon (same vertex count, counter-clockwise
/// about +z, corresponding vertices), extruded from `z0` to `z1` in `frame` with `rings` axial divisions.
/// Outward normals: away from the axis on the outer wall, toward it on the inner wall, ∓z on the ends.
pub fn ring_solid(frame: &Frame, inner: &[(f64, f64)], outer: &[(f64, f64)], z0: f64, z1: f64, rings: usize) -> TriMesh {
    let p = inner.len();
    assert_eq!(p, outer.len());
    let rings = rings.max(1);
    let mut m = TriMesh::default();
    // Vertices: inner wall rings 0..=rings, then outer wall rings 0..=rings.
    for profile in [inner, outer] {
        for r in 0..=rings {
            let z = z0 + (z1 - z0) * r as f64 / rings as f64;
            for &(x, y) in profile {
                m.vertices.push(frame.point_to_global(DVec3::new(x, y, z)));
            }
        }
    }
    let iv = |r: usize, k: usize| (r * p + k % p) as u32;
    let ov = |r: usize, k: usize| ((rings + 1) * p + r * p + k % p) as u32;
    for r in 0..rings {
        for k in 0..p {
            // Outer wall: (k, r) → (k+1, r) → (k+1, r+1) is counter-clockwise seen from outside.
            m.triangles.push([ov(r, k), ov(r, k + 1), ov(r + 1, k + 1)]);
            m.triangles.push([ov(r, k), ov(r + 1, k + 1), ov(r + 1, k)]);
            // Inner wall, seen from the axis: reversed.
            m.triangles.push([iv(r, k), iv(r + 1, k + 1), iv(r, k + 1)]);
            m.triangles.push([iv(r, k), iv(r + 1, k), iv(r + 1, k + 1)]);
        }
    }
    for k in 0..p {
        // End at z0 (normal −z) and at z1 (normal +z).
        m.triangles.push([iv(0, k), iv(0, k + 1), ov(0, k + 1)]);
        m.triangles.push([iv(0, k), ov(0, k + 1), ov(0, k)]);
        m.triangles.push([iv(rings, k), ov(rings, k + 1), iv(rings, k + 1)]);
        m.triangles.push([iv(rings, k), ov(rings, k), ov(rings, k + 1)]);
    }
    m
}

/// A closed box [lo, hi] in `frame`, each face a `grid × grid` array of quads, outward normals.
pub fn box_solid(frame: &Frame, lo: DVec3, hi: DVec3, grid: usize) -> TriMesh {
    let g = grid.max(1);
    let mut m = TriMesh::default();
    let mut index = std::collections::HashMap::new();
    let mut vertex = |m: &mut TriMesh, c: [usize; 3]| -> u32 {
        *index.entry(c).or_insert_with(|| {
            let t = |i: usize, a: f64, b: f64| a + (b - a) * c[i] as f64 / g as f64;
            m.vertices.push(frame.point_to_global(DVec3::new(t(0, lo.x, hi.x), t(1, lo.y, hi.y), t(2, lo.z, hi.z))));
            (m.vertices.len() - 1) as u32
        })
    };
    // Face with fixed axis `a` at grid coordinate `side` (0 or g); (b, c) the other axes, right-handed.
    for a in 0..3 {
        let (b, c) = ((a + 1) % 3, (a + 2) % 3);
        for side in [0, g] {
            for i in 0..g {
                for j in 0..g {
                    let at = |di: usize, dj: usize| {
                        let mut k = [0; 3];
                        k[a] = side;
                        k[b] = i + di;
                        k[c] = j + dj;
                        k
                    };
                    let q = [at(0, 0), at(1, 0), at(1, 1), at(0, 1)].map(|k| vertex(&mut m, k));
                    // e_b × e_c = e_a: counter-clockwise seen from +a; flip on the low side.
                    if side == g {
                        m.triangles.push([q[0], q[1], q[2]]);
                        m.triangles.push([q[0], q[2], q[3]]);
                    } else {
                        m.triangles.push([q[0], q[2], q[1]]);
                        m.triangles.push([q[0], q[3], q[2]]);
                    }
                }
            }
        }
    }
    m
}

/// `n` points counter-clockwise on the circle of radius `r`.
fn circle(r: f64, n: usize) -> Vec<(f64, f64)> {
    (0..n).map(|k| (TAU * k as f64 / n as f64).sin_cos()).map(|(s, c)| (r * c, r * s)).collect()
}

/// `n` (a multiple of 4) points counter-clockwise on the rectangle |x| ≤ hx, |y| ≤ hy, starting at a corner.
fn rectangle(hx: f64, hy: f64, n: usize) -> Vec<(f64, f64)> {
    let q = (n / 4).max(1);
    let corners = [(hx, -hy), (hx, hy), (-hx, hy), (-hx, -hy)];
    (0..4)
        .flat_map(|side| {
            let (a, b) = (corners[side], corners[(side + 1) % 4]);
            (0..q).map(move |k| {
                let t = k as f64 / q as f64;
                (a.0 + (b.0 - a.0) * t, a.1 + (b.1 - a.1) * t)
            })
        })
        .collect()
}

/// Bounds of `points` in `frame`'s local coordinates: (max |x|, max |y|, min z, max z).
fn local_extent(frame: &Frame, points: &[DVec3]) -> (f64, f64, f64, f64) {
    points.iter().map(|p| frame.point_to_local(*p)).fold((0.0f64, 0.0f64, f64::INFINITY, f64::NEG_INFINITY), |(x, y, lo, hi), l| {
        (x.max(l.x.abs()), y.max(l.y.abs()), lo.min(l.z), hi.max(l.z))
    })
}

/// The generated mounts of `system`.
pub fn generate(system: &SequentialSystem, o: &GenerateOptions) -> Result<Vec<Part>> {
    if o.segments < 8 || o.segments > 4096 {
        return Err(Error::invalid(format!("mechanics segments = {}: must be in 8..=4096", o.segments)));
    }
    for (name, v) in [("clearance_mm", o.clearance_mm), ("wall_mm", o.wall_mm), ("baffle_width_mm", o.baffle_width_mm), ("housing_depth_mm", o.housing_depth_mm)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(Error::invalid(format!("mechanics {name} = {v}: must be finite and > 0")));
        }
    }
    let n = o.segments.div_ceil(4) * 4;
    let radii = clear_radii(system)?;
    let (c, w) = (o.clearance_mm, o.wall_mm);
    let elements = elements(system);
    let mut parts = Vec::new();
    let part = |kind: PartKind, name: String, mesh: TriMesh| Part { name, kind, surface: o.surface, mesh };

    // Lens groups: runs of coaxial lens elements with no prism between them.
    let mut groups: Vec<Vec<usize>> = Vec::new();
    let mut last_was_lens = false;
    for e in &elements {
        if e.prism {
            last_was_lens = false;
            continue;
        }
        let f = system.surfaces[e.surfaces[0]].frame;
        let joins = last_was_lens
            && groups.last().is_some_and(|g| {
                let g0 = system.surfaces[g[0]].frame;
                let off = g0.point_to_local(f.origin);
                f.rotation.z_axis.dot(g0.rotation.z_axis) >= PARALLEL_COS && off.x.hypot(off.y) < 0.1
            });
        if joins {
            groups.last_mut().unwrap().extend(&e.surfaces);
        } else {
            groups.push(e.surfaces.clone());
        }
        last_was_lens = true;
    }
    let mut baffle_done = false;
    for (gi, g) in groups.iter().enumerate() {
        let frame = system.surfaces[g[0]].frame;
        let pts: Vec<DVec3> = g.iter().flat_map(|&s| rim(system, s, radii[s])).collect();
        let r = pts.iter().map(|p| frame.point_to_local(*p)).map(|l| l.x.hypot(l.y)).fold(0.0, f64::max) + c;
        let (_, _, zlo, zhi) = local_extent(&frame, &pts);
        let (z0, z1) = (zlo - c, zhi + c);
        // The polygon is circumscribed about the circle of radius r (vertices at r / cos(π/n)).
        let k = 1.0 / (std::f64::consts::PI / n as f64).cos();
        let mesh = ring_solid(&frame, &circle(r * k, n), &circle((r + w) * k, n), z0, z1, n / 4);
        parts.push(part(PartKind::LensTube, format!("lens tube {} (surfaces {}–{})", gi + 1, g[0], g[g.len() - 1]), mesh));
        if !baffle_done {
            // Baffle: an annulus 1 mm in front of the first tube, its hole the tube's bore plus clearance.
            let (ri, ro) = ((r + c) * k, (r + c + o.baffle_width_mm) * k);
            let mesh = ring_solid(&frame, &circle(ri, n), &circle(ro, n), z0 - 1.0 - w, z0 - 1.0, 1);
            parts.push(part(PartKind::Baffle, "baffle".into(), mesh));
            baffle_done = true;
        }
    }
    for (pi, e) in elements.iter().filter(|e| e.prism).enumerate() {
        let first = rim(system, e.surfaces[0], radii[e.surfaces[0]]);
        let last = rim(system, e.surfaces[e.surfaces.len() - 1], radii[e.surfaces[e.surfaces.len() - 1]]);
        let centre = |v: &[DVec3]| v.iter().copied().sum::<DVec3>() / v.len() as f64;
        let axis = centre(&last) - centre(&first);
        let axis = if axis.length() > 1e-9 { axis } else { system.surfaces[e.surfaces[0]].frame.rotation.z_axis };
        let frame = frame_along(centre(&first), axis);
        let pts: Vec<DVec3> = e.surfaces.iter().flat_map(|&s| rim(system, s, radii[s])).collect();
        let (hx, hy, zlo, zhi) = local_extent(&frame, &pts);
        // Rays leave a tilted exit face deviated; the sleeve is padded by a quarter of its length so the
        // exit beam clears it before the open end.
        let pad = c + 0.25 * (zhi - zlo);
        let (hx, hy) = (hx + pad, hy + pad);
        let mesh = ring_solid(&frame, &rectangle(hx, hy, n), &rectangle(hx + w, hy + w, n), zlo - c, zhi + c, n / 4);
        parts.push(part(PartKind::PrismHolder, format!("prism holder {} (surfaces {}–{})", pi + 1, e.surfaces[0], e.surfaces[e.surfaces.len() - 1]), mesh));
    }
    // Detector housing: a sleeve around the detector and the beam's last leg, and a back plate.
    let img = system.surfaces.len() - 1;
    let frame = system.surfaces[img].frame;
    let before = system.path.len().checked_sub(2).map(|k| system.path[k].surface);
    let mut pts = rim(system, img, radii[img]);
    let mut depth = o.housing_depth_mm;
    if let Some(b) = before {
        let prev = rim(system, b, radii[b]);
        let (_, _, zlo, _) = local_extent(&frame, &prev);
        if zlo < 0.0 {
            depth = depth.min(0.5 * -zlo);
        }
        // The beam between the last surface and the detector lies in the hull of their rims: clip the
        // last surface's rim to the housing's depth by taking both rims' lateral extent.
        pts.extend(prev.iter().map(|p| {
            let l = frame.point_to_local(*p);
            frame.point_to_global(DVec3::new(l.x, l.y, 0.0))
        }));
    }
    let (hx, hy, _, _) = local_extent(&frame, &pts);
    let h = hx.max(hy) + c;
    let mut mesh = ring_solid(&frame, &rectangle(h, h, n), &rectangle(h + w, h + w, n), -depth, c, n / 8);
    mesh.append(&box_solid(&frame, DVec3::new(-h - w, -h - w, c), DVec3::new(h + w, h + w, c + w), n / 8));
    parts.push(part(PartKind::DetectorHousing, "detector housing".into(), mesh));
    Ok(parts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ring_and_box_are_closed_outward_solids() {
        let f = Frame::IDENTITY;
        let ring = ring_solid(&f, &circle(1.0, 16), &circle(2.0, 16), 0.0, 3.0, 4);
        ring.validate("ring", true).unwrap();
        let bx = box_solid(&f, DVec3::splat(-1.0), DVec3::splat(1.0), 3);
        bx.validate("box", true).unwrap();
        assert_eq!(bx.triangles.len(), 6 * 9 * 2);
        // Outward: the signed volume (divergence theorem) is positive and equals the solid's volume.
        let vol = |m: &TriMesh| (0..m.triangles.len()).map(|k| { let [a, b, c] = m.corners(k); a.dot(b.cross(c)) / 6.0 }).sum::<f64>();
        assert!((vol(&bx) - 8.0).abs() < 1e-12);
        let exact_ring = 3.0 * 0.5 * 16.0 * (2f64 * 2.0 - 1.0) * (TAU / 16.0).sin(); // polygon areas × height
        assert!((vol(&ring) - exact_ring).abs() < 1e-9, "{} vs {exact_ring}", vol(&ring));
        let rect = ring_solid(&f, &rectangle(1.0, 2.0, 8), &rectangle(1.5, 2.5, 8), 0.0, 1.0, 1);
        rect.validate("sleeve", true).unwrap();
        assert!((vol(&rect) - (3.0 * 5.0 - 2.0 * 4.0)).abs() < 1e-12);
    }
}
