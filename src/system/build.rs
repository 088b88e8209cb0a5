//! spec → [`SequentialSystem`]: media, pickups, paraxial pupil, frames and chief-ray solves.
use super::paraxial::{entrance_pupil, first_order, ParaxialSurface};
use super::{Interaction, PathStep, ResolvedSurface, SequentialSystem, StopProbe};
use crate::surfaces::grating::Grating;
use crate::error::{Error, Result};
use crate::geometry::{coordinate_break_frame, BreakOrder, Frame};
use crate::materials::{GlassCatalog, Medium};
use crate::spec::{Driver, SurfaceKind, SystemSpec};
use crate::surfaces::{Aperture, SurfaceShape};
use glam::DVec3;
use std::collections::HashMap;

/// For a glass the spec's catalogues lack: the built-in catalogues that hold it and how to name them
/// (`; it is in the built-in catalogue OHARA: add "builtin:OHARA" to glass_catalogs …`), or nothing.
fn builtin_hint(name: &str) -> String {
    let holding = crate::materials::builtin_catalogs::holding(name);
    if holding.is_empty() {
        return String::new();
    }
    let entries: Vec<String> = holding.iter().map(|c| format!("\"builtin:{c}\"")).collect();
    format!(
        "; it is in the built-in catalogue{} {}: add {} to the spec's glass_catalogs (or --glass-catalog builtin:{})",
        if holding.len() > 1 { "s" } else { "" },
        holding.join(", "),
        entries.join(" or "),
        holding[0]
    )
}

const CB_COLUMNS: [&str; 5] = ["decenter_x_mm", "decenter_y_mm", "tilt_x_deg", "tilt_y_deg", "tilt_z_deg"];

impl SequentialSystem {
    /// Build with the built-in glass table plus the spec's `glass_catalogs`, merged in order (a later
    /// catalogue's glass wins): the one place a spec's catalogues are assembled (the CLI's `--glass-catalog`
    /// and a render record go through the spec). A relative file path is read against the working directory;
    /// [`crate::spec::load_spec_file`] makes a spec file's relative entries absolute first.
    pub fn build(spec: &SystemSpec) -> Result<Self> {
        Self::build_with_catalog(spec, &Self::catalog_of(spec)?)
    }

    /// [`Self::build`] for a spec read from a file of `origin` ([`SystemOrigin::of_path`]): the build's errors
    /// and the system's later ones (a run-time wavelength outside a glass's range) name that file's fixes —
    /// a `.zmx` file's `DCWP allow_extrapolation` record, not a spec's `wavelength_policy`.
    pub fn build_from(spec: &SystemSpec, origin: super::SystemOrigin) -> Result<Self> {
        let mut system = Self::build(spec).map_err(|e| origin.hints(e))?;
        system.origin = origin;
        Ok(system)
    }

    /// The glass catalogue [`Self::build`] uses for `spec`: the built-in table plus the spec's `glass_catalogs`,
    /// merged in order (also what `calibrate` fits glasses against: it took the built-in table alone, and a
    /// spec whose glasses come from its own catalogues was refused).
    pub fn catalog_of(spec: &SystemSpec) -> Result<GlassCatalog> {
        let mut catalog = GlassCatalog::builtin();
        for path in &spec.glass_catalogs {
            catalog.merge(GlassCatalog::from_entry(path)?);
        }
        Ok(catalog)
    }

    /// The content identities of `spec`'s catalogue files, `(entry, identity)` in the spec's order
    /// ([`GlassCatalog::entry_identity`]; built-in catalogues have none). Take them *before* building
    /// from the files: a file edited in between then reads as changed (a copy refused), never the other way
    /// (a copy silently tracing other glasses). A file that cannot be read is left out: [`Self::build`]
    /// names it.
    pub fn catalog_identities(spec: &SystemSpec) -> Vec<(String, String)> {
        spec.glass_catalogs.iter().filter_map(|e| Some((e.clone(), GlassCatalog::entry_identity(e)?.ok()?))).collect()
    }

