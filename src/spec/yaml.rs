//! Import of the reference paper's YAML system files (Paillet et al., `DiffCassiSim`, a fork of dO /
//! DiffOptics): `shared/reference/systems/*.yml` and whatever users of that tool bring.
//!
//! # The YAML model (as the paper's tracer evaluates it)
//!
//! Confirmed in `lpaillet-laas/DiffCassiSim`: `CASSI_class.py` (`HSSystem.import_system`, `create_system`,
//! `create_lensgroup`, `trace_psf_from_point_source`, `extract_hexapolar_dir`, `plot_spot_diagram`),
//! `diffoptics/optics.py` (`Lensgroup`, `Surface`, `Aspheric`, `XYPolynomial`, `ThinLens`) and
//! `diffoptics/basics.py` (`rodrigues_rotation_matrix`, `Transformation`).
//!
//! * The system is a list of element groups `g`. Group `g` has a rigid frame `global = R·local + t` with
//!   `R` the product of single-axis right-handed rotations (Rodrigues, angle in degrees, positive = counter-
//!   clockwise about the axis) **in the order listed** by `list_rotation_order[g]` (`"xyz"` → Rx·Ry·Rz,
//!   `"yxz"` → Ry·Rx·Rz), and `t = origin + R·shift` (`list_origin[g]` null → 0, `list_shift[g]` null → 0).
//! * Surface `i` of a group sits at local `z = d₀ + … + dᵢ` (`d` is relative to the previous surface).
//! * `ThinLens` (`params.f`): ideal lens in the plane `z = z_i`; a ray of direction (dx, dy, dz) leaves
//!   toward (f·dx/dz, f·dy/dz, z_i + f) — Zemax's Paraxial surface. The media around it are ignored by dO.
//!   Clear aperture: the disc of radius `R` (dO ignores `is_square` there).
//! * `XYPolynomial` (`J`, `ai`, `b`): `b z² − z + Σ_{j≤J} Σ_{i≤j} a_k xⁱ y^{j−i} = 0` around `z_i`, `a_k`
//!   counted with `j` outer, `i` inner: `ai = [a₀, a_y, a_x, …]`. With `b = 0` and `J = 1` it is the plane
//!   `z = z_i + a₀ + a_y·y + a_x·x` (so `ai = [0, 0, t]` is `z = z_i + t·x`).
//! * `Aspheric` (`c`, `k`, `ai`): `z = c r²/(1 + √(1 − (1+k)c²r²)) + ai[0] r⁴ + ai[1] r⁶ + …` (dO's
//!   `ai` start at r⁴). Note: `create_lensgroup` does not pass `k` on to dO, so the paper's tracer always
//!   uses k = 0; this importer honours the file's `k` (every reference file has `k: 0.0`).
//! * Apertures: dO keeps a ray if its intersection's *group-frame* (x, y) satisfies `x² + y² < R²`, or
//!   `max(|x|, |y|) < R` when `params.is_square` is true. The surface-level `is_square` key found in the
//!   reference files is not read by the paper's code and is ignored here too.
//! * `systems_materials[g]` lists the media before, between and after the group's surfaces (one more
//!   entry than surfaces); `air`/`vacuum` are the surrounding air.
//! * Rays start at the object plane `z = 0` of the global frame and the centre of every traced cone is the
//!   direction +z (object-space telecentric sampling: `extract_hexapolar_dir`, `plot_spot_diagram`).
//!   Each group is traced in turn; only the last group's `list_d_sensor` matters for forward tracing: the
//!   detector is the plane `z = d_sensor` of the last group's frame, and image coordinates are that frame's
//!   local (x, y). `list_r_last`, `list_film_size`, `list_pixel_size`, `device` and `save_dir` do not affect
//!   the geometry.
//!
//! # Mapping into the sequential model
//!
//! * Surface 0: the object plane, global z = 0 (identity frame).
//! * Each YAML surface becomes its own surface placed in the exact frame where dO evaluates it: the group
//!   frame moved to `z_i` (for a tilted plane, additionally rotated so that its local z is the plane normal).
//!   The step from the previous surface's frame is written as: the along-z part of the offset in the previous
//!   surface's thickness (it may be negative) plus, when needed, a Coordinate Break (order 0) holding the
//!   x/y decenter and the tilts [`decompose_xyz`] of the relative rotation. A tilted plane therefore is a
//!   break + a flat Standard surface, and the next break takes the ray back to the next frame.
//! * `ThinLens` → Paraxial (`focal_length_mm = f`), circular aperture `R`. `Aspheric` → Standard (plane or
//!   conic, radius 1/c) or, when `ai` has a non-zero term, Even Asphere with α₁ = 0, α₂.. = `ai`. Apertures
//!   are exact for untilted surfaces (circle or square of half-width `R`). On a tilted plane dO's aperture is
//!   the group-frame disc or square projected onto the plane (an ellipse / rectangle in the plane's own
//!   coordinates): a square tilted about a single axis is exact (a rectangle); otherwise the disc of radius
//!   `R` in the plane's coordinates is used — inscribed in dO's clear aperture, so a ray that passes here
//!   passes in dO too.
//! * The image surface is the detector plane.
//! * Stop: the paper's tracer has no stop; its chief ray leaves the object parallel to +z. When the first
//!   surface is a `ThinLens`, the import reproduces that with a dummy plane (flagged stop) at the thin
//!   lens's back focal point, which makes the object space telecentric (to 5·10⁻¹¹ rad, see
//!   the ThinLens's back focal point). Otherwise the first surface is the stop. System data: object-space NA 0.05, fields (0,0), (2.5,0), (0,2.5), (2.5,2.5) mm, the file's
//!   wavelengths, primary 520 nm, ray aiming off.
//! * Glass names are kept as written (catalogue look-up is case-insensitive and happens when the system is
//!   built); note that dO gives air the index 1.000293 while Zemax (and diffcassi) measure glass indices
//!   relative to air, index 1.
//!
//! Every error names the file, the YAML path of the field (`systems_surfaces[1][0].params.ai`) and the
//! offending value.
//!
//! ```no_run
//! let text = std::fs::read_to_string("../shared/reference/systems/system_single.yml").unwrap();
//! let spec = diffcassi::spec::yaml::import_yaml(&text, "system_single.yml").unwrap();
//! let sys = diffcassi::system::SequentialSystem::build(&spec).unwrap();
//! assert!(sys.pupil.distance_mm.abs() > 1e9); // object-space telecentric, as the paper's tracer
//! ```
use super::{Cell, RayAiming, SurfaceKind, SurfaceSpec, SystemAperture, SystemSpec};
use crate::error::{Error, Result};
use crate::geometry::{decompose_xyz, rot_x, rot_y, rot_z, rotation_xyz, Frame};
use crate::materials::WavelengthPolicy;
use crate::surfaces::Aperture;
use glam::{DMat3, DVec3};
use yaml_rust2::{Yaml, YamlLoader};

