//! Mesh import: STL (binary and ASCII) and Wavefront OBJ (`v` and `f` statements; polygons are
//! fan-triangulated, so they must be convex; materials, normals, texture coordinates, groups and lines are
//! ignored). Vertices of an STL (a triangle soup) are merged when bit-identical, so shared edges are
//! found. The result is checked by [`TriMesh::validate`].
//!
//! Hand-written rather than `stl_io`/`tobj` (both on crates.io): neither reports the line of a malformed
//! ASCII statement (`tobj` returns a bare `PositionParseError`), and the project's rule is that an error
//! names the file *and* the line; the formats' subsets read here are a few dozen lines each.
//!
//! Limits are checked before allocating: the file size ([`MAX_MESH_FILE_BYTES`]) before reading it, a
//! binary STL's triangle count against [`MAX_MESH_TRIANGLES`] and against the file's length before any
//! triangle is read, and ASCII triangle counts as they grow.
//!
//! ```
//! use diffcassi::mechanics::mesh_io::parse_mesh;
//! let obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
//! let m = parse_mesh(obj, "tet.obj", true)?;
//! assert_eq!(m.triangles.len(), 4);
//! let e = parse_mesh(b"v 0 0 nan\n", "bad.obj", true).unwrap_err();
//! assert!(e.to_string().contains("bad.obj: line 1"));
//! # Ok::<(), diffcassi::Error>(())
//! ```
use super::TriMesh;
use crate::error::{Error, Result};
use glam::DVec3;
use std::collections::HashMap;
use std::path::Path;

/// Most triangles an imported mesh may have.
pub const MAX_MESH_TRIANGLES: usize = 5_000_000;
/// Largest mesh file read, bytes (a binary STL of [`MAX_MESH_TRIANGLES`] is 250 MB).
pub const MAX_MESH_FILE_BYTES: u64 = 1 << 30;

/// Reads an STL or OBJ file (by extension: `.stl`, `.obj`, case-insensitive) and validates it
/// (`closed`: every edge must belong to exactly two triangles).
pub fn load_mesh(path: &Path, closed: bool) -> Result<TriMesh> {
    let name = path.display().to_string();
    let file_err = |message: String| Error::File { path: name.clone(), message };
    // A regular file (never a FIFO or device) within MAX_MESH_FILE_BYTES, checked before reading.
    let bytes = crate::io::input::read_input(path, MAX_MESH_FILE_BYTES).map_err(|e| match e {
        crate::io::IoError::Io { source, .. } => file_err(format!("cannot read the mesh file: {source}")),
        crate::io::IoError::Input { reason, .. } => file_err(format!("mesh file {reason}")),
        other => other.into(),
    })?;
    parse_mesh(&bytes, &name, closed)
}

/// Parses `bytes` as the format `name`'s extension says and validates the mesh.
pub fn parse_mesh(bytes: &[u8], name: &str, closed: bool) -> Result<TriMesh> {
    let ext = Path::new(name).extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let mesh = match ext.as_deref() {
        Some("stl") => parse_stl(bytes, name)?,
        Some("obj") => parse_obj(bytes, name)?,
        other => {
            return Err(Error::File { path: name.into(), message: format!("unknown mesh format {:?}: the extension must be .stl or .obj", other.unwrap_or("")) })
        }
    };
    mesh.validate(name, closed)?;
    Ok(mesh)
}

fn err(name: &str, message: String) -> Error {
    Error::File { path: name.into(), message }
}

/// Merges bit-identical vertices of a triangle soup.
struct Welder {
    index: HashMap<[u64; 3], u32>,
    mesh: TriMesh,
}

impl Welder {
    fn new() -> Self {
        Welder { index: HashMap::new(), mesh: TriMesh::default() }
    }
    fn vertex(&mut self, v: DVec3) -> u32 {
        // +0.0 and −0.0 are the same point.
        let key = [v.x + 0.0, v.y + 0.0, v.z + 0.0].map(f64::to_bits);
        let next = self.mesh.vertices.len() as u32;
        *self.index.entry(key).or_insert_with(|| {
            self.mesh.vertices.push(v);
            next
        })
    }
    fn triangle(&mut self, v: [DVec3; 3], origin: String) {
        let t = v.map(|p| self.vertex(p));
        self.mesh.triangles.push(t);
        self.mesh.origin.push(origin);
    }
}