    /// Check catalogue files against the identities recorded when a system was built
    /// ([`Self::catalog_identities`]) before a copy of it is rebuilt from its spec, which reads the files
    /// again (Python's pickle, `copy.deepcopy`, a spawned worker): a file whose content changed since is an
    /// error naming it — the copy would trace other refractive indices than the original, with the same
    /// prescription. A file that is gone is left to the rebuild, which names it.
    pub fn check_catalog_identities(recorded: &[(String, String)]) -> Result<()> {
        for (entry, then) in recorded {
            if let Some(Ok(now)) = GlassCatalog::entry_identity(entry) {
                if &now != then {
                    return Err(Error::invalid(format!(
                        "glass catalogue {entry}: its content changed since the system was built (then {then}, now {now}): a copy rebuilt from it \
                         would trace other refractive indices than the original; restore the file, or build the system again from its spec file to use the catalogue as it is now"
                    )));
                }
            }
        }
        Ok(())
    }

    /// Build against an explicit glass catalogue.
    pub fn build_with_catalog(spec: &SystemSpec, catalog: &GlassCatalog) -> Result<Self> {
        spec.validate().map_err(|m| Error::spec(&spec.name, m))?;
        let n = spec.surfaces.len();
        let sys_err = |surface: usize, field: &str, message: String| Error::System {
            system: spec.name.clone(),
            surface,
            field: field.to_string(),
            message,
        };

        // Media: a Coordinate Break keeps the medium before it; blank = air.
        let mut media: Vec<Medium> = Vec::with_capacity(n);
        for (i, s) in spec.surfaces.iter().enumerate() {
            let m = match (&s.material, s.kind) {
                (_, SurfaceKind::CoordinateBreak) => media[i - 1].clone(),
                // A mirror keeps the medium before it (OpticStudio: the index after a mirror is the index before it).
                (Some(name), _) if crate::spec::is_mirror_material(name) => media[i - 1].clone(),
                (None, _) => Medium::Air,
                (Some(name), _) if name.eq_ignore_ascii_case("air") => Medium::Air,
                (Some(name), _) => Medium::Glass(catalog.get(name).map_err(|e| sys_err(i, "material", format!("{e}{}", builtin_hint(name))))?),
            };
            media.push(m);
        }
        // Every system wavelength must be valid in every glass (unless extrapolation is allowed).
        let mut wavelengths = spec.wavelengths_nm.clone();
        wavelengths.push(spec.primary_wavelength_nm);
        for (i, m) in media.iter().enumerate() {
            for &w in &wavelengths {
                m.refractive_index(w, spec.wavelength_policy).map_err(|e| sys_err(i, "material", e.to_string()))?;
            }
        }

        // Pass 1: every cell except chief-ray solves (and pickups that depend on them).
        let mut values: Vec<HashMap<String, Option<f64>>> = vec![HashMap::new(); n];
        for i in 0..n {
            for col in spec.surfaces[i].present_columns() {
                let v = resolve_cell(spec, i, &col, 0).map_err(|m| sys_err(i, &col, m))?;
                if let Some(v) = v.filter(|v| !(i == 0 && col == "thickness_mm" && *v == f64::INFINITY)) {
                    crate::limits::check_resolved_cell(&col, v).map_err(|m| sys_err(i, &col, resolved_message(spec, i, &col, m)))?;
                }
                values[i].insert(col, v);
            }
        }
        let value = |values: &Vec<HashMap<String, Option<f64>>>, i: usize, col: &str| -> Option<f64> {
            values[i].get(col).copied().flatten()
        };

        // Paraxial entrance pupil at the primary wavelength (needs no frames).
        let primary = spec.primary_wavelength_nm;
        let mut n_primary = Vec::with_capacity(n);
        for m in &media {
            n_primary.push(super::medium_index(m, spec, primary)?);
        }
        // The paraxial trace uses OpticStudio's signed indices: each mirror flips the sign of the index after
        // it (n′ = −n), so that a mirror's power is c(n′ − n) = −2nc and a negative thickness after it
        // advances the ray (t/n′ > 0).
        let mut n_paraxial = Vec::with_capacity(n);
        let mut sign = 1.0;
        for (i, s) in spec.surfaces.iter().enumerate() {
            if s.is_mirror() {
                sign = -sign;
            }
            n_paraxial.push(sign * n_primary[i]);
        }
        // The tables the kernel reads: a grating reads the wavelength after the per-surface indices.
        let has_grating = spec.surfaces.iter().any(|s| s.kind == SurfaceKind::DiffractionGrating);
        if has_grating {
            n_primary.push(primary);
        }
        let stop_index = spec.stop_index();
        let at_infinity = spec.object_at_infinity();
        let mut parax = Vec::with_capacity(n);
        for (i, s) in spec.surfaces.iter().enumerate() {
            let r = value(&values, i, "radius_mm");
            let alpha1 = if matches!(s.kind, SurfaceKind::EvenAsphere | SurfaceKind::Toroidal) { value(&values, i, "asphere_1").unwrap_or(0.0) } else { 0.0 };
            parax.push(ParaxialSurface {
                kind: s.kind,
                curvature: r.map(|r| 1.0 / r).unwrap_or(0.0) + 2.0 * alpha1,
                focal_length_mm: value(&values, i, "focal_length_mm").unwrap_or(f64::INFINITY),
                // An object at infinity is traced from the plane of surface 1's vertex (the object frame).
                thickness_mm: spec.traced_thickness(i, Ok(0.0), || value(&values, i, "thickness_mm").ok_or_else(|| sys_err(i, "thickness_mm", "unresolved".into())))?,
                n_after: n_paraxial[i],
            });
        }
        let pupil = entrance_pupil(&parax, stop_index, spec.aperture, spec.surfaces[stop_index].semi_diameter_mm, at_infinity)
            .map_err(|m| sys_err(stop_index, "stop", m))?;
        let first_order = first_order(&parax, stop_index, &pupil);
        let mut fields = super::fields::object_fields(spec, &pupil, &first_order).map_err(|m| Error::spec(&spec.name, m))?;

        // Pass 2: frames, solving chief-ray cells in surface order.
        let mut resolved_spec = spec.clone();
        let mut surfaces: Vec<ResolvedSurface> = Vec::with_capacity(n);
        let mut path: Vec<PathStep> = Vec::new();
        let mut current = Frame::IDENTITY; // frame at the vertex of the surface being placed
        let mut last_step_frame = Frame::IDENTITY; // frame of the previous traced surface (object = identity)
        let mut stop_probe: Option<StopProbe> = None;
        let mut coded_mask: Option<super::MaskSurface> = None;
        for i in 0..n {
            let s = &spec.surfaces[i];
            let surface_frame = current;
            let mut next = current;
            let mut shape = None;
            if s.kind == SurfaceKind::CoordinateBreak {
                // Late pickups (sources solved by now).
                for col in CB_COLUMNS {
                    if value(&values, i, col).is_none() {
                        if let Some(Driver::Pickup(p)) = s.cell(col).map(|c| &c.driver) {
                            let src_col = p.column.as_deref().unwrap_or(col);
                            let v = value(&values, p.surface, src_col).ok_or_else(|| {
                                sys_err(i, col, format!("pickup from surface {} `{src_col}`, which is not resolved before this surface", p.surface))
                            })?;
                            values[i].insert(col.to_string(), Some(p.scale * v + p.offset));
                        }
                    }
                }
                let solved: Vec<&str> =
                    CB_COLUMNS.iter().copied().filter(|c| s.cell(c).map(|c| c.driver == Driver::ChiefRay).unwrap_or(false)).collect();
                if !solved.is_empty() {
                    let partial = SequentialSystem {
                        spec: resolved_spec.clone(),
                        surfaces: surfaces.clone(),
                        stop_index,
                        pupil,
                        first_order,
                        fields: fields.clone(),
                        aim_stop_radius_mm: pupil.stop_radius_mm,
                        path: path.clone(),
                        // Before the stop is placed there is nothing to aim at: steps > path.len() says so.
                        coded_mask: None,
                        origin: Default::default(),
                        stop_probe: stop_probe.clone().unwrap_or_else(|| StopProbe { steps: usize::MAX, probe: path_step(&Frame::IDENTITY, &Frame::IDENTITY, 0, SurfaceShape::Plane, Aperture::None, Interaction::Refract), open_path: None }),
                    };
                    if spec.field_type == crate::spec::FieldType::RealImageHeight {
                        return Err(sys_err(i, solved[0], "a chief-ray solve needs the object field before the system is built; real image height fields are found by tracing the built system: use another field type".into()));
                    }
                    let field = fields.first().copied().unwrap_or([0.0, 0.0]);
                    let (p_local, d_local) = chief_ray_at(&partial, &last_step_frame, &surface_frame, field, &n_primary)
                        .map_err(|m| sys_err(i, solved[0], format!("chief-ray solve failed: {m}")))?;
                    let order = if s.order == 0 { BreakOrder::DecenterThenTilt } else { BreakOrder::TiltThenDecenter };
                    let get = |values: &Vec<HashMap<String, Option<f64>>>, c: &str| value(values, i, c).unwrap_or(0.0);
                    let sol = solve_chief_ray_break(
                        p_local,
                        d_local,
                        [get(&values, CB_COLUMNS[0]), get(&values, CB_COLUMNS[1]), get(&values, CB_COLUMNS[2]), get(&values, CB_COLUMNS[3]), get(&values, CB_COLUMNS[4])],
                        [0, 1, 2, 3, 4].map(|k| solved.contains(&CB_COLUMNS[k])),
                        order,
                    );
                    for (k, col) in CB_COLUMNS.iter().enumerate() {
                        if solved.contains(col) {
                            values[i].insert(col.to_string(), Some(sol[k]));
                        }
                    }
                }
                let g = |c: &str| value(&values, i, c).unwrap_or(0.0);
                next = coordinate_break_frame(
                    &current,
                    g("decenter_x_mm"),
                    g("decenter_y_mm"),
                    g("tilt_x_deg").to_radians(),
                    g("tilt_y_deg").to_radians(),
                    g("tilt_z_deg").to_radians(),
                    if s.order == 0 { BreakOrder::DecenterThenTilt } else { BreakOrder::TiltThenDecenter },
                );
            } else {
                let curvature = value(&values, i, "radius_mm").map(|r| 1.0 / r).unwrap_or(0.0);
                let conic = value(&values, i, "conic").unwrap_or(0.0);
                shape = Some(match s.kind {
                    SurfaceKind::Paraxial => SurfaceShape::Paraxial { focal_length: value(&values, i, "focal_length_mm").unwrap_or(f64::INFINITY) },
                    SurfaceKind::EvenAsphere => SurfaceShape::EvenAsphere {
                        curvature,
                        conic,
                        coefficients: (1..=s.asphere_coefficients.len()).map(|k| value(&values, i, &format!("asphere_{k}")).unwrap_or(0.0)).collect(),
                    },
                    SurfaceKind::Toroidal => SurfaceShape::Toroidal {
                        curvature,
                        conic,
                        coefficients: (1..=s.asphere_coefficients.len()).map(|k| value(&values, i, &format!("asphere_{k}")).unwrap_or(0.0)).collect(),
                        rotation_curvature: value(&values, i, "rotation_radius_mm").map(|r| 1.0 / r).unwrap_or(0.0),
                    },
                    _ if curvature == 0.0 => SurfaceShape::Plane,
                    _ => SurfaceShape::Conic { curvature, conic },
                });
            }
            let thickness = value(&values, i, "thickness_mm").unwrap_or(0.0);
            // Write resolved values back into the spec's cells (late pickups and solves checked here).
            for col in resolved_spec.surfaces[i].present_columns() {
                if let Some(v) = value(&values, i, &col).filter(|v| !(i == 0 && col == "thickness_mm" && *v == f64::INFINITY)) {
                    crate::limits::check_resolved_cell(&col, v).map_err(|m| sys_err(i, &col, resolved_message(spec, i, &col, m)))?;
                }
                if let (Some(cell), Some(v)) = (resolved_spec.surfaces[i].cell_mut(&col), value(&values, i, &col)) {
                    cell.value = v;
                }
            }
            let surface = ResolvedSurface {
                index: i,
                kind: s.kind,
                comment: s.comment.clone(),
                is_stop: i == stop_index,
                frame: surface_frame,
                shape: shape.clone(),
                aperture: s.aperture.clone().unwrap_or(Aperture::None),
                medium_after: media[i].clone(),
                thickness_mm: thickness,
                semi_diameter_mm: s.semi_diameter_mm,
                interaction: match s.kind {
                    SurfaceKind::DiffractionGrating => Interaction::Grating {
                        grating: Grating {
                            lines_per_um: value(&values, i, "grating_lines_per_um").unwrap_or(f64::NAN),
                            order: value(&values, i, "grating_order").unwrap_or(0.0),
                        },
                        reflective: s.is_mirror(),
                        wavelength_slot: n,
                    },
                    _ if s.is_mirror() => Interaction::Reflect,
                    _ => Interaction::Refract,
                },
            };
            if i == stop_index {
                // The stop's own figure (a plane for a Coordinate Break stop), reached after the steps so far.
                let probe_shape = shape.clone().unwrap_or(SurfaceShape::Plane);
                // Apertures before the stop (clear apertures and obscurations) do not stop the aiming trace
                // (`rays::aim::stop_crossing`): they vignette the aimed ray when it is traced.
                let limited = |st: &PathStep| !matches!(st.aperture, Aperture::None);
                let open_path = path.iter().any(limited).then(|| path.iter().map(|st| PathStep { aperture: Aperture::None, ..st.clone() }).collect());
                stop_probe = Some(StopProbe { steps: path.len(), probe: path_step(&last_step_frame, &surface_frame, i, probe_shape, Aperture::None, Interaction::Refract), open_path });
            }
            if let Some(m) = &s.coded_mask {
                if !media[i - 1].is_air() {
                    return Err(sys_err(i, "coded_mask", "the coded mask must sit in air: the medium before it is a glass".into()));
                }
                coded_mask = Some(super::MaskSurface { surface: i, step: path.len(), pitch_mm: m.pitch_mm(), sampling: m.sampling });
            }
            if i > 0 {
                if let Some(shape) = shape {
                    path.push(path_step(&last_step_frame, &surface_frame, i, shape, surface.aperture.clone(), surface.interaction));
                    last_step_frame = surface_frame;
                }
            }
            surfaces.push(surface);
            // An object at infinity: surface 1 sits on the object frame's z = 0 plane, where rays start.
            current = next.advanced(spec.traced_thickness(i, 0.0, || thickness));
        }
        let stop_probe = stop_probe.expect("validated: the stop is a surface of the system");
        let mut system =
            SequentialSystem { spec: resolved_spec, surfaces, stop_index, pupil, first_order, fields: Vec::new(), aim_stop_radius_mm: pupil.stop_radius_mm, path, stop_probe, coded_mask, origin: Default::default() };
        if spec.ray_aiming == crate::spec::RayAiming::Real && spec.aperture != crate::spec::SystemAperture::FloatByStopSize {
            system.aim_stop_radius_mm = crate::rays::real_stop_radius(&system).map_err(|m| Error::spec(&spec.name, m))?;
        }
        if spec.field_type == crate::spec::FieldType::RealImageHeight {
            fields = super::fields::real_image_height_fields(&system, &fields).map_err(|m| Error::spec(&spec.name, m))?;
        }
        system.fields = fields;
        Ok(system)
    }
}