/// Import a paper YAML system (`text`, read from `source_name`) as a sequential [`SystemSpec`].
pub fn import_yaml(text: &str, source_name: &str) -> crate::Result<super::SystemSpec> {
    import_with_frames(text, source_name).map(|(spec, _)| spec)
}

/// The spec plus, for every non-break surface of it, the global frame dO evaluates it in.
pub(crate) fn import_with_frames(text: &str, source_name: &str) -> Result<(SystemSpec, Vec<(usize, Frame)>)> {
    let fail = |m: String| Error::spec(source_name, m);
    check_expansion(text).map_err(fail)?;
    let docs = YamlLoader::load_from_str(text).map_err(|e| {
        let m = e.marker();
        fail(format!("malformed YAML at line {}, column {}: {}", m.line(), m.col() + 1, e.info()))
    })?;
    let root = match docs.len() {
        0 => return Err(fail("empty YAML document: expected a mapping with `systems_surfaces`, `systems_materials`, …".into())),
        1 => Node { y: &docs[0], path: String::new() },
        n => return Err(fail(format!("{n} YAML documents: expected exactly one"))),
    };
    let model = parse(&root).map_err(fail)?;
    let name = std::path::Path::new(source_name)
        .file_stem()
        .and_then(|s| s.to_str())
        .filter(|s| !s.is_empty())
        .unwrap_or("imported")
        .to_string();
    let (spec, frames) = lower(&model, &name, source_name).map_err(fail)?;
    spec.validate().map_err(|m| fail(format!("imported system is invalid: {m}")))?;
    Ok((spec, frames))
}

type R<T> = std::result::Result<T, String>;

/// Most nodes (scalars, sequences, mappings) a YAML document may expand to once its aliases are resolved,
/// and deepest nesting. A paper system file has a few hundred nodes and depth < 10; these bounds stop an
/// alias bomb ("billion laughs": each anchor referring to the previous one several times) or a deeply
/// nested document *before* [`YamlLoader`] copies every alias into the tree.
pub const YAML_MAX_NODES: u64 = 1_000_000;
pub const YAML_MAX_DEPTH: usize = 256;

/// Count the nodes the document expands to (an alias counts as a copy of its anchor's node) from the
/// parser's event stream, without building anything; error past [`YAML_MAX_NODES`] / [`YAML_MAX_DEPTH`].
fn check_expansion(text: &str) -> R<()> {
    use yaml_rust2::parser::{Event, Parser};
    let mut parser = Parser::new_from_str(text);
    // Open collections: (anchor id, expanded nodes so far inside it, counting itself).
    let mut open: Vec<(usize, u64)> = Vec::new();
    let mut anchors: std::collections::HashMap<usize, u64> = std::collections::HashMap::new();
    let mut total: u64 = 0;
    loop {
        // A scan error is reported by the loader with its position; stop counting there.
        let Ok((event, mark)) = parser.next_token() else { return Ok(()) };
        let add = |n: u64, open: &mut Vec<(usize, u64)>, total: &mut u64| -> R<()> {
            *total = total.saturating_add(n);
            if let Some(top) = open.last_mut() {
                top.1 = top.1.saturating_add(n);
            }
            if *total > YAML_MAX_NODES {
                return Err(format!(
                    "YAML document expands to more than {YAML_MAX_NODES} nodes (at line {}: aliases `*name` repeating anchors `&name`); a system file needs far fewer",
                    mark.line()
                ));
            }
            Ok(())
        };
        match event {
            Event::StreamEnd => return Ok(()),
            Event::Scalar(_, _, anchor, _) => {
                add(1, &mut open, &mut total)?;
                if anchor > 0 {
                    anchors.insert(anchor, 1);
                }
            }
            Event::Alias(id) => {
                let n = anchors.get(&id).copied().unwrap_or(1);
                add(n, &mut open, &mut total)?;
            }
            Event::SequenceStart(anchor, _) | Event::MappingStart(anchor, _) => {
                total = total.saturating_add(1);
                open.push((anchor, 1));
                if open.len() > YAML_MAX_DEPTH {
                    return Err(format!("YAML nesting deeper than {YAML_MAX_DEPTH} levels at line {}", mark.line()));
                }
            }
            Event::SequenceEnd | Event::MappingEnd => {
                if let Some((anchor, n)) = open.pop() {
                    if anchor > 0 {
                        anchors.insert(anchor, n);
                    }
                    if let Some(top) = open.last_mut() {
                        top.1 = top.1.saturating_add(n);
                    }
                }
            }
            _ => {}
        }
    }
}