/// STL: binary when the file is exactly 84 + 50·N bytes for the N its header gives, else ASCII if it
/// starts with `solid`, else a (truncated or corrupt) binary file.
pub fn parse_stl(bytes: &[u8], name: &str) -> Result<TriMesh> {
    let binary_size = (bytes.len() >= 84).then(|| 84 + 50 * u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as u64);
    // A `solid` header with binary data after it is a binary STL whose size is wrong (some CAD programs
    // start a binary file's header with `solid`): its error is the binary one, not "not valid UTF-8".
    if binary_size != Some(bytes.len() as u64) && bytes.trim_ascii_start().starts_with(b"solid") && (std::str::from_utf8(bytes).is_ok() || looks_like_text(&bytes[84.min(bytes.len())..])) {
        return parse_stl_ascii(bytes, name);
    }
    if binary_size != Some(bytes.len() as u64) && looks_like_text(bytes) {
        let first = String::from_utf8_lossy(bytes.trim_ascii_start().split(|&b| b == b'\n').next().unwrap_or_default());
        let first: String = first.trim_end().chars().take(40).collect();
        return Err(err(
            name,
            format!("text that is not an ASCII STL (an ASCII STL starts with `solid`; this file starts with `{first}`){}", if is_obj_text(bytes) { ": it looks like an OBJ file, name it .obj" } else { "" }),
        ));
    }
    if bytes.len() < 84 {
        return Err(err(name, format!("truncated binary STL: {} bytes, fewer than the 84 of the header and triangle count", bytes.len())));
    }
    let n = u32::from_le_bytes([bytes[80], bytes[81], bytes[82], bytes[83]]) as usize;
    if n > MAX_MESH_TRIANGLES {
        return Err(err(name, format!("binary STL header gives {n} triangles, more than the limit of {MAX_MESH_TRIANGLES}")));
    }
    if binary_size != Some(bytes.len() as u64) {
        let want = 84 + 50 * n;
        return Err(err(
            name,
            if bytes.len() > want {
                format!("binary STL longer than its header says: the header gives {n} triangles = {want} bytes, the file has {} ({} bytes after the last triangle; a wrong triangle count or trailing data)", bytes.len(), bytes.len() - want)
            } else {
                format!("truncated binary STL: the header gives {n} triangles = {want} bytes, the file has {}", bytes.len())
            },
        ));
    }
    let mut w = Welder::new();
    w.mesh.triangles.reserve(n);
    let f = |b: &[u8], at: usize| f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]]) as f64;
    for k in 0..n {
        let rec = &bytes[84 + 50 * k..84 + 50 * (k + 1)];
        let mut v = [DVec3::ZERO; 3];
        for (j, p) in v.iter_mut().enumerate() {
            let at = 12 + 12 * j;
            *p = DVec3::new(f(rec, at), f(rec, at + 4), f(rec, at + 8));
            if !p.is_finite() {
                return Err(err(name, format!("facet {k} vertex {j} = ({}, {}, {}) is not finite", p.x, p.y, p.z)));
            }
        }
        w.triangle(v, format!("facet {k}"));
    }
    Ok(w.mesh)
}

/// The first 512 bytes are printable ASCII or whitespace (a binary STL's float data almost never is).
fn looks_like_text(bytes: &[u8]) -> bool {
    !bytes.is_empty() && bytes.iter().take(512).all(|&b| b.is_ascii_graphic() || b.is_ascii_whitespace())
}

/// Text whose statements start like an OBJ file's (`v`, `vn`, `vt`, `f`, `o`, `g`, `#`, `mtllib`, …).
fn is_obj_text(bytes: &[u8]) -> bool {
    String::from_utf8_lossy(&bytes[..bytes.len().min(4096)])
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .take(8)
        .any(|l| ["v ", "vn ", "vt ", "f ", "o ", "g ", "mtllib ", "usemtl "].iter().any(|k| l.starts_with(k)))
}

/// The non-blank lines of an ASCII STL as whitespace-split statements, with the line number.
struct Statements<'a> {
    lines: Box<dyn Iterator<Item = (usize, Vec<&'a str>)> + 'a>,
    last_line: usize,
    name: &'a str,
}

impl<'a> Statements<'a> {
    /// The next statement, `None` at the end of the file.
    fn next_or_end(&mut self) -> Option<(usize, Vec<&'a str>)> {
        let (n, t) = self.lines.next()?;
        self.last_line = n;
        Some((n, t))
    }

