//! [`TriMesh`]: an indexed triangle mesh in f64 (mm) with the checks a mechanical part must pass — finite
//! vertices, no degenerate triangle, no edge shared by more than two triangles, and (for a closed solid)
//! no open boundary edge — and its placement by a scale, a rotation and a translation.
//!
//! ```
//! use diffcassi::mechanics::TriMesh;
//! let tet = TriMesh::new(
//!     vec![[0., 0., 0.].into(), [1., 0., 0.].into(), [0., 1., 0.].into(), [0., 0., 1.].into()],
//!     vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
//! );
//! assert!(tet.validate("tetrahedron", true).is_ok());
//! ```
use crate::error::{Error, Result};
use crate::geometry::rotation_xyz;
use crate::limits::fmt_num;
use glam::DVec3;
use std::collections::HashMap;

/// Largest |coordinate| of a mesh vertex, in its file's units before `scale` or in mm after: 10¹⁵ (squared
/// lengths and cross products stay far from f64's overflow; a placed part must also lie within
/// ±[`crate::limits::MAX_LENGTH_MM`], checked with its `scale`).
pub const MAX_COORDINATE: f64 = 1e15;

/// An indexed triangle mesh, vertices in mm.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<DVec3>,
    pub triangles: Vec<[u32; 3]>,
    /// Where each triangle came from, for error messages (e.g. `"line 12"`, `"facet 3"`); empty for
    /// generated meshes.
    pub origin: Vec<String>,
}

impl TriMesh {
    pub fn new(vertices: Vec<DVec3>, triangles: Vec<[u32; 3]>) -> Self {
        TriMesh { vertices, triangles, origin: Vec::new() }
    }

    /// Triangle `k`'s three corners.
    #[inline]
    pub fn corners(&self, k: usize) -> [DVec3; 3] {
        let t = self.triangles[k];
        [self.vertices[t[0] as usize], self.vertices[t[1] as usize], self.vertices[t[2] as usize]]
    }

    /// Appends `other` (indices shifted).
    pub fn append(&mut self, other: &TriMesh) {
        let base = self.vertices.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(other.triangles.iter().map(|t| [t[0] + base, t[1] + base, t[2] + base]));
        if !other.origin.is_empty() || !self.origin.is_empty() {
            self.origin.resize(self.triangles.len() - other.triangles.len(), String::new());
            self.origin.extend(other.origin.iter().cloned());
            self.origin.resize(self.triangles.len(), String::new());
        }
    }