// ---------------------------------------------------------------------------------------------------
// YAML access with paths
// ---------------------------------------------------------------------------------------------------

/// A YAML node and its path from the document root (`systems_surfaces[1][0].params.ai`).
struct Node<'a> {
    y: &'a Yaml,
    path: String,
}

fn show(y: &Yaml) -> String {
    match y {
        Yaml::Real(s) => s.clone(),
        Yaml::Integer(i) => i.to_string(),
        Yaml::String(s) => format!("{s:?}"),
        Yaml::Boolean(b) => b.to_string(),
        Yaml::Array(a) => format!("[…] ({} items)", a.len()),
        Yaml::Hash(h) => format!("{{…}} ({} keys)", h.len()),
        Yaml::Null => "null".into(),
        Yaml::Alias(_) => "*alias".into(),
        Yaml::BadValue => "<invalid>".into(),
    }
}

fn kind_of(y: &Yaml) -> &'static str {
    match y {
        Yaml::Real(_) | Yaml::Integer(_) => "a number",
        Yaml::String(_) => "a string",
        Yaml::Boolean(_) => "a boolean",
        Yaml::Array(_) => "a list",
        Yaml::Hash(_) => "a mapping",
        Yaml::Null => "null",
        Yaml::Alias(_) => "an alias",
        Yaml::BadValue => "an invalid value",
    }
}

impl<'a> Node<'a> {
    fn path_or_root(&self) -> &str {
        if self.path.is_empty() {
            "<document root>"
        } else {
            &self.path
        }
    }
    fn wrong(&self, expected: &str) -> String {
        format!("{} = {}: expected {expected}, found {}", self.path_or_root(), show(self.y), kind_of(self.y))
    }
    fn key_path(&self, key: &str) -> String {
        if self.path.is_empty() {
            key.to_string()
        } else {
            format!("{}.{key}", self.path)
        }
    }
    fn is_null(&self) -> bool {
        matches!(self.y, Yaml::Null)
    }
    /// The value under `key` (possibly null), if the key is present. `self` must be a mapping.
    fn child(&self, key: &str) -> R<Option<Node<'a>>> {
        let Yaml::Hash(h) = self.y else { return Err(self.wrong("a mapping")) };
        Ok(h.get(&Yaml::String(key.to_string())).map(|y| Node { y, path: self.key_path(key) }))
    }
    /// The value under `key`; a missing key is an error that says what the key is for.
    fn req(&self, key: &str, what: &str) -> R<Node<'a>> {
        self.child(key)?.ok_or_else(|| format!("{}: missing key `{key}` ({what})", self.path_or_root()))
    }
    /// The value under `key`, `None` when missing or null.
    fn opt(&self, key: &str) -> R<Option<Node<'a>>> {
        Ok(self.child(key)?.filter(|n| !n.is_null()))
    }
    /// Rejects keys outside `allowed` (a typo would otherwise silently fall back to a default).
    fn only_keys(&self, allowed: &[&str]) -> R<()> {
        let Yaml::Hash(h) = self.y else { return Err(self.wrong("a mapping")) };
        for k in h.keys() {
            match k {
                Yaml::String(s) if allowed.contains(&s.as_str()) => {}
                Yaml::String(s) => {
                    return Err(format!("{}: unknown key `{s}` (known keys: {})", self.path_or_root(), allowed.join(", ")))
                }
                other => return Err(format!("{}: key {} is not a string", self.path_or_root(), show(other))),
            }
        }
        Ok(())
    }
    /// A finite number (YAML integer or float).
    fn num(&self) -> R<f64> {
        let v = match self.y {
            Yaml::Integer(i) => *i as f64,
            Yaml::Real(s) => self.y.as_f64().ok_or_else(|| format!("{} = {s}: not a number", self.path))?,
            _ => return Err(self.wrong("a number")),
        };
        if !v.is_finite() {
            return Err(format!("{} = {}: not a finite number", self.path, show(self.y)));
        }
        Ok(v)
    }
    fn positive(&self) -> R<f64> {
        let v = self.num()?;
        if v <= 0.0 {
            return Err(format!("{} = {}: must be > 0", self.path, show(self.y)));
        }
        Ok(v)
    }
    fn int(&self) -> R<i64> {
        match self.y {
            Yaml::Integer(i) => Ok(*i),
            Yaml::Real(_) => {
                let v = self.num()?;
                if v.fract() == 0.0 && v.abs() < 1e15 {
                    Ok(v as i64)
                } else {
                    Err(format!("{} = {}: expected an integer", self.path, show(self.y)))
                }
            }
            _ => Err(self.wrong("an integer")),
        }
    }
    fn boolean(&self) -> R<bool> {
        match self.y {
            Yaml::Boolean(b) => Ok(*b),
            _ => Err(self.wrong("a boolean (true/false)")),
        }
    }
    fn string(&self) -> R<&'a str> {
        match self.y {
            Yaml::String(s) => Ok(s.as_str()),
            _ => Err(self.wrong("a string")),
        }
    }
    fn list(&self) -> R<Vec<Node<'a>>> {
        match self.y {
            Yaml::Array(a) => Ok(a.iter().enumerate().map(|(i, y)| Node { y, path: format!("{}[{i}]", self.path) }).collect()),
            _ => Err(self.wrong("a list")),
        }
    }
    /// A list of exactly `n` numbers.
    fn vec_n(&self, n: usize) -> R<Vec<f64>> {
        let items = self.list()?;
        if items.len() != n {
            return Err(format!("{} = {}: expected {n} numbers, found {}", self.path, show(self.y), items.len()));
        }
        items.iter().map(Node::num).collect()
    }
}