    /// The next statement; the end of the file is an error naming what was expected.
    fn next(&mut self, what: &str) -> Result<(usize, Vec<&'a str>)> {
        let last = self.last_line;
        self.next_or_end().ok_or_else(|| err(self.name, format!("truncated ASCII STL: the file ends after line {last}, expected `{what}`")))
    }
}

fn parse_stl_ascii(bytes: &[u8], name: &str) -> Result<TriMesh> {
    let text = std::str::from_utf8(bytes).map_err(|e| err(name, format!("ASCII STL is not valid UTF-8 (byte {})", e.valid_up_to())))?;
    // NUL bytes (a padded export's tail) separate statements like whitespace.
    let mut st = Statements {
        lines: Box::new(text.lines().enumerate().map(|(i, l)| (i + 1, l.split(|c: char| c.is_whitespace() || c == '\0').filter(|w| !w.is_empty()).collect::<Vec<_>>())).filter(|(_, t)| !t.is_empty())),
        last_line: 0,
        name,
    };
    let (n0, first) = st.next("solid")?;
    if first[0] != "solid" {
        return Err(err(name, format!("line {n0}: expected `solid`, found `{}`", first.join(" "))));
    }
    let mut w = Welder::new();
    // CAD exports write several bodies as consecutive `solid … endsolid` blocks: all of them are the mesh.
    'solids: loop {
        let (n, t) = st.next("facet normal nx ny nz` or `endsolid")?;
        match t[0] {
            "endsolid" => {
                let Some((n, t)) = st.next_or_end() else { break 'solids };
                if t[0] != "solid" {
                    return Err(err(name, format!("line {n}: expected `solid` (another body) or the end of the file after `endsolid`, found `{}`", t.join(" ").escape_debug())));
                }
                // Each body is welded on its own: two bodies that touch (a shared face) stay two closed
                // solids, not one non-manifold one (as two mesh files would).
                w.index.clear();
                continue 'solids;
            }
            "facet" if t.len() == 5 && t[1] == "normal" => {}
            _ => return Err(err(name, format!("line {n}: expected `facet normal nx ny nz` or `endsolid`, found `{}`", t.join(" ")))),
        }
        let facet_line = n;
        let (n, t) = st.next("outer loop")?;
        if t != ["outer", "loop"] {
            return Err(err(name, format!("line {n}: expected `outer loop`, found `{}`", t.join(" "))));
        }
        let mut v = [DVec3::ZERO; 3];
        for p in &mut v {
            let (n, t) = st.next("vertex x y z")?;
            if t.len() != 4 || t[0] != "vertex" {
                return Err(err(name, format!("line {n}: expected `vertex x y z`, found `{}`", t.join(" "))));
            }
            let mut c = [0.0; 3];
            for (j, s) in t[1..].iter().enumerate() {
                c[j] = s.parse::<f64>().map_err(|_| err(name, format!("line {n}: vertex coordinate `{s}` is not a number")))?;
                if !c[j].is_finite() {
                    return Err(err(name, format!("line {n}: vertex coordinate `{s}` is not finite")));
                }
            }
            *p = DVec3::from_array(c);
        }
        for what in [&["endloop"][..], &["endfacet"][..]] {
            let (n, t) = st.next(what[0])?;
            if t != what {
                return Err(err(name, format!("line {n}: expected `{}`, found `{}`", what[0], t.join(" "))));
            }
        }
        if w.mesh.triangles.len() >= MAX_MESH_TRIANGLES {
            return Err(err(name, format!("line {facet_line}: more than the limit of {MAX_MESH_TRIANGLES} triangles")));
        }
        w.triangle(v, format!("line {facet_line}"));
    }
    Ok(w.mesh)
}