/// The step from frame `from` into surface `surface` placed at `to`.
fn path_step(from: &Frame, to: &Frame, surface: usize, shape: SurfaceShape, aperture: Aperture, interaction: Interaction) -> PathStep {
    // p_to = R_toᵀ R_from (p_from − o), o = the new vertex in `from` coordinates.
    let offset = from.point_to_local(to.origin);
    let rotation = to.rotation.transpose() * from.rotation;
    PathStep { surface, rotation, offset, shape, aperture, interaction }
}

/// The message of an implausible resolved value, saying where it came from (a pickup, a solve, or as given).
fn resolved_message(spec: &SystemSpec, i: usize, col: &str, why: String) -> String {
    match spec.surfaces[i].cell(col).map(|c| &c.driver) {
        Some(Driver::Pickup(p)) => format!("{why} after its pickup from surface {} (scale {}, offset {})", p.surface, crate::limits::fmt_num(p.scale), crate::limits::fmt_num(p.offset)),
        Some(Driver::ChiefRay) => format!("{why} after its chief-ray solve"),
        _ => why,
    }
}

/// Pass-1 value of a cell: `Ok(None)` when it depends on a chief-ray solve (resolved in pass 2).
fn resolve_cell(spec: &SystemSpec, i: usize, col: &str, depth: usize) -> Result<Option<f64>, String> {
    if depth > spec.surfaces.len() {
        return Err("pickup cycle".into());
    }
    let cell = spec.surfaces[i].cell(col).ok_or_else(|| format!("surface {i} has no `{col}` column to pick up"))?;
    match &cell.driver {
        // A pickup of unknown source is traced at its shown value.
        Driver::Fixed | Driver::UnknownPickup => Ok(Some(cell.value)),
        Driver::ChiefRay => Ok(None),
        Driver::Pickup(p) => {
            let src_col = p.column.as_deref().unwrap_or(col);
            if spec.surfaces.get(p.surface).is_none() {
                return Err(format!("pickup from surface {} which does not exist", p.surface));
            }
            let v = resolve_cell(spec, p.surface, src_col, depth + 1)?;
            if v.is_none() && p.surface > i {
                return Err(format!("pickup from later surface {} whose value is a chief-ray solve", p.surface));
            }
            Ok(v.map(|v| p.scale * v + p.offset))
        }
    }
}