// ---------------------------------------------------------------------------------------------------
// Parsed model
// ---------------------------------------------------------------------------------------------------

const TOP_KEYS: &[&str] = &[
    "systems_surfaces",
    "systems_materials",
    "list_d_sensor",
    "list_r_last",
    "list_film_size",
    "list_pixel_size",
    "list_theta_x",
    "list_theta_y",
    "list_theta_z",
    "list_origin",
    "list_shift",
    "list_rotation_order",
    "wavelengths",
    "device",
    "save_dir",
];

enum Shape {
    /// dO `ThinLens`.
    Thin { f: f64 },
    /// dO `XYPolynomial` that is a plane: z = z_i + a0 + ay·y + ax·x.
    Plane { a0: f64, ay: f64, ax: f64 },
    /// dO `Aspheric`.
    Asphere { c: f64, k: f64, ai: Vec<f64> },
}

struct Surf {
    path: String,
    type_name: &'static str,
    shape: Shape,
    r: f64,
    d: f64,
    square: bool,
}

struct Group {
    surfaces: Vec<Surf>,
    /// Media before/between/after the surfaces: `None` = air.
    media: Vec<Option<String>>,
    d_sensor: f64,
    frame: Frame,
    r_last: Option<f64>,
}

struct Model {
    groups: Vec<Group>,
    wavelengths: Vec<f64>,
}

fn medium(node: &Node) -> R<Option<String>> {
    if node.is_null() {
        return Ok(None); // dO: Material(None) is vacuum
    }
    let name = node.string()?.trim();
    if name.is_empty() {
        return Err(format!("{} = {}: empty material name", node.path, show(node.y)));
    }
    if name.eq_ignore_ascii_case("air") || name.eq_ignore_ascii_case("vacuum") {
        Ok(None)
    } else {
        Ok(Some(name.to_string()))
    }
}

fn same_medium(a: &Option<String>, b: &Option<String>) -> bool {
    match (a, b) {
        (None, None) => true,
        (Some(x), Some(y)) => x.eq_ignore_ascii_case(y),
        _ => false,
    }
}

fn medium_label(m: &Option<String>) -> &str {
    m.as_deref().unwrap_or("air")
}

/// A per-group list (`list_theta_x`, …): `None` when absent or null, else exactly `n` entries.
fn per_group<'a>(root: &Node<'a>, key: &str, n: usize) -> R<Option<Vec<Node<'a>>>> {
    let Some(node) = root.opt(key)? else { return Ok(None) };
    let items = node.list()?;
    if items.len() != n {
        return Err(format!(
            "{key} has {} entries but systems_surfaces has {n} groups: every list_* array needs one entry per group",
            items.len()
        ));
    }
    Ok(Some(items))
}