/// OBJ `v` (x y z [w], w ignored) and `f` (1-based or negative relative indices, `i`, `i/t`, `i//n`,
/// `i/t/n`) statements; every other statement is ignored.
pub fn parse_obj(bytes: &[u8], name: &str) -> Result<TriMesh> {
    let text = std::str::from_utf8(bytes).map_err(|e| err(name, format!("OBJ is not valid UTF-8 (byte {})", e.valid_up_to())))?;
    let mut mesh = TriMesh::default();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let line = line.split('#').next().unwrap_or("");
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first().copied() {
            Some("v") => {
                // `v x y z [w]`, or `v x y z r g b` (vertex colours, as MeshLab writes them): only x y z are read.
                if !matches!(t.len(), 4 | 5 | 7) {
                    return Err(err(name, format!("line {n}: expected `v x y z [w]` (or `v x y z r g b`), found `{}`", t.join(" "))));
                }
                let mut c = [0.0; 3];
                for (j, s) in t[1..4].iter().enumerate() {
                    c[j] = s.parse::<f64>().map_err(|_| err(name, format!("line {n}: vertex coordinate `{s}` is not a number")))?;
                    if !c[j].is_finite() {
                        return Err(err(name, format!("line {n}: vertex coordinate `{s}` is not finite")));
                    }
                }
                mesh.vertices.push(DVec3::from_array(c));
            }
            Some("f") => {
                if t.len() < 4 {
                    return Err(err(name, format!("line {n}: a face needs at least 3 vertices, found `{}`", t.join(" "))));
                }
                let count = mesh.vertices.len() as i64;
                let mut idx = Vec::with_capacity(t.len() - 1);
                for s in &t[1..] {
                    let head = s.split('/').next().unwrap_or("");
                    let k: i64 = head.parse().map_err(|_| err(name, format!("line {n}: face vertex `{s}` is not an index")))?;
                    let abs = if k > 0 { k - 1 } else { count + k };
                    if k == 0 || abs < 0 || abs >= count {
                        return Err(err(name, format!("line {n}: face vertex index {k} out of range ({count} vertices defined so far)")));
                    }
                    idx.push(abs as u32);
                }
                if mesh.triangles.len() + idx.len() - 2 > MAX_MESH_TRIANGLES {
                    return Err(err(name, format!("line {n}: more than the limit of {MAX_MESH_TRIANGLES} triangles")));
                }
                let triangles = triangulate(&mesh.vertices, &idx).map_err(|e| err(name, format!("line {n}: a face of {} vertices {e}", idx.len())))?;
                for t in triangles {
                    mesh.triangles.push(t);
                    mesh.origin.push(format!("line {n}"));
                }
            }
            _ => {}
        }
    }
    Ok(mesh)
}

/// Largest distance of a polygon's vertex from its plane, relative to the square root of its area (its width,
/// not its length: a long thin twisted quad is not planar), that is still planar: either triangulation is then
/// the same surface to 1 % of its size. CAD exports round coordinates to f32, or to a few decimals in text (a
/// 0.1 mm face in metres with 6 decimals, Blender's default, is off by 5e-3 of its size).
const PLANAR_TOLERANCE: f64 = 1e-2;

/// Largest angle (rad, as its sine) between a corner's plane and the polygon's that is still planar: a long
/// thin quad twisted at one end (its triangles 79° apart) tilts the best plane so that every vertex lies near
/// it, but not its corners (a prober, round 11).
const CORNER_TOLERANCE: f64 = 2e-2;