/// Trace the primary chief ray of `field` through the surfaces placed so far and intersect it with the
/// plane z = 0 of `break_frame`. Returns the point and direction in `break_frame`'s coordinates.
fn chief_ray_at(partial: &SequentialSystem, last_frame: &Frame, break_frame: &Frame, field: [f64; 2], n: &[f64]) -> Result<(DVec3, DVec3), String> {
    let (p0, d0) = if partial.spec.ray_aiming == crate::spec::RayAiming::Off || partial.stop_probe.steps > partial.path.len() {
        crate::rays::object_ray(partial, field, 0.0, 0.0)
    } else {
        crate::rays::aimed_ray(partial, n, field, 0.0, 0.0).map_err(|e| e.to_string())?
    };
    let (p, d) = crate::tracer::kernel::trace_steps(&partial.path, n, p0, d0).map_err(|(st, s)| format!("chief ray {st:?} at surface {s}"))?;
    // p, d are in last_frame coordinates: to global, then to the break's frame.
    let pg = last_frame.point_to_global(p);
    let dg = last_frame.dir_to_global(d);
    let pl = break_frame.point_to_local(pg);
    let dl = break_frame.dir_to_local(dg);
    if dl.z == 0.0 {
        return Err("chief ray parallel to the break plane".into());
    }
    let t = -pl.z / dl.z;
    Ok((pl + dl * t, dl))
}