fn parse_surface(node: &Node) -> R<Surf> {
    node.only_keys(&["type", "R", "d", "params", "is_square"])?;
    let type_node = node.req("type", "the surface type: ThinLens, XYPolynomial or Aspheric")?;
    let type_text = type_node.string()?;
    let r = node.req("R", "the clear-aperture radius, mm")?.positive()?;
    let d = node.req("d", "the distance from the previous surface of the group, mm")?.num()?;
    if let Some(sq) = node.opt("is_square")? {
        sq.boolean()?; // present in the reference files; not read by the paper's tracer
    }
    let params = node.req("params", "the surface parameters")?;
    let square_of = |allowed: &[&str]| -> R<bool> {
        params.only_keys(allowed)?;
        params.opt("is_square")?.map(|n| n.boolean()).transpose().map(|b| b.unwrap_or(false))
    };
    let (type_name, shape, square) = match type_text {
        "ThinLens" => {
            // dO's ThinLens clips on the disc of radius R whatever `is_square` says.
            square_of(&["f", "is_square"])?;
            let fnode = params.req("f", "the focal length of the ThinLens, mm")?;
            let f = fnode.num()?;
            if f == 0.0 {
                return Err(format!("{} = {}: a ThinLens needs a non-zero focal length", fnode.path, show(fnode.y)));
            }
            ("ThinLens", Shape::Thin { f }, false)
        }
        "XYPolynomial" => {
            let square = square_of(&["J", "ai", "b", "is_square"])?;
            let j = match params.opt("J")? {
                None => 0,
                Some(n) => {
                    let j = n.int()?;
                    if !(0..=20).contains(&j) {
                        return Err(format!("{} = {}: polynomial order must be in 0..=20", n.path, show(n.y)));
                    }
                    j as usize
                }
            };
            let size = (j + 1) * (j + 2) / 2;
            let ai = match params.opt("ai")? {
                None => vec![0.0; size],
                Some(n) => {
                    let items = n.list()?;
                    if items.len() != size {
                        return Err(format!(
                            "{} = {}: J = {j} needs (J+1)(J+2)/2 = {size} coefficients, found {}",
                            n.path,
                            show(n.y),
                            items.len()
                        ));
                    }
                    items.iter().map(Node::num).collect::<R<Vec<f64>>>()?
                }
            };
            if let Some(bn) = params.opt("b")? {
                let b = bn.num()?;
                if b != 0.0 {
                    return Err(format!(
                        "{} = {}: only planar XYPolynomial surfaces (b = 0, terms of degree ≤ 1) can be imported",
                        bn.path,
                        show(bn.y)
                    ));
                }
            }
            if let Some(k) = ai.iter().skip(3).position(|v| *v != 0.0) {
                return Err(format!(
                    "{}.ai[{}] = {}: only planar XYPolynomial surfaces (terms of degree ≤ 1) can be imported",
                    params.path,
                    k + 3,
                    ai[k + 3]
                ));
            }
            let a = |i: usize| ai.get(i).copied().unwrap_or(0.0);
            ("XYPolynomial", Shape::Plane { a0: a(0), ay: a(1), ax: a(2) }, square)
        }
        "Aspheric" => {
            let square = square_of(&["c", "k", "ai", "is_square"])?;
            let c = params.opt("c")?.map(|n| n.num()).transpose()?.unwrap_or(0.0);
            let k = params.opt("k")?.map(|n| n.num()).transpose()?.unwrap_or(0.0);
            let ai = match params.opt("ai")? {
                None => Vec::new(),
                Some(n) => {
                    let items = n.list()?;
                    if items.len() > 7 {
                        return Err(format!(
                            "{} = {}: at most 7 terms (r⁴ … r¹⁶) fit an Even Asphere, found {}",
                            n.path,
                            show(n.y),
                            items.len()
                        ));
                    }
                    items.iter().map(Node::num).collect::<R<Vec<f64>>>()?
                }
            };
            ("Aspheric", Shape::Asphere { c, k, ai }, square)
        }
        other => {
            return Err(format!(
                "{} = {other:?}: unknown or unsupported surface type (supported: ThinLens, XYPolynomial, Aspheric)",
                type_node.path
            ))
        }
    };
    Ok(Surf { path: node.path.clone(), type_name, shape, r, d, square })
}