/// Triangles of a planar polygon face (`idx` into `vertices`, in its winding order, which the triangles
/// keep). A convex polygon is fanned from its first vertex, as OBJ readers do (from a straight corner if it
/// has one); a concave one is ear-clipped in its plane (a fan from a reflex vertex would cover its notch).
/// Errors: a polygon that is not planar (which triangles it means is ambiguous), that holds a point twice, or
/// that is not simple (two edges cross).
fn triangulate(vertices: &[DVec3], idx: &[u32]) -> std::result::Result<Vec<[u32; 3]>, String> {
    let n = idx.len();
    let fan_from = |s: usize| (1..n - 1).map(|j| [idx[s], idx[(s + j) % n], idx[(s + j + 1) % n]]).collect::<Vec<_>>();
    let fan = || fan_from(0);
    if n == 3 {
        return Ok(fan());
    }
    let p: Vec<DVec3> = idx.iter().map(|&k| vertices[k as usize]).collect();
    if let Some((i, j)) = (0..n).flat_map(|i| (i + 1..n).map(move |j| (i, j))).find(|&(i, j)| p[i] == p[j]) {
        return Err(format!("has the same point twice (its vertices {} and {}): split it into triangles", i + 1, j + 1));
    }
    // Newell's normal: twice the vector area, well defined for concave polygons.
    let mut normal = DVec3::ZERO;
    for (a, b) in p.iter().zip(p.iter().cycle().skip(1)) {
        normal += DVec3::new((a.y - b.y) * (a.z + b.z), (a.z - b.z) * (a.x + b.x), (a.x - b.x) * (a.y + b.y));
    }
    let Some(nz) = normal.try_normalize() else {
        return Err("has zero area (its points are collinear, or it folds onto itself like a symmetric bow tie): remove it or split it into triangles".to_string());
    };
    let size = (0.5 * normal.length()).sqrt();
    let centroid = p.iter().copied().sum::<DVec3>() / p.len() as f64;
    let diameter = p.iter().flat_map(|a| p.iter().map(move |b| (*a - *b).length())).fold(0.0, f64::max);
    // Plus the f32 rounding of coordinates far from the origin (a 0.5 mm face 1 m away).
    let far = p.iter().map(|v| v.abs().max_element()).fold(0.0, f64::max);
    if let Some((j, off)) = p.iter().map(|v| (*v - centroid).dot(nz).abs()).enumerate().max_by(|a, b| a.1.total_cmp(&b.1)) {
        if off > PLANAR_TOLERANCE * size + 4.0 * f32::EPSILON as f64 * far {
            return Err(format!("is not planar (its vertex {} lies {off:.3e} off the polygon's plane; its area is {:.3e}): split it into triangles", j + 1, size * size));
        }
    }
    for i in 0..n {
        let (a, b, c) = (p[(i + n - 1) % n], p[i], p[(i + 1) % n]);
        let corner = (c - b).cross(a - b);
        // A straight corner has no plane of its own.
        if corner.length() > 1e-9 * diameter * diameter {
            let sin = corner.normalize().cross(nz).length();
            if sin > CORNER_TOLERANCE {
                return Err(format!("is not planar (its corner at vertex {} turns {:.1}° out of the polygon's plane): split it into triangles", i + 1, sin.asin().to_degrees()));
            }
        }
    }
    // In-plane coordinates, the polygon counter-clockwise about its Newell normal.
    let u = nz.any_orthonormal_vector();
    let w = nz.cross(u);
    let q: Vec<(f64, f64)> = p.iter().map(|v| ((*v - centroid).dot(u), (*v - centroid).dot(w))).collect();
    let cross = |a: (f64, f64), b: (f64, f64), c: (f64, f64)| (b.0 - a.0) * (c.1 - b.1) - (b.1 - a.1) * (c.0 - b.0);
    let m = q.len();
    // Simple: no two edges that do not share a vertex meet (a bow tie, a pentagram: no triangulation follows).
    let meet = |(a, b): ((f64, f64), (f64, f64)), (c, d): ((f64, f64), (f64, f64))| {
        let (d1, d2, d3, d4) = (cross(a, b, c), cross(a, b, d), cross(c, d, a), cross(c, d, b));
        if (d1, d2, d3, d4) == (0.0, 0.0, 0.0, 0.0) {
            // Collinear: they meet where their extents overlap.
            let overlap = |p: fn((f64, f64)) -> f64| p(a).min(p(b)).max(p(c).min(p(d))) <= p(a).max(p(b)).min(p(c).max(p(d)));
            return overlap(|v| v.0) && overlap(|v| v.1);
        }
        d1 * d2 <= 0.0 && d3 * d4 <= 0.0
    };
    let edge = |i: usize| (q[i], q[(i + 1) % m]);
    if let Some((i, j)) = (0..m).flat_map(|i| (i + 2..m).filter(move |&j| (j + 1) % m != i).map(move |j| (i, j))).find(|&(i, j)| meet(edge(i), edge(j))) {
        return Err(format!("is not a simple polygon (its edges {}–{} and {}–{} cross): split it into triangles", i + 1, (i + 1) % m + 1, j + 1, (j + 1) % m + 1));
    }
    let turn = |i: usize| cross(q[(i + m - 1) % m], q[i], q[(i + 1) % m]);
    // A turn within rounding of 0 (the projection into the plane) is a straight corner.
    let straight = 1e-12 * diameter * diameter;
    if (0..m).all(|i| turn(i) >= -straight) {
        // Convex: fanned from a vertex that lies on the line of its two edges, if any (a fan from elsewhere
        // would have a zero-area triangle through it), else from the first.
        return Ok(fan_from((0..m).find(|&i| turn(i).abs() <= straight).unwrap_or(0)));
    }
    // Ear clipping: an ear is a convex corner whose triangle holds no other remaining vertex.
    let inside = |t: [(f64, f64); 3], x: (f64, f64)| cross(t[0], t[1], x) >= 0.0 && cross(t[1], t[2], x) >= 0.0 && cross(t[2], t[0], x) >= 0.0;
    let mut left: Vec<usize> = (0..m).collect();
    let mut out = Vec::with_capacity(m - 2);
    while left.len() > 3 {
        let k = left.len();
        let ear = (0..k).find(|&i| {
            let (a, b, c) = (left[(i + k - 1) % k], left[i], left[(i + 1) % k]);
            let t = [q[a], q[b], q[c]];
            cross(t[0], t[1], t[2]) > straight && left.iter().filter(|&&o| o != a && o != b && o != c).all(|&o| !inside(t, q[o]))
        });
        let Some(i) = ear else {
            return Err("is not a simple polygon (its edges fold back on each other): split it into triangles".to_string());
        };
        out.push([idx[left[(i + k - 1) % k]], idx[left[i]], idx[left[(i + 1) % k]]]);
        left.remove(i);
    }
    out.push([idx[left[0]], idx[left[1]], idx[left[2]]]);
    Ok(out)
}