/// Decenters and tilts (mm, degrees) for the solved parameters so that the chief ray passing through
/// `p` (on the break plane) with direction `d` goes through the new origin along the new +z (as far as
/// the solved subset allows; unsolved parameters keep their values).
fn solve_chief_ray_break(p: DVec3, d: DVec3, mut v: [f64; 5], solved: [bool; 5], order: BreakOrder) -> [f64; 5] {
    use crate::geometry::{rot_x, rot_y};
    match order {
        BreakOrder::DecenterThenTilt => {
            if solved[0] {
                v[0] = p.x;
            }
            if solved[1] {
                v[1] = p.y;
            }
            // R = Rx(a) Ry(b) Rz(c). Solve a so that d has no component along the new y (independent of b),
            // then b so that it has none along the new x.
            if solved[2] {
                v[2] = (-d.y).atan2(d.z).to_degrees();
            }
            if solved[3] {
                let d1 = rot_x(v[2].to_radians()).transpose() * d;
                v[3] = d1.x.atan2(d1.z).to_degrees();
            }
            if solved[4] {
                v[4] = 0.0; // rotation about the chief ray itself is free: Zemax leaves it at zero
            }
        }
        BreakOrder::TiltThenDecenter => {
            // R = Rz(c) Ry(b) Rx(a): the z axis after Rz is unchanged, so solve b then a in the Rz frame.
            let dz = crate::geometry::rot_z(v[4].to_radians()).transpose() * d;
            if solved[3] {
                v[3] = dz.x.atan2((dz.y * dz.y + dz.z * dz.z).sqrt()).to_degrees();
            }
            let d2 = rot_y(v[3].to_radians()).transpose() * dz;
            if solved[2] {
                v[2] = (-d2.y).atan2(d2.z).to_degrees();
            }
            if solved[4] {
                v[4] = 0.0;
            }
            // Decenter along the tilted axes: the chief ray's crossing of the new origin plane.
            let r = crate::geometry::rot_z(v[4].to_radians()) * rot_y(v[3].to_radians()) * rot_x(v[2].to_radians());
            // The chief ray crosses the tilted plane z′ = 0 at q; the decenter puts the origin there.
            let (pr, dr) = (r.transpose() * p, r.transpose() * d);
            let pr = if dr.z != 0.0 { pr - dr * (pr.z / dr.z) } else { pr };
            if solved[0] {
                v[0] = pr.x;
            }
            if solved[1] {
                v[1] = pr.y;
            }
        }
    }
    v
}