fn parse(root: &Node) -> R<Model> {
    if !matches!(root.y, Yaml::Hash(_)) {
        return Err(root.wrong("a mapping with `systems_surfaces`, `systems_materials`, `list_d_sensor`, `wavelengths`, …"));
    }
    root.only_keys(TOP_KEYS)?;
    let groups_node = root.req("systems_surfaces", "the surfaces of each element group")?;
    let group_nodes = groups_node.list()?;
    let n = group_nodes.len();
    if n == 0 {
        return Err("systems_surfaces = []: no element group".into());
    }
    let materials_node = root.req("systems_materials", "the media around the surfaces of each group")?;
    let material_groups = materials_node.list()?;
    if material_groups.len() != n {
        return Err(format!(
            "systems_materials has {} entries but systems_surfaces has {n} groups",
            material_groups.len()
        ));
    }
    let d_sensor = per_group(root, "list_d_sensor", n)?
        .ok_or_else(|| "missing key `list_d_sensor` (the detector distance of each group, mm)".to_string())?;
    let theta: Vec<Option<Vec<Node>>> =
        ["list_theta_x", "list_theta_y", "list_theta_z"].iter().map(|k| per_group(root, k, n)).collect::<R<_>>()?;
    let origins = per_group(root, "list_origin", n)?;
    let shifts = per_group(root, "list_shift", n)?;
    let orders = per_group(root, "list_rotation_order", n)?;
    let r_last = per_group(root, "list_r_last", n)?;
    if let Some(items) = per_group(root, "list_film_size", n)? {
        for it in &items {
            if !it.is_null() {
                it.vec_n(2)?;
            }
        }
    }
    if let Some(items) = per_group(root, "list_pixel_size", n)? {
        for it in &items {
            if !it.is_null() {
                it.num()?;
            }
        }
    }
    for key in ["device", "save_dir"] {
        if let Some(node) = root.opt(key)? {
            node.string()?;
        }
    }

    let mut groups = Vec::with_capacity(n);
    for (g, gnode) in group_nodes.iter().enumerate() {
        let surfaces = gnode.list()?.iter().map(parse_surface).collect::<R<Vec<Surf>>>()?;
        let mats = material_groups[g].list()?;
        if mats.len() != surfaces.len() + 1 {
            return Err(format!(
                "{} has {} entries but systems_surfaces[{g}] has {} surfaces: a group lists the medium before, between and after its surfaces ({} entries)",
                material_groups[g].path,
                mats.len(),
                surfaces.len(),
                surfaces.len() + 1
            ));
        }
        let media = mats.iter().map(medium).collect::<R<Vec<_>>>()?;
        // Rotation: product of single-axis rotations in the listed order (dO `_compute_transformation`).
        let mut angles = [0.0f64; 3];
        for (a, list) in theta.iter().enumerate() {
            if let Some(items) = list {
                angles[a] = items[g].num()?;
            }
        }
        let order: String = match &orders {
            Some(items) if !items[g].is_null() => {
                let s = items[g].string()?;
                let mut sorted: Vec<char> = s.chars().collect();
                sorted.sort_unstable();
                if sorted != ['x', 'y', 'z'] {
                    return Err(format!(
                        "{} = {}: a rotation order lists x, y and z once each (e.g. \"xyz\", \"yxz\")",
                        items[g].path,
                        show(items[g].y)
                    ));
                }
                s.to_string()
            }
            _ => "xyz".to_string(),
        };
        let mut rotation = DMat3::IDENTITY;
        for ch in order.chars() {
            rotation *= match ch {
                'x' => rot_x(angles[0].to_radians()),
                'y' => rot_y(angles[1].to_radians()),
                _ => rot_z(angles[2].to_radians()),
            };
        }
        let vec3 = |list: &Option<Vec<Node>>| -> R<DVec3> {
            match list {
                Some(items) if !items[g].is_null() => {
                    let v = items[g].vec_n(3)?;
                    Ok(DVec3::new(v[0], v[1], v[2]))
                }
                _ => Ok(DVec3::ZERO),
            }
        };
        let origin = vec3(&origins)? + rotation * vec3(&shifts)?;
        let r_last = match &r_last {
            Some(items) if !items[g].is_null() => Some(items[g].positive()?),
            _ => None,
        };
        groups.push(Group { surfaces, media, d_sensor: d_sensor[g].num()?, frame: Frame::new(origin, rotation), r_last });
    }
    // The medium between two groups must be the same seen from both sides.
    for g in 0..n - 1 {
        let (a, b) = (groups[g].media.last().unwrap(), &groups[g + 1].media[0]);
        if !same_medium(a, b) {
            return Err(format!(
                "systems_materials[{g}][{}] = {:?} but systems_materials[{}][0] = {:?}: the medium between two groups must agree",
                groups[g].media.len() - 1,
                medium_label(a),
                g + 1,
                medium_label(b)
            ));
        }
    }
    let wl_node = root.req("wavelengths", "the system wavelengths, nm")?;
    let wavelengths = wl_node.list()?.iter().map(Node::positive).collect::<R<Vec<f64>>>()?;
    if wavelengths.is_empty() {
        return Err("wavelengths = []: at least one wavelength is needed".into());
    }
    Ok(Model { groups, wavelengths })
}

// ---------------------------------------------------------------------------------------------------
// Lowering into the sequential model
// ---------------------------------------------------------------------------------------------------

/// Relative transforms below these are rounding noise: no Coordinate Break is written for them.
/// dO's `Material('air')`: n = 1.000293 without dispersion, used with catalogue (air-relative) glass data.
/// The paper calibrated its files under this convention; set [`SystemSpec::air_index`] to 1 for Zemax's.
pub const PAPER_AIR_INDEX: f64 = 1.000293;

const DECENTER_EPS_MM: f64 = 1e-12;
const TILT_EPS_RAD: f64 = 1e-13;



/// Builds the surface list while tracking the frame of the last non-break surface.
struct Sequence {
    surfaces: Vec<SurfaceSpec>,
    frames: Vec<(usize, Frame)>,
    last: usize,
    frame: Frame,
}

impl Sequence {
    /// Move from the last surface's frame to `target`: along-z offset into its thickness, the rest into a
    /// Coordinate Break (order 0: decenter x/y, then tilt about x, y, z).
    fn go_to(&mut self, target: &Frame, comment: &str) {
        let (t, r) = self.frame.relative(target);
        self.surfaces[self.last].thickness_mm = Cell::fixed(t.z);
        let (a, b, c) = decompose_xyz(r);
        let snap = |v: f64, eps: f64| if v.abs() < eps { 0.0 } else { v };
        let (dx, dy) = (snap(t.x, DECENTER_EPS_MM), snap(t.y, DECENTER_EPS_MM));
        let (a, b, c) = (snap(a, TILT_EPS_RAD), snap(b, TILT_EPS_RAD), snap(c, TILT_EPS_RAD));
        if dx != 0.0 || dy != 0.0 || a != 0.0 || b != 0.0 || c != 0.0 {
            let mut cb = SurfaceSpec::coordinate_break(dx, dy, a.to_degrees(), b.to_degrees(), c.to_degrees(), 0.0);
            cb.comment = comment.to_string();
            self.surfaces.push(cb);
        }
    }
    fn push(&mut self, s: SurfaceSpec, frame: Frame) {
        self.surfaces.push(s);
        self.last = self.surfaces.len() - 1;
        self.frame = frame;
        self.frames.push((self.last, frame));
    }
}