/// Binary STL bytes of `mesh` (f32 coordinates, zero normals and attribute words): the fixtures' writer.
pub fn write_stl_binary(mesh: &TriMesh) -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out.extend_from_slice(&(mesh.triangles.len() as u32).to_le_bytes());
    for k in 0..mesh.triangles.len() {
        out.extend_from_slice(&[0u8; 12]);
        for v in mesh.corners(k) {
            for c in v.to_array() {
                out.extend_from_slice(&(c as f32).to_le_bytes());
            }
        }
        out.extend_from_slice(&[0u8; 2]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    const TET_OBJ: &str = "# tetrahedron\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nf 1//1 3//1 2//1\nf 1 2 4\nf -4 -1 -2\nf 2 3 4\n";

    fn tet() -> TriMesh {
        parse_obj(TET_OBJ.as_bytes(), "t.obj").unwrap()
    }

    #[test]
    fn obj_quads_are_fan_triangulated_and_negative_indices_resolve() {
        let m = tet();
        assert_eq!(m.triangles[2], [0, 3, 2]);
        m.validate("t.obj", true).unwrap();
        let cube = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n\
                    f 1 4 3 2\nf 5 6 7 8\nf 1 2 6 5\nf 2 3 7 6\nf 3 4 8 7\nf 4 1 5 8\n";
        let m = parse_mesh(cube.as_bytes(), "cube.OBJ", true).unwrap();
        assert_eq!(m.triangles.len(), 12);
        assert_eq!(m.origin[11], "line 14");
    }

    #[test]
    fn stl_binary_round_trip_and_truncation() {
        let bytes = write_stl_binary(&tet());
        let m = parse_mesh(&bytes, "t.stl", true).unwrap();
        assert_eq!((m.vertices.len(), m.triangles.len()), (4, 4));
        let e = parse_stl(&bytes[..bytes.len() - 7], "t.stl").unwrap_err().to_string();
        assert!(e.contains("truncated binary STL") && e.contains("4 triangles"), "{e}");
        let e = parse_stl(&bytes[..50], "t.stl").unwrap_err().to_string();
        assert!(e.contains("fewer than the 84"), "{e}");
        let mut huge = bytes.clone();
        huge[80..84].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = parse_stl(&huge, "t.stl").unwrap_err().to_string();
        assert!(e.contains("more than the limit"), "{e}");
    }

    #[test]
    fn ascii_stl_errors_name_the_line() {
        let good = "solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n";
        let m = parse_stl(good.as_bytes(), "a.stl").unwrap();
        assert_eq!(m.triangles.len(), 1);
        let e = parse_stl(good.replace("vertex 1 0 0", "vertex 1 nan 0").as_bytes(), "a.stl").unwrap_err().to_string();
        assert!(e.contains("a.stl: line 5") && e.contains("not finite"), "{e}");
        let e = parse_stl(good.replace("endloop", "endloops").as_bytes(), "a.stl").unwrap_err().to_string();
        assert!(e.contains("line 7: expected `endloop`"), "{e}");
        let e = parse_stl(&good.as_bytes()[..60], "a.stl").unwrap_err().to_string();
        assert!(e.contains("truncated ASCII STL"), "{e}");
        let e = parse_mesh(b"v 0 0 0\nf 1 2 3\n", "x.obj", false).unwrap_err().to_string();
        assert!(e.contains("line 2: face vertex index 2 out of range"), "{e}");
        let e = parse_mesh(b"", "x.ply", false).unwrap_err().to_string();
        assert!(e.contains("unknown mesh format"), "{e}");
    }

    /// Round 11: an ASCII STL of several bodies (`solid … endsolid` blocks, as CAD programs export "all bodies")
    /// is all of them (the second was dropped); text after the last `endsolid` is an error naming its line.
    #[test]
    fn ascii_stl_of_several_bodies_is_every_body() {
        let body = |name: &str, z: f64| {
            let mut t = format!("solid {name}\n");
            for tri in tet().triangles.iter() {
                t += " facet normal 0 0 0\n  outer loop\n";
                for &k in tri {
                    let v = tet().vertices[k as usize];
                    t += &format!("   vertex {} {} {}\n", v.x, v.y, v.z + z);
                }
                t += "  endloop\n endfacet\n";
            }
            t + &format!("endsolid {name}\n")
        };
        let two = body("bracket", 0.0) + &body("blocker", 5.0);
        let m = parse_mesh(two.as_bytes(), "bodies.stl", true).unwrap();
        assert_eq!((m.vertices.len(), m.triangles.len()), (8, 8));
        let trailing = body("t", 0.0) + "this is not stl at all\n";
        let e = parse_stl(trailing.as_bytes(), "t.stl").unwrap_err().to_string();
        assert!(e.contains("t.stl: line 31") && e.contains("after `endsolid`") && e.contains("this is not stl at all"), "{e}");
        // A binary file whose header starts with `solid` (SolidWorks) and whose size is wrong: the binary error.
        let mut bin = write_stl_binary(&tet());
        bin[..5].copy_from_slice(b"solid");
        bin[84 + 10] = 0xff;
        let e = parse_stl(&bin[..bin.len() - 50], "s.stl").unwrap_err().to_string();
        assert!(e.contains("truncated binary STL") && e.contains("4 triangles"), "{e}");
    }

    /// Round 11: a concave polygon was fanned from its first vertex, covering its notch when that vertex sees
    /// past it (an L-shaped face absorbed the light the notch lets through); it is ear-clipped, whatever vertex
    /// the face starts from, and keeps its winding. A non-planar or self-crossing polygon is refused, naming the
    /// line; `v x y z r g b` (vertex colours) is read.
    #[test]
    fn concave_obj_faces_are_ear_clipped() {
        // The L: a 40 × 40 mm square without its x > 0, y > 0 quarter (area 1200 mm²), one face.
        let l = [(-20.0, -20.0), (20.0, -20.0), (20.0, 0.0), (0.0, 0.0), (0.0, 20.0), (-20.0, 20.0)];
        for start in 0..6 {
            let mut text = String::new();
            for (x, y) in l {
                text += &format!("v {x} {y} 50 0.5 0.5 0.5\n");
            }
            let order: Vec<String> = (0..6).map(|k| ((start + k) % 6 + 1).to_string()).collect();
            text += &format!("f {}\n", order.join(" "));
            let m = parse_obj(text.as_bytes(), "l.obj").unwrap();
            assert_eq!(m.triangles.len(), 4, "start {start}");
            let mut area = 0.0;
            for k in 0..m.triangles.len() {
                let [a, b, c] = m.corners(k);
                let n = (b - a).cross(c - a);
                assert!(n.z > 0.0, "start {start}: triangle {k} keeps the face's (counter-clockwise) winding");
                area += 0.5 * n.length();
                // No triangle covers the notch's point (10, 10).
                let p = DVec3::new(10.0, 10.0, 50.0);
                let inside = [(a, b), (b, c), (c, a)].iter().all(|(u, v)| (*v - *u).cross(p - *u).z > 0.0);
                assert!(!inside, "start {start}: triangle {k} covers the notch");
            }
            assert!((area - 1200.0).abs() < 1e-9, "start {start}: area {area}");
        }
        let e = parse_obj(b"v 0 0 0\nv 1 0 0\nv 1 1 0.5\nv 0 1 0\nf 1 2 3 4\n", "bent.obj").unwrap_err().to_string();
        assert!(e.contains("bent.obj: line 5: a face of 4 vertices is not planar"), "{e}");
        let e = parse_obj(b"v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\nv 0.5 -1 0\nf 1 2 3 4 5\n", "bow.obj").unwrap_err().to_string();
        assert!(e.contains("line 6") && e.contains("not a simple polygon"), "{e}");
        // A pentagram turns the same way at every corner: refused, not fanned.
        let star: String = (0..5).map(|k| { let a = (2 * k) as f64 * std::f64::consts::TAU / 5.0; format!("v {} {} 0\n", a.cos(), a.sin()) }).collect::<String>() + "f 1 2 3 4 5\n";
        let e = parse_obj(star.as_bytes(), "star.obj").unwrap_err().to_string();
        assert!(e.contains("line 6") && e.contains("not a simple polygon"), "{e}");
        let e = parse_obj(b"v 0 0 0 1 1\n", "c.obj").unwrap_err().to_string();
        assert!(e.contains("line 1: expected `v x y z [w]`"), "{e}");
    }

    /// A second prober of round 11: two bodies that touch (a shared face) are welded each on its own and load as
    /// two closed solids; a flat face from an f32 or 4-decimal export, far from the origin, is planar; a convex
    /// face with a straight corner next to its first vertex loads; a repeated point is named; NUL padding after
    /// the last `endsolid` is blank.
    #[test]
    fn cad_exports_load_as_written() {
        let cube = |x0: f64| -> String {
            let c = |i: u32| DVec3::new(x0 + (i & 1) as f64, ((i >> 1) & 1) as f64, ((i >> 2) & 1) as f64);
            let faces = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [1, 3, 7, 5], [3, 2, 6, 7], [2, 0, 4, 6]];
            let mut t = format!("solid c{x0}\n");
            for f in faces {
                for tri in [[f[0], f[1], f[2]], [f[0], f[2], f[3]]] {
                    t += " facet normal 0 0 0\n  outer loop\n";
                    for k in tri {
                        let v = c(k);
                        t += &format!("   vertex {} {} {}\n", v.x, v.y, v.z);
                    }
                    t += "  endloop\n endfacet\n";
                }
            }
            t + "endsolid\n"
        };
        let two = cube(0.0) + &cube(1.0) + "\0\0\0\0";
        let m = parse_mesh(two.as_bytes(), "touching.stl", true).unwrap();
        assert_eq!((m.vertices.len(), m.triangles.len()), (16, 24));
        // A 0.7 mm quad 1 m from the origin in f32, and a 1 mm quad written with 4 decimals.
        let (x, y) = (1000.123_f32, -999.877_f32);
        let f32_quad = format!("v {} {} 500.5\nv {} {} 500.5\nv {} {} 500.5\nv {} {} 500.5\nf 1 2 3 4\n", x, y, x + 0.5, y, x + 0.5, y + 0.5, x, y + 0.5);
        parse_obj(f32_quad.as_bytes(), "far.obj").unwrap();
        parse_obj(b"v 0 0 0\nv 1.0000 0 0.00004\nv 1.0000 1.0000 -0.00004\nv 0 1.0000 0.00004\nf 1 2 3 4\n", "dec.obj").unwrap();
        // A square with a point on its first edge, listed right after the first vertex: no zero-area triangle.
        let m = parse_obj(b"v 0 0 0\nv 0.5 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4 5\n", "straight.obj").unwrap();
        for k in 0..m.triangles.len() {
            let [a, b, c] = m.corners(k);
            assert!((b - a).cross(c - a).length() > 1e-9, "triangle {k} {:?}", m.triangles[k]);
        }
        let e = parse_obj(b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 1 0 0\nf 1 2 3 4 5\n", "twice.obj").unwrap_err().to_string();
        assert!(e.contains("the same point twice (its vertices 2 and 5)"), "{e}");
        // A fourth prober: a symmetric bow tie (zero area) and a 100 × 0.01 mm quad twisted at one end (its best
        // plane tilts so that every vertex lies near it) are refused; a 50 µm face in metres with 6 decimals loads.
        let e = parse_obj(b"v 0 0 0\nv 1 1 0\nv 1 0 0\nv 0 1 0\nf 1 2 3 4\n", "bow.obj").unwrap_err().to_string();
        assert!(e.contains("has zero area"), "{e}");
        let e = parse_obj(b"v 0 0 0\nv 100 0 0\nv 100 0.01 0.05\nv 0 0.01 0\nf 1 2 3 4\n", "sliver.obj").unwrap_err().to_string();
        assert!(e.contains("is not planar") && e.contains("out of the polygon's plane"), "{e}");
        parse_obj(b"v 0.054486 0.033118 0.019233\nv 0.054532 0.033101 0.019226\nv 0.054532 0.033120 0.019180\nv 0.054486 0.033137 0.019187\nf 1 2 3 4\n", "m.obj").unwrap();
    }
}