    /// Axis-aligned bounds (min, max), mm.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.vertices.iter().fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(lo, hi), v| (lo.min(*v), hi.max(*v)))
    }

    /// `p' = R · (scale · p) + translation` with R = Rx(a)·Ry(b)·Rz(c) (Zemax's tilt order, degrees in).
    pub fn placed(&self, translate_mm: [f64; 3], rotate_deg: [f64; 3], scale: f64) -> TriMesh {
        let r = rotation_xyz(rotate_deg[0].to_radians(), rotate_deg[1].to_radians(), rotate_deg[2].to_radians());
        let t = DVec3::from_array(translate_mm);
        let mut out = self.clone();
        for v in &mut out.vertices {
            *v = r * (*v * scale) + t;
        }
        // A negative scale mirrors the mesh: flip the winding so normals stay outward.
        if scale < 0.0 {
            for tri in &mut out.triangles {
                tri.swap(1, 2);
            }
        }
        out
    }

    fn where_(&self, k: usize) -> String {
        match self.origin.get(k) {
            Some(o) if !o.is_empty() => format!("triangle {k} ({o})"),
            _ => format!("triangle {k}"),
        }
    }

    /// Checks the mesh; `name` (a file or a part) starts every message. Errors: an empty mesh, a vertex
    /// index out of range, a non-finite vertex, a degenerate triangle (a repeated vertex or zero area
    /// relative to the mesh size: |e₁ × e₂| ≤ 1e-12 · L², L the bounding-box diagonal), an edge shared by
    /// more than two triangles (non-manifold), and with `closed`, an edge used by one triangle only (an
    /// open boundary: the mesh does not enclose a solid).
    pub fn validate(&self, name: &str, closed: bool) -> Result<()> {
        if self.triangles.is_empty() {
            return Err(Error::File { path: name.into(), message: "the mesh has no triangles".into() });
        }
        for (i, v) in self.vertices.iter().enumerate() {
            if !v.is_finite() {
                return Err(Error::File { path: name.into(), message: format!("vertex {i} = ({}, {}, {}) is not finite", v.x, v.y, v.z) });
            }
            // Beyond this the areas (squared lengths) the checks and the tracers compute overflow.
            if v.abs().max_element() > MAX_COORDINATE {
                let c = [v.x, v.y, v.z].into_iter().fold(0.0f64, |a, c| if c.abs() > a.abs() { c } else { a });
                return Err(Error::File {
                    path: name.into(),
                    message: format!("vertex {i} = ({}, {}, {}): coordinate {} is beyond ±{MAX_COORDINATE:e} (the geometry would overflow); check the file's units and `scale`", fmt_num(v.x), fmt_num(v.y), fmt_num(v.z), fmt_num(c)),
                });
            }
        }
        let (lo, hi) = self.bounds();
        let l2 = (hi - lo).length_squared();
        let n = self.vertices.len() as u32;
        let mut edges: HashMap<(u32, u32), u32> = HashMap::with_capacity(self.triangles.len() * 3 / 2 + 1);
        for (k, t) in self.triangles.iter().enumerate() {
            if t.iter().any(|&i| i >= n) {
                return Err(Error::File { path: name.into(), message: format!("{}: vertex index {:?} out of range (the mesh has {n} vertices)", self.where_(k), t) });
            }
            let [a, b, c] = self.corners(k);
            if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || (b - a).cross(c - a).length() <= 1e-12 * l2 {
                return Err(Error::File { path: name.into(), message: format!("{} is degenerate (zero area): corners {a:?}, {b:?}, {c:?}", self.where_(k)) });
            }
            for (p, q) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *edges.entry((p.min(q), p.max(q))).or_insert(0) += 1;
            }
        }
        let mut bad: Option<((u32, u32), u32)> = None;
        for (&e, &count) in &edges {
            if count > 2 || (closed && count == 1) {
                // Report the first by vertex order, so the message is deterministic.
                if !matches!(bad, Some((b, _)) if b < e) {
                    bad = Some((e, count));
                }
            }
        }
        if let Some(((p, q), count)) = bad {
            let users: Vec<String> = self
                .triangles
                .iter()
                .enumerate()
                .filter(|(_, t)| t.contains(&p) && t.contains(&q))
                .map(|(k, _)| self.where_(k))
                .collect();
            let (vp, vq) = (self.vertices[p as usize], self.vertices[q as usize]);
            let message = if count > 2 {
                format!("non-manifold edge from vertex {p} {vp:?} to vertex {q} {vq:?}: shared by {count} triangles ({})", users.join(", "))
            } else {
                format!("open boundary: the edge from vertex {p} {vp:?} to vertex {q} {vq:?} belongs to one triangle only ({}); a closed solid is required (set `closed = false` for a sheet)", users.join(", "))
            };
            return Err(Error::File { path: name.into(), message });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tet() -> TriMesh {
        TriMesh::new(vec![DVec3::ZERO, DVec3::X, DVec3::Y, DVec3::Z], vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    }

    #[test]
    fn closed_open_nonmanifold_degenerate_nan() {
        assert!(tet().validate("t", true).is_ok());
        let mut open = tet();
        open.triangles.pop();
        assert!(open.validate("t", false).is_ok());
        let e = open.validate("t", true).unwrap_err().to_string();
        assert!(e.contains("open boundary"), "{e}");
        let mut fan = tet();
        fan.vertices.push(DVec3::new(-1.0, -1.0, 0.0));
        fan.triangles.push([0, 1, 4]); // edge 0-1 now has three triangles
        let e = fan.validate("t", false).unwrap_err().to_string();
        assert!(e.contains("non-manifold edge from vertex 0") && e.contains("3 triangles"), "{e}");
        let mut flat = tet();
        flat.vertices[3] = DVec3::new(0.5, 0.5, 0.0);
        flat.triangles = vec![[0, 1, 2], [0, 1, 3]];
        flat.vertices[3] = DVec3::new(2.0, 0.0, 0.0); // collinear with 0 and 1
        let e = flat.validate("t", false).unwrap_err().to_string();
        assert!(e.contains("triangle 1 is degenerate"), "{e}");
        let mut nan = tet();
        nan.vertices[2].y = f64::NAN;
        let e = nan.validate("part.stl", true).unwrap_err().to_string();
        assert!(e.starts_with("part.stl: vertex 2") && e.contains("not finite"), "{e}");
    }

    #[test]
    fn placement_scales_rotates_translates() {
        let m = tet().placed([1.0, 2.0, 3.0], [0.0, 0.0, 90.0], 2.0);
        // X scaled by 2, rotated +90° about z → 2·Y, then translated.
        assert!((m.vertices[1] - DVec3::new(1.0, 4.0, 3.0)).length() < 1e-12);
        assert!(m.validate("t", true).is_ok());
        let mirrored = tet().placed([0.0; 3], [0.0; 3], -1.0);
        assert_eq!(mirrored.triangles[0], [0, 1, 2]);
    }
}