fn lower(model: &Model, name: &str, source_name: &str) -> R<(SystemSpec, Vec<(usize, Frame)>)> {
    let mut object = SurfaceSpec::standard(None, 0.0, model.groups[0].media[0].as_deref());
    object.comment = "object plane: global z = 0".into();
    let mut seq = Sequence { surfaces: Vec::new(), frames: Vec::new(), last: 0, frame: Frame::IDENTITY };
    seq.push(object, Frame::IDENTITY);

    let mut stop_placed = false;
    for (g, group) in model.groups.iter().enumerate() {
        let mut z = 0.0;
        for (i, s) in group.surfaces.iter().enumerate() {
            z += s.d;
            let (before, after) = (&group.media[i], &group.media[i + 1]);
            let at_z = group.frame.point_to_global(DVec3::new(0.0, 0.0, z));
            let (frame, mut spec) = match &s.shape {
                Shape::Thin { f } => {
                    if !same_medium(before, after) {
                        return Err(format!(
                            "{}: a ThinLens between different media ({} → {}) is not supported (dO ignores the media of a ThinLens)",
                            s.path,
                            medium_label(before),
                            medium_label(after)
                        ));
                    }
                    let mut p = SurfaceSpec::paraxial(*f, 0.0);
                    p.material = after.clone();
                    p.aperture = Some(Aperture::circular(s.r));
                    (Frame::new(at_z, group.frame.rotation), p)
                }
                Shape::Plane { a0, ay, ax } => {
                    // Local z along the plane normal (−ax, −ay, 1): R = Rx(atan ay)·Ry(atan2(−ax, √(1+ay²))).
                    let (ta, tb) = (ay.atan(), (-ax).atan2((1.0 + ay * ay).sqrt()));
                    let origin = group.frame.point_to_global(DVec3::new(0.0, 0.0, z + a0));
                    let frame = Frame::new(origin, group.frame.rotation * rotation_xyz(ta, tb, 0.0));
                    let mut p = SurfaceSpec::standard(None, 0.0, after.as_deref());
                    p.aperture = Some(if *ax == 0.0 && *ay == 0.0 {
                        if s.square {
                            Aperture::Rectangular { half_width_x_mm: s.r, half_width_y_mm: s.r, decenter_x_mm: 0.0, decenter_y_mm: 0.0 }
                        } else {
                            Aperture::circular(s.r)
                        }
                    } else if s.square && (*ax == 0.0 || *ay == 0.0) {
                        // Group-frame square seen in the plane's own coordinates: x = u cos b, y = v cos a.
                        Aperture::Rectangular {
                            half_width_x_mm: s.r / tb.cos(),
                            half_width_y_mm: s.r / ta.cos(),
                            decenter_x_mm: 0.0,
                            decenter_y_mm: 0.0,
                        }
                    } else {
                        // The disc of radius R in the plane projects inside dO's clear aperture.
                        Aperture::circular(s.r)
                    });
                    (frame, p)
                }
                Shape::Asphere { c, k, ai } => {
                    let radius = if *c == 0.0 { None } else { Some(1.0 / c) };
                    let mut p = SurfaceSpec::standard(radius, 0.0, after.as_deref());
                    if *k != 0.0 {
                        p.conic = Some(Cell::fixed(*k));
                    }
                    if ai.iter().any(|v| *v != 0.0) {
                        p.kind = SurfaceKind::EvenAsphere;
                        p.asphere_coefficients = std::iter::once(0.0).chain(ai.iter().copied()).map(Cell::fixed).collect();
                    }
                    p.aperture = Some(if s.square {
                        Aperture::Rectangular { half_width_x_mm: s.r, half_width_y_mm: s.r, decenter_x_mm: 0.0, decenter_y_mm: 0.0 }
                    } else {
                        Aperture::circular(s.r)
                    });
                    (Frame::new(at_z, group.frame.rotation), p)
                }
            };
            spec.semi_diameter_mm = Some(s.r);
            spec.comment = format!("{} {}", s.path, s.type_name);
            seq.go_to(&frame, &format!("to {} frame", s.path));
            let is_first = !stop_placed;
            seq.push(spec, frame);
            if is_first {
                stop_placed = true;
                match s.shape {
                    Shape::Thin { f } => {
                        // The paper's chief ray leaves the object along +z: a stop at the back focal point.
                        let mut stop = SurfaceSpec::standard(None, 0.0, after.as_deref());
                        stop.stop = true;
                        stop.comment = format!("stop: back focal plane of {} (telecentric object space, as the paper's tracer)", s.path);
                        let s_stop = f; // exactly telecentric: the entrance pupil is at infinity
                        seq.surfaces[seq.last].thickness_mm = Cell::fixed(s_stop);
                        let focal = frame.advanced(s_stop);
                        seq.push(stop, focal);
                    }
                    _ => seq.surfaces[seq.last].stop = true,
                }
            }
        }
        if g + 1 == model.groups.len() {
            let sensor = Frame::new(group.frame.point_to_global(DVec3::new(0.0, 0.0, group.d_sensor)), group.frame.rotation);
            let mut image = SurfaceSpec::standard(None, 0.0, None);
            image.comment = format!("detector: list_d_sensor[{g}] = {} mm in group {g}'s frame", group.d_sensor);
            image.semi_diameter_mm = group.r_last;
            seq.go_to(&sensor, &format!("to the detector frame (group {g})"));
            seq.push(image, sensor);
        }
    }
    if !stop_placed {
        return Err("systems_surfaces: every group is empty; at least one surface is needed".into());
    }
    let spec = SystemSpec {
        name: name.to_string(),
        description: format!(
            "imported from {source_name} (paper YAML, {} groups): object-space telecentric chief rays and air n = {PAPER_AIR_INDEX} \
             (catalogue glass indices unchanged), as the paper's tracer",
            model.groups.len()
        ),
        aperture: SystemAperture::ObjectSpaceNa(0.05),
        ray_aiming: RayAiming::Off,
        wavelengths_nm: model.wavelengths.clone(),
        primary_wavelength_nm: 520.0,
        fields_mm: vec![[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]],
        field_type: Default::default(),
        fields_deg: Vec::new(),
        vignetting_factors: Vec::new(),
        wavelength_policy: WavelengthPolicy::default(),
        air_index: PAPER_AIR_INDEX,
        glass_catalogs: Vec::new(),
        surfaces: seq.surfaces,
        mechanics: None,
    };
    Ok((spec, seq.frames))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::system::SequentialSystem;

    const MINI: &str = "
systems_surfaces:
- - {R: 5.0, d: 20.0, type: ThinLens, params: {f: 20.0}}
- - {R: 6.0, d: 0.0, type: XYPolynomial, params: {J: 1, ai: [0, 0.1, 0.3]}}
  - {R: 6.0, d: 5.0, type: Aspheric, params: {c: 0.02, k: -0.5, ai: [1.0e-5]}}
systems_materials:
- [air, air]
- [air, N-BK7, air]
list_d_sensor: [40.0, 30.0]
list_theta_x: [0.0, 3.0]
list_theta_y: [0.0, -10.0]
list_theta_z: [0.0, 2.0]
list_origin: [null, [0.0, 0.0, 40.0]]
list_shift: [null, [0.1, -0.2, 0.3]]
list_rotation_order: [xyz, zyx]
wavelengths: [520.0]
";

    /// The built system places every surface exactly in the frame dO evaluates it in.
    #[test]
    fn frames_match_the_do_model() {
        let (spec, frames) = import_with_frames(MINI, "mini.yml").unwrap();
        let sys = SequentialSystem::build(&spec).unwrap();
        for (i, f) in frames {
            let got = sys.surfaces[i].frame;
            assert!((got.origin - f.origin).length() < 1e-12, "surface {i}: {:?} vs {:?}", got.origin, f.origin);
            let dr = (got.rotation - f.rotation).to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(dr < 1e-14, "surface {i}: rotation off by {dr}");
        }
        assert!(sys.pupil.distance_mm.abs() > 1e9, "{:?}", sys.pupil);
        assert_eq!(spec.surfaces.iter().filter(|s| s.kind == SurfaceKind::EvenAsphere).count(), 1);
    }

    /// Plane tilt convention: ai = [0, 0, t] is z = d + t·x, so the local z axis leans toward −x for t > 0.
    #[test]
    fn plane_normal() {
        let (_, frames) = import_with_frames(MINI, "mini.yml").unwrap();
        // frames: object, thin lens, stop, plane, asphere, image
        let plane = frames[3].1;
        let g = rotation_xyz(0.0, 0.0, 0.0) * rot_z(2f64.to_radians()) * rot_y((-10f64).to_radians()) * rot_x(3f64.to_radians());
        let n_local = g.transpose() * plane.rotation.z_axis;
        let expect = DVec3::new(-0.3, -0.1, 1.0).normalize();
        assert!((n_local - expect).length() < 1e-14, "{n_local:?}");
    }

    /// "Billion laughs": 9 levels of 9 aliases each expand to 9⁹ ≈ 3.9·10⁸ nodes; refused from the event
    /// stream in milliseconds instead of exhausting memory in the loader.
    #[test]
    fn alias_bomb_is_refused_before_expansion() {
        let mut text = String::from("a0: &a0 [x, x, x, x, x, x, x, x, x]\n");
        for k in 1..10 {
            let p = k - 1;
            text += &format!("a{k}: &a{k} [*a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}]\n");
        }
        let t = std::time::Instant::now();
        let e = import_yaml(&text, "bomb.yml").unwrap_err().to_string();
        assert!(e.contains("bomb.yml") && e.contains("expands to more than") && e.contains("anchors"), "{e}");
        assert!(t.elapsed().as_secs_f64() < 5.0);
        // A few aliases are fine (and reach the importer's own checks).
        let e = import_yaml("a: &x [1, 2]\nb: *x\n", "small.yml").unwrap_err().to_string();
        assert!(!e.contains("expands"), "{e}");
    }

    #[test]
    fn deep_nesting_is_refused() {
        let text = format!("{}{}", "[".repeat(5000), "]".repeat(5000));
        let e = import_yaml(&text, "deep.yml").unwrap_err().to_string();
        assert!(e.contains("deep.yml") && (e.contains("deeper than") || e.contains("recursion")), "{e}");
    }
}
