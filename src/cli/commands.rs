use super::args::*;
use super::shared::*;
use crate::analysis::{self, linspace, DistortionGrid, SpotDiagram};
use crate::error::{Error, Result};
use crate::io::{write_atomic, write_npy_f32, write_npy_f64, write_npy_u8, CsvValue, CsvWriter};
use crate::plot;
use crate::rays::{PupilPattern, RayBatch};
use crate::spec::{Driver, SurfaceKind};
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, RayStatus, Tracer};
use std::path::{Path, PathBuf};
use std::time::Instant;


fn pupil_points(a: &SpotArgs) -> Result<Vec<[f64; 2]>> {
    match &a.pupil_csv {
        Some(path) => {
            let cols = crate::io::read_columns(path, &["px", "py"])?;
            let pts: Vec<[f64; 2]> = cols[0].iter().zip(&cols[1]).map(|(x, y)| [*x, *y]).collect();
            if pts.is_empty() {
                return Err(Error::File { path: path.display().to_string(), message: "no pupil rows".into() });
            }
            // Normalised pupil coordinates live in the unit disc (a tiny tolerance for exported rims).
            if let Some((i, p)) = crate::analysis::first_point_outside_pupil(&pts) {
                return Err(Error::File {
                    path: path.display().to_string(),
                    message: format!("pupil row {} (px, py) = ({}, {}): normalised pupil coordinates must satisfy px² + py² ≤ 1", i + 1, p[0], p[1]),
                });
            }
            Ok(pts)
        }
        None => Ok(parse_pupil(&a.pupil)?.points()),
    }
}

/// Rays of `pupil × fields × wavelengths` within the ray and memory budgets (the CSV/PNG keep every ray).
fn check_spot_budget(pupil: usize, fields: usize, wavelengths: usize) -> Result<()> {
    let n = (pupil as f64 + 1.0) * fields as f64 * wavelengths as f64;
    let what = format!("--pupil × --field-mm × --wavelength-nm ({pupil} × {fields} × {wavelengths})");
    crate::limits::check_traced_rays(&what, &what, n)
}

/// The fields of `--field-mm`/`--field-deg` as object-space field points (mm, or rad at infinity), or the
/// system's.
fn fields(a: &SpotArgs, system: &SequentialSystem) -> Result<Vec<[f64; 2]>> {
    match parse_fields_for(system, &a.field_mm, &a.field_deg)? {
        Some(f) => Ok(f),
        None if system.fields.is_empty() => {
            Err(Error::invalid(format!("the system defines no fields: give {}", if system.object_at_infinity() { "--field-deg X,Y" } else { "--field-mm X,Y" })))
        }
        None => Ok(system.fields.clone()),
    }
}

/// A field point as printed: "(x, y) mm" for a finite object, "(θx, θy) deg" at infinity.
fn field_text(system: &SequentialSystem, f: [f64; 2]) -> String {
    let (v, unit) = system.field_display(f);
    format!("({}, {}) {unit}", shown(v[0]), shown(v[1]))
}

/// A value for text (not data): 12 significant digits, so a conversion's last bit does not show
/// (`24.000000000000004°` of a radian round trip, `587.5618000000001 nm` of µm × 1000), and −0 as 0.
fn shown(v: f64) -> String {
    let r: f64 = format!("{v:.11e}").parse().unwrap_or(v);
    crate::limits::fmt_num(if r == 0.0 { 0.0 } else { r })
}

fn shown_list(v: &[f64]) -> String {
    format!("[{}]", v.iter().map(|&x| shown(x)).collect::<Vec<_>>().join(", "))
}

fn wavelengths_or_system(w: &Option<String>, system: &SequentialSystem) -> Result<Vec<f64>> {
    match w {
        Some(t) => parse_wavelengths(t),
        None => Ok(system.spec.wavelengths_nm.clone()),
    }
}

/// Outputs staged but not yet moved into place: announced by [`commit`] once the whole set is in place.
static STAGED_WRITTEN: std::sync::Mutex<Vec<PathBuf>> = std::sync::Mutex::new(Vec::new());

/// Print "wrote PATH". A file staged by an [`crate::io::OutputSet`] (a staging name, or inside a staging
/// folder) is announced under its final name only when [`commit`] has moved the set into place: a later
/// failure (another output of the set that cannot be written) must not leave a "wrote" line behind.
pub(super) fn say_written(path: &Path) {
    let name = final_name(path);
    if name.as_path() != path {
        STAGED_WRITTEN.lock().unwrap_or_else(|e| e.into_inner()).push(name);
    } else {
        eprintln!("wrote {}", name.display());
    }
}

/// Commit an output set, then announce the files [`say_written`] deferred (none when the commit fails).
pub(super) fn commit(set: crate::io::OutputSet) -> Result<()> {
    let result = set.commit();
    let written = std::mem::take(&mut *STAGED_WRITTEN.lock().unwrap_or_else(|e| e.into_inner()));
    result?;
    for p in written {
        eprintln!("wrote {}", p.display());
    }
    Ok(())
}

/// The destination a staging path stands for: a component `.NAME.stage-<host>-<pid>-<start>-<n>[.ext]`
/// (a staged file, or a staging folder) → `NAME` ([`crate::io::stale`]).
fn final_name(path: &Path) -> PathBuf {
    path.components()
        .map(|c| {
            let s = c.as_os_str().to_string_lossy();
            if let (true, Some(k)) = (s.starts_with('.'), s.find(".stage-").filter(|&k| k > 1)) {
                s[1..k].to_string()
            } else {
                s.into_owned()
            }
        })
        .collect()
}

/// Check the format an output option names by its extension, and the output policy (not a folder, not one of
/// the command's `inputs`: [`crate::io::policy::check_out_file`]), before anything is computed or written.
pub(super) fn check_extension(option: &str, path: &Option<PathBuf>, allowed: &[&str], inputs: &[(&str, &Path)]) -> Result<()> {
    if let Some(p) = path {
        let ext = p.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
        if !allowed.contains(&ext.as_str()) {
            return Err(Error::invalid(format!("{option} {}: the file name must end in {}", p.display(), allowed.iter().map(|e| format!(".{e}")).collect::<Vec<_>>().join(" or "))));
        }
        if p.is_dir() {
            return Err(Error::invalid(format!("{option} {}: is a directory", p.display())));
        }
        crate::io::policy::check_out_file(option, p, inputs)?;
    }
    Ok(())
}

pub(super) fn write_json<T: serde::Serialize>(path: &Path, value: &T) -> Result<()> {
    crate::limits::check_json_finite(&final_name(path).display().to_string(), value)?;
    let text = serde_json::to_string_pretty(value).map_err(|e| Error::invalid(format!("JSON encoding failed: {e}")))?;
    write_atomic(path, text.as_bytes())?;
    say_written(path);
    Ok(())
}

// ---------------------------------------------------------------- info / export

fn cell_text(c: Option<&crate::spec::Cell>) -> String {
    match c {
        None => String::new(),
        Some(c) => {
            let flag = match (&c.driver, c.variable) {
                (Driver::Pickup(p), _) => format!(" P{}", p.surface),
                (Driver::ChiefRay, _) => " C".into(),
                (Driver::UnknownPickup, _) => " P?".into(),
                (Driver::Fixed, true) => " V".into(),
                _ => String::new(),
            };
            // OpticStudio's Lens Data Editor writes an infinite radius or thickness as "Infinity".
            if c.value.is_infinite() {
                format!("{}Infinity{flag}", if c.value < 0.0 { "-" } else { "" })
            } else {
                format!("{:.4}{flag}", c.value)
            }
        }
    }
}

/// The resolved Lens Data Editor as text.
pub fn lde_table(system: &SequentialSystem) -> String {
    use std::fmt::Write;
    let spec = &system.spec;
    let mut s = String::new();
    let _ = writeln!(s, "system `{}` — {}", spec.name, spec.description);
    // The fields as given: mm (object or image heights) or, for angle fields, degrees (a finite object's
    // angle fields printed `fields [] mm`; a held-out battery, round 7).
    let (values, unit) = match spec.field_type {
        crate::spec::FieldType::Angle => (spec.field_values(), "deg"),
        _ => (spec.field_values(), "mm"),
    };
    let fields = values.iter().map(|f| format!("({}, {})", shown(f[0]), shown(f[1]))).collect::<Vec<_>>().join(", ");
    let _ = writeln!(
        s,
        "aperture {:?}, ray aiming {:?}, primary {} nm, wavelengths {} nm, fields ({}) [{fields}] {unit}",
        spec.aperture,
        spec.ray_aiming,
        shown(spec.primary_wavelength_nm),
        shown_list(&spec.wavelengths_nm),
        spec.field_type.label()
    );
    let p = &system.pupil;
    if system.object_at_infinity() {
        let fo = &system.first_order;
        let shown: Vec<String> = system.fields.iter().map(|f| field_text(system, *f)).collect();
        let _ = writeln!(s, "object at infinity; fields ({}, as given: {:?}) as angles: {}", spec.field_type.label(), spec.field_values(), shown.join(", "));
        let _ = writeln!(
            s,
            "paraxial entrance pupil {:.6} mm after surface 1, diameter {:.6} mm{}; stop surface {} (paraxial stop radius {:.6} mm)",
            p.distance_mm,
            2.0 * p.radius_mm,
            if p.magnification_sign < 0.0 { ", an inverted image of the stop" } else { "" },
            system.stop_index,
            p.stop_radius_mm
        );
        // An afocal system (a flat grating, a telescope) has no finite EFL, BFL or F/#: said in words, never
        // `-inf` (the output policy: no inf in an output).
        let mm = |v: f64, none: &str| if v.is_finite() { format!("{v:.6} mm") } else { none.to_string() };
        let fno = fo.efl_mm.abs() / fo.enp_diameter_mm;
        let _ = writeln!(
            s,
            "first order (primary wavelength): EFL {}, BFL {}, exit pupil {} from the last surface ({} from the image), F/# {}",
            mm(fo.efl_mm, "afocal (infinite)"),
            mm(fo.bfl_mm, "none (afocal)"),
            mm(fo.exp_from_last_surface_mm, "at infinity"),
            mm(fo.exp_from_image_mm, "at infinity"),
            if fno.is_finite() { format!("{fno:.6}") } else { "none (afocal)".to_string() }
        );
    }
    let where_ = if system.object_at_infinity() {
        None
    } else if p.is_telecentric() {
        Some("at infinity (telecentric object space)".to_string())
    } else {
        Some(format!(
            "{:.4} mm from the object, radius {:.4} mm{}",
            p.distance_mm,
            p.radius_mm,
            if p.magnification_sign < 0.0 { ", an inverted image of the stop" } else { "" }
        ))
    };
    if let Some(where_) = where_ {
        let _ = writeln!(s, "paraxial entrance pupil {where_}; stop surface {} (paraxial stop radius {:.4} mm)", system.stop_index, p.stop_radius_mm);
    }
    if spec.ray_aiming != crate::spec::RayAiming::Off {
        let _ = writeln!(s, "ray aiming {:?}: rays cross the stop at (px, py) × {:.9} mm", spec.ray_aiming, system.aim_stop_radius_mm);
    }
    if !spec.vignetting_factors.is_empty() {
        let _ = writeln!(s, "vignetting factors [VDX, VDY, VCX, VCY] per field (applied by trace and spot; --full-pupil ignores them): {:?}", spec.vignetting_factors);
    }
    let n = system.indices(spec.primary_wavelength_nm).unwrap_or_default();
    let _ = writeln!(s, "{:>3} {:<18} {:<14} {:>12} {:>12} {:<8} {:>9} {:>8} {:>9}  parameters (flags: V variable, Pn pickup, C chief-ray solve)", "#", "type", "comment", "radius", "thickness", "material", "n@primary", "semi-dia", "aperture");
    for (i, surf) in spec.surfaces.iter().enumerate() {
        let kind = format!(
            "{}{}",
            if i == 0 { "OBJ " } else if i + 1 == spec.surfaces.len() { "IMA " } else if i == system.stop_index { "STO " } else { "" },
            surf.kind.label()
        );
        let params = match surf.kind {
            SurfaceKind::CoordinateBreak => format!(
                "dec x {} dec y {} tilt x {} tilt y {} tilt z {} order {}",
                cell_text(surf.decenter_x_mm.as_ref()),
                cell_text(surf.decenter_y_mm.as_ref()),
                cell_text(surf.tilt_x_deg.as_ref()),
                cell_text(surf.tilt_y_deg.as_ref()),
                cell_text(surf.tilt_z_deg.as_ref()),
                surf.order
            ),
            SurfaceKind::Paraxial => format!("f {}", cell_text(surf.focal_length_mm.as_ref())),
            _ => {
                let mut t = String::new();
                if let Some(k) = &surf.conic {
                    t += &format!("conic {}", cell_text(Some(k)));
                }
                if surf.kind == SurfaceKind::Toroidal {
                    t += &format!(" rotation radius {}", surf.rotation_radius_mm.as_ref().map(|c| cell_text(Some(c))).unwrap_or_else(|| "Infinity (cylinder)".into()));
                }
                for (k, a) in surf.asphere_coefficients.iter().enumerate() {
                    let var = if surf.kind == SurfaceKind::Toroidal { "y" } else { "a" };
                    t += &format!(" {var}{} {:e}", 2 * (k + 1), a.value);
                }
                if surf.kind == SurfaceKind::DiffractionGrating {
                    t += &format!(
                        " lines/µm {} order {} efficiency {}",
                        cell_text(surf.grating_lines_per_um.as_ref()),
                        cell_text(surf.grating_order.as_ref()),
                        surf.grating_efficiency.unwrap_or(1.0)
                    );
                }
                t.trim().to_string()
            }
        };
        let _ = writeln!(
            s,
            "{:>3} {:<18} {:<14} {:>12} {:>12} {:<8} {:>9} {:>8} {:>9}  {}",
            i,
            kind,
            surf.comment.chars().take(14).collect::<String>(),
            surf.radius_mm.as_ref().map(|r| cell_text(Some(r))).unwrap_or_else(|| if surf.kind == SurfaceKind::CoordinateBreak { String::new() } else { "Infinity".into() }),
            cell_text(Some(&surf.thickness_mm)),
            surf.material.clone().unwrap_or_default(),
            n.get(i).map(|v| format!("{v:.6}")).unwrap_or_default(),
            surf.semi_diameter_mm.map(|v| format!("{v:.3}")).unwrap_or_default(),
            match &surf.aperture {
                Some(crate::surfaces::Aperture::Circular { semi_diameter_mm, .. }) => format!("circ {semi_diameter_mm}"),
                Some(crate::surfaces::Aperture::Rectangular { half_width_x_mm, half_width_y_mm, .. }) => format!("rect {half_width_x_mm}×{half_width_y_mm}"),
                Some(crate::surfaces::Aperture::CircularObscuration { min_radius_mm, max_radius_mm, .. }) => format!("obsc {min_radius_mm}–{max_radius_mm}"),
                _ => String::new(),
            },
            params
        );
    }
    s
}

pub(super) fn info(a: InfoArgs) -> Result<()> {
    let system = load_system(&a.system)?;
    if a.json {
        println!("{}", crate::spec::to_json(&system.spec)?);
    } else {
        print!("{}", lde_table(&system));
        print!("{}", glass_table(&system)?);
        if let Some(path) = a.system.system.as_ref().filter(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("zmx"))) {
            let glass_catalogs = a.system.glass_catalogs.iter().map(crate::spec::catalog_entry).collect();
            let imported = crate::spec::zmx::import_zmx_file(path, &crate::spec::zmx::ZmxOptions { glass_catalogs, ..Default::default() })?;
            print!("{}", zmx_report(path, &imported));
        }
    }
    Ok(())
}

/// Where each glass comes from: catalogue, formula, n_d, the catalogue entry and the source.
fn glass_table(system: &SequentialSystem) -> Result<String> {
    use std::fmt::Write as _;
    // (`--glass-catalog` files are in the system's spec already: `load_system`.)
    let origins = crate::spec::zmx::glass_origins(&system.spec)?;
    let mut s = String::new();
    if origins.is_empty() {
        return Ok(s);
    }
    let _ = writeln!(s, "\nglasses (surface, glass, catalogue, formula, catalogue n_d, from, source):");
    for o in &origins {
        let _ = writeln!(s, "{:>3} {:<14} {:<10} {:<22} {:<10} {}  {}", o.surface, o.name, o.catalog, o.formula, o.nd, o.entry, o.source);
    }
    Ok(s)
}

/// What `info` adds for a `.zmx` file: its encoding, catalogue notes and the records skipped as carrying no optics.
fn zmx_report(path: &Path, imported: &crate::spec::zmx::ZmxImport) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(s, "\n{}: {}", path.display(), imported.encoding.label());
    for n in &imported.notes {
        let _ = writeln!(s, "note: {n}");
    }
    let _ = writeln!(s, "{}", skipped_list(&imported.skipped));
    s
}

/// The skipped records grouped by keyword: `  VERS ×1 (line 2): file and editor settings`.
pub(super) fn skipped_list(skipped: &[crate::spec::zmx::Unsupported]) -> String {
    use std::fmt::Write as _;
    let mut s = format!("skipped, no optics ({} records):", skipped.len());
    let mut groups: Vec<(&str, &str, Vec<usize>)> = Vec::new();
    for u in skipped {
        match groups.iter_mut().find(|g| g.0 == u.keyword && g.1 == u.reason) {
            Some(g) => g.2.push(u.line),
            None => groups.push((&u.keyword, &u.reason, vec![u.line])),
        }
    }
    for (k, reason, lines) in groups {
        let mut shown: Vec<String> = lines.iter().take(6).map(|l| l.to_string()).collect();
        if lines.len() > 6 {
            shown.push("…".into());
        }
        let _ = write!(s, "\n  {k} ×{} (line {}): {reason}", lines.len(), shown.join(", "));
    }
    s
}

pub(super) fn export_spec(a: ExportArgs) -> Result<()> {
    if let Some(fmt) = &a.format {
        let ext = a.out.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).unwrap_or_default();
        if ext != *fmt {
            return Err(Error::invalid(format!("--format {fmt} but --out {} has the extension `.{ext}`: name the file *.{fmt}", a.out.display())));
        }
    }
    crate::io::policy::check_out_file("--out", &a.out, &system_inputs(&a.system))?;
    let system = load_system(&a.system)?;
    crate::spec::save_spec_file(&system.spec, &a.out)?;
    say_written(&a.out);
    Ok(())
}

// ---------------------------------------------------------------- trace / spot

/// The system of `trace`/`spot`, its vignetting factors dropped under `--full-pupil`.
fn spot_system(a: &SpotArgs) -> Result<SequentialSystem> {
    let mut system = load_system(&a.system)?;
    if a.full_pupil {
        system.spec.vignetting_factors.clear();
    }
    Ok(system)
}

/// The comment saying which vignetting factors mapped a field's pupil points (empty when none did).
fn vignetting_note(system: &SequentialSystem, field: [f64; 2]) -> String {
    system
        .vignetting_of(field)
        .map(|v| format!("; pupil points traced at (VDX + px(1 − VCX), VDY + py(1 − VCY)), the field's vignetting factors VDX {} VDY {} VCX {} VCY {}", v.decenter[0], v.decenter[1], v.compression[0], v.compression[1]))
        .unwrap_or_default()
}

pub(super) fn trace(a: SpotArgs) -> Result<()> {
    let system = spot_system(&a)?;
    let ws = wavelengths_or_system(&a.wavelength_nm, &system)?;
    let fs = fields(&a, &system)?;
    if ws.len() != 1 || fs.len() != 1 {
        return Err(Error::invalid(format!(
            "trace takes one --wavelength-nm and one --field-mm (--field-deg at infinity) (got {} wavelengths, {} fields); use `spot` for several",
            ws.len(),
            fs.len()
        )));
    }
    check_outputs(&a)?;
    let pupil = pupil_points(&a)?;
    check_spot_budget(pupil.len(), 1, 1)?;
    let rays = RayBatch::for_field(&system, fs[0], &system.vignetted_pupil(fs[0], &pupil), ws[0])?;
    let tracer = super::fidelity::tracer_for(&a.backend, &system, &ws, rays.len() as u64)?;
    let out = tracer.trace(&system, &rays)?;
    let ok = out.ok_count();
    println!("traced {} rays of field {} at {} nm: {} ok, {} failed", out.len(), field_text(&system, fs[0]), shown(ws[0]), ok, out.len() - ok);
    if ok < out.len() {
        // Why they failed, most first (every cause is in the CSV's status and stop_surface columns).
        println!("failed: {}", analysis::describe_lost(&analysis::lost_rays(&out.status, &out.surface), 3));
    }
    let mut set = crate::io::OutputSet::files();
    if let Some(path) = &a.csv {
        let path = &set.stage(path);
        let mut w = CsvWriter::new(path, &["px", "py", "x_mm", "y_mm", "dir_x", "dir_y", "dir_z", "status", "stop_surface"])?;
        w.comment(&format!("system {}; field {}; wavelength {} nm; image-surface frame{}", system.name(), field_text(&system, fs[0]), shown(ws[0]), vignetting_note(&system, fs[0])));
        for i in 0..out.len() {
            let okr = out.status[i] == RayStatus::Ok;
            let num = |v: f64| if okr { CsvValue::F64(v) } else { CsvValue::Str("") };
            let surf = if okr { CsvValue::Str("") } else { CsvValue::Int(out.surface[i] as i64) };
            w.row(&[CsvValue::F64(pupil[i][0]), CsvValue::F64(pupil[i][1]), num(out.x[i]), num(out.y[i]), num(out.dir_x[i]), num(out.dir_y[i]), num(out.dir_z[i]), CsvValue::Str(out.status[i].label()), surf])?;
        }
        w.finish()?;
        say_written(path);
    }
    if let Some(path) = &a.json {
        let rays: Vec<serde_json::Value> = (0..out.len())
            .map(|i| serde_json::json!({"px": pupil[i][0], "py": pupil[i][1], "x_mm": out.x[i], "y_mm": out.y[i], "status": out.status[i].label()}))
            .collect();
        let field_key = if system.object_at_infinity() { "field_deg" } else { "field_mm" };
        write_json(&set.stage(path), &serde_json::json!({"system": system.name(), field_key: system.field_display(fs[0]).0, "wavelength_nm": ws[0], "rays": rays}))?;
    }
    commit(set)?;
    Ok(())
}

fn spot_summary(system: &SequentialSystem, s: &SpotDiagram) -> serde_json::Value {
    let (field, unit) = system.field_display(s.field_mm);
    serde_json::json!({
        if unit == "deg" { "field_deg" } else { "field_mm" }: field,
        "wavelength_nm": s.wavelength_nm,
        "rays": s.rays,
        "rays_ok": s.stats.map(|t| t.count).unwrap_or(0),
        "centroid_mm": s.stats.map(|t| t.centroid_mm),
        "chief_mm": s.chief_mm,
        "rms_radius_um": s.stats.map(|t| t.rms_radius_um),
        "geo_radius_um": s.stats.map(|t| t.geo_radius_um),
        "rms_radius_chief_um": s.rms_radius_chief_um,
        "rays_lost": s.lost,
    })
}

fn print_spot_table(system: &SequentialSystem, spots: &[SpotDiagram]) {
    let unit = system.field_display([0.0, 0.0]).1;
    println!("{:>16} {:>9} {:>11} {:>24} {:>10} {:>10} {:>10}", format!("field ({unit})"), "λ (nm)", "rays ok", "centroid (mm)", "RMS (µm)", "GEO (µm)", "RMS/chief");
    for s in spots {
        let ok = s.stats.map(|t| t.count).unwrap_or(0);
        let (c, r, g) = s.stats.map(|t| (format!("({:.6}, {:.6})", t.centroid_mm[0], t.centroid_mm[1]), format!("{:.3}", t.rms_radius_um), format!("{:.3}", t.geo_radius_um))).unwrap_or_default();
        println!(
            "{:>16} {:>9} {:>11} {:>24} {:>10} {:>10} {:>10}",
            {
                let f = system.field_display(s.field_mm).0;
                format!("({}, {})", shown(f[0]), shown(f[1]))
            },
            shown(s.wavelength_nm),
            format!("{ok}/{}", s.rays),
            c,
            r,
            g,
            s.rms_radius_chief_um.map(|v| format!("{v:.3}")).unwrap_or_default()
        );
    }
    // A spot whose every ray was lost has an empty row: say why (the three largest causes, and how many more).
    for s in spots.iter().filter(|s| s.stats.is_none() && s.rays > 0) {
        let f = system.field_display(s.field_mm).0;
        eprintln!("warning: field ({}, {}) {unit} at {} nm: no ray reached the image: {}", shown(f[0]), shown(f[1]), shown(s.wavelength_nm), analysis::describe_lost(&s.lost, 3));
    }
}

/// One panel per (field, wavelength), each centred on its own centroid: in a dispersive system the
/// wavelengths of one field land hundreds of µm apart, so sharing a panel would hide every spot's shape.
fn spot_plot(path: &Path, system: &SequentialSystem, title: &str, spots: &[SpotDiagram], fields: &[[f64; 2]]) -> Result<()> {
    let panels: Vec<plot::SpotPanel> = spots
        .iter()
        .filter_map(|s| {
            let ok: Vec<usize> = (0..s.status.len()).filter(|&i| s.status[i] == RayStatus::Ok).collect();
            if ok.is_empty() {
                return None;
            }
            let k = fields.iter().position(|f| *f == s.field_mm).map(|k| format!("F{} ", k + 1)).unwrap_or_default();
            Some(plot::SpotPanel {
                label: format!("{k}{} · {} nm", field_text(system, s.field_mm), shown(s.wavelength_nm)),
                series: vec![plot::SpotSeries {
                    label: format!("{} nm", shown(s.wavelength_nm)),
                    x_um: ok.iter().map(|&i| s.x_mm[i] * 1e3).collect(),
                    y_um: ok.iter().map(|&i| s.y_mm[i] * 1e3).collect(),
                }],
            })
        })
        .collect();
    plot::spot_diagram(path, title, &panels)?;
    say_written(path);
    Ok(())
}

/// Spot diagrams of every field × wavelength; `keep_rays: false` keeps only their statistics (the table
/// and JSON need no per-ray results), so memory holds one spot's rays at a time.
fn compute_spots(system: &SequentialSystem, tracer: &dyn Tracer, fs: &[[f64; 2]], ws: &[f64], pupil: &[[f64; 2]], keep_rays: bool) -> Result<Vec<SpotDiagram>> {
    let mut spots = Vec::new();
    for f in fs {
        for &w in ws {
            let mut s = analysis::spot_diagram(system, tracer, *f, w, pupil)?;
            if !keep_rays {
                s.keep_statistics_only();
            }
            spots.push(s);
        }
    }
    Ok(spots)
}

fn write_spot_csv(path: &Path, system: &SequentialSystem, spots: &[SpotDiagram]) -> Result<()> {
    let several = spots.len() > 1;
    let mut header = vec!["px", "py", "x_mm", "y_mm", "status"];
    if several {
        if system.object_at_infinity() {
            header.extend(["field_x_deg", "field_y_deg", "wavelength_nm"]);
        } else {
            header.extend(["field_x_mm", "field_y_mm", "wavelength_nm"]);
        }
    }
    let mut w = CsvWriter::new(path, &header)?;
    w.comment(&format!("system {}; image positions in the image surface's frame (mm); failed rays have empty positions", system.name()));
    for s in spots {
        for i in 0..s.status.len() {
            let ok = s.status[i] == RayStatus::Ok;
            let num = |v: f64| if ok { CsvValue::F64(v) } else { CsvValue::Str("") };
            let mut row = vec![CsvValue::F64(s.pupil[i][0]), CsvValue::F64(s.pupil[i][1]), num(s.x_mm[i]), num(s.y_mm[i]), CsvValue::Str(s.status[i].label())];
            if several {
                let f = system.field_display(s.field_mm).0;
                row.extend([CsvValue::F64(f[0]), CsvValue::F64(f[1]), CsvValue::F64(s.wavelength_nm)]);
            }
            w.row(&row)?;
        }
    }
    w.finish()?;
    say_written(path);
    Ok(())
}

/// `--csv`/`--json`/`--png` name files of their format (checked before any work).
fn check_outputs(a: &SpotArgs) -> Result<()> {
    let mut inputs = system_inputs(&a.system);
    inputs.extend(a.pupil_csv.as_deref().map(|p| ("--pupil-csv", p)));
    check_extension("--csv", &a.csv, &["csv"], &inputs)?;
    check_extension("--json", &a.json, &["json"], &inputs)?;
    check_extension("--png", &a.png, &["png"], &inputs)
}

pub(super) fn spot(a: SpotArgs) -> Result<()> {
    check_outputs(&a)?;
    let system = spot_system(&a)?;
    let ws = wavelengths_or_system(&a.wavelength_nm, &system)?;
    let fs = fields(&a, &system)?;
    let pupil = pupil_points(&a)?;
    check_spot_budget(pupil.len(), fs.len(), ws.len())?;
    let tracer = super::fidelity::tracer_for(&a.backend, &system, &ws, ((pupil.len() + 1) * fs.len() * ws.len()) as u64)?;
    let spots = compute_spots(&system, tracer.as_ref(), &fs, &ws, &pupil, a.csv.is_some() || a.png.is_some())?;
    print_spot_table(&system, &spots);
    if let Some(png) = a.png.as_ref().filter(|_| spots.iter().all(|s| s.stats.is_none())) {
        return Err(Error::invalid(format!("--png {}: no ray of any spot reached the image (the warnings above say why): nothing to plot; nothing written", png.display())));
    }
    let mut set = crate::io::OutputSet::files();
    if let Some(path) = &a.csv {
        write_spot_csv(&set.stage(path), &system, &spots)?;
    }
    if let Some(path) = &a.json {
        write_json(&set.stage(path), &serde_json::json!({"system": system.name(), "spots": spots.iter().map(|s| spot_summary(&system, s)).collect::<Vec<_>>()}))?;
    }
    if let Some(path) = &a.png {
        spot_plot(&set.stage(path), &system, &format!("{} spot diagram", system.name()), &spots, &fs)?;
    }
    commit(set)?;
    Ok(())
}

// ---------------------------------------------------------------- distortion / dispersion / mapping

fn write_distortion_csv(path: &Path, system: &SequentialSystem, g: &DistortionGrid) -> Result<()> {
    let header: &[&str] = if system.object_at_infinity() {
        &["i", "j", "x_field_tan", "y_field_tan", "r_field_tan", "pred_x_mm", "pred_y_mm", "real_x_mm", "real_y_mm", "distortion_pct", "status"]
    } else {
        &["i", "j", "x_field_mm", "y_field_mm", "r_field_mm", "pred_x_mm", "pred_y_mm", "real_x_mm", "real_y_mm", "distortion_pct", "status"]
    };
    let mut w = CsvWriter::new(path, header)?;
    w.comment(&format!("system {}; wavelength {} nm; positions absolute in the image surface's frame (mm)", system.name(), shown(g.wavelength_nm)));
    w.comment(&format!("reference (on-axis chief ray) Xref_mm={} Yref_mm={}", g.reference_mm[0], g.reference_mm[1]));
    w.comment(&format!("predicted = ref + ABCD·field, A={} B={} C={} D={}; max distortion {}%", g.abcd[0], g.abcd[1], g.abcd[2], g.abcd[3], g.max_distortion_pct));
    for p in &g.points {
        let ok = p.status == RayStatus::Ok;
        let num = |v: f64| if ok { CsvValue::F64(v) } else { CsvValue::Str("") };
        w.row(&[
            CsvValue::Int(p.i as i64),
            CsvValue::Int(p.j as i64),
            CsvValue::F64(p.x_field_mm),
            CsvValue::F64(p.y_field_mm),
            CsvValue::F64(p.x_field_mm.hypot(p.y_field_mm)),
            CsvValue::F64(p.pred_x_mm),
            CsvValue::F64(p.pred_y_mm),
            num(p.real_x_mm),
            num(p.real_y_mm),
            num(p.distortion_pct),
            CsvValue::Str(p.status.label()),
        ])?;
    }
    w.finish()?;
    say_written(path);
    Ok(())
}

fn distortion_plot(path: &Path, system: &SequentialSystem, g: &DistortionGrid, arrow_scale: f64) -> Result<()> {
    let pts: Vec<plot::DistortionPoint> = g
        .points
        .iter()
        .filter(|p| p.status == RayStatus::Ok)
        .map(|p| plot::DistortionPoint { paraxial_x_mm: p.pred_x_mm, paraxial_y_mm: p.pred_y_mm, real_x_mm: p.real_x_mm, real_y_mm: p.real_y_mm })
        .collect();
    plot::distortion_map(path, &format!("{} grid distortion at {} nm (max {:.3} %)", system.name(), shown(g.wavelength_nm), g.max_distortion_pct), &pts, arrow_scale)?;
    say_written(path);
    Ok(())
}

pub(super) fn distortion(a: DistortionArgs) -> Result<()> {
    check_extension("--csv", &a.csv, &["csv"], &system_inputs(&a.system))?;
    check_extension("--json", &a.json, &["json"], &system_inputs(&a.system))?;
    check_extension("--png", &a.png, &["png"], &system_inputs(&a.system))?;
    if !(a.arrow_scale.is_finite() && a.arrow_scale > 0.0) {
        return Err(Error::invalid(format!("--arrow-scale {}: must be finite and > 0", a.arrow_scale)));
    }
    // From 1 µm: below it the ABCD fit to the grid itself is rounding noise (1e-12 mm reported 100 % distortion;
    // a held-out battery, round 6).
    if !(a.half_width_mm.is_finite() && a.half_width_mm >= MIN_GRID_HALF_WIDTH_MM && a.half_width_mm <= crate::limits::MAX_LENGTH_MM) {
        return Err(Error::invalid(format!("--half-width-mm {}: the half width must be in [{MIN_GRID_HALF_WIDTH_MM:e}, {:e}] mm", crate::limits::fmt_num(a.half_width_mm), crate::limits::MAX_LENGTH_MM)));
    }
    if a.grid == 0 {
        return Err(Error::invalid("--grid 0: needs at least 1 point per side"));
    }
    let n = (a.grid as f64).powi(2);
    crate::limits::check_rays(&format!("--grid {}", a.grid), n)?;
    crate::limits::check_memory(&format!("--grid {}", a.grid), crate::limits::bytes_distortion(a.grid))?;
    let system = load_system(&a.system)?;
    let w = a.wavelength_nm.unwrap_or(system.primary_wavelength_nm());
    let tracer = super::fidelity::tracer_for(&a.backend, &system, &[w], (a.grid * a.grid + 5) as u64)?;
    let g = if system.object_at_infinity() {
        let deg = match a.half_width_deg {
            Some(d) => d,
            None => {
                let m = system.fields.iter().map(|f| f[0].abs().max(f[1].abs())).fold(0.0, f64::max).to_degrees();
                if m > 0.0 {
                    m
                } else {
                    return Err(Error::invalid(format!("system `{}` has its object at infinity and no off-axis field: give the grid's half width in degrees (--half-width-deg D)", system.name())));
                }
            }
        };
        analysis::grid_distortion_angle(&system, tracer.as_ref(), w, a.grid, deg)?
    } else {
        if a.half_width_deg.is_some() {
            return Err(Error::invalid(format!("--half-width-deg: system `{}` has a finite object; give the grid's half width in mm (--half-width-mm)", system.name())));
        }
        analysis::grid_distortion(&system, tracer.as_ref(), w, a.grid, a.half_width_mm)?
    };
    let failed = g.points.iter().filter(|p| p.status != RayStatus::Ok).count();
    let max_disp_um = g.points.iter().filter(|p| p.status == RayStatus::Ok).map(|p| 1e3 * (p.real_x_mm - p.pred_x_mm).hypot(p.real_y_mm - p.pred_y_mm)).fold(0.0, f64::max);
    // Over the rays that arrived: with most of the grid lost the maximum describes few points (24 of 25
    // failed printed "max distortion 0.0000 %"; a held-out battery, round 7).
    let arrived = g.points.len() - failed;
    let max_text = match arrived {
        0 => "max distortion n/a (no ray arrived)".to_string(),
        n if failed > 0 => format!("max distortion {:.4} % ({max_disp_um:.2} µm) over the {n} of {} rays that arrived", g.max_distortion_pct, g.points.len()),
        _ => format!("max distortion {:.4} % ({max_disp_um:.2} µm)", g.max_distortion_pct),
    };
    println!(
        "{}: {}×{} grid at {} nm over ±{}: reference ({:.6}, {:.6}) mm, ABCD [{:.5}, {:.5}, {:.5}, {:.5}], {max_text}, {failed} rays failed",
        system.name(), a.grid, a.grid, shown(w),
        if system.object_at_infinity() { format!("{}° (tan θ grid)", shown(g.points.last().and_then(|p| p.y_field_deg).unwrap_or(0.0))) } else { format!("{} mm", shown(a.half_width_mm)) },
        g.reference_mm[0], g.reference_mm[1], g.abcd[0], g.abcd[1], g.abcd[2], g.abcd[3]
    );
    let mut set = crate::io::OutputSet::files();
    if let Some(p) = &a.csv {
        write_distortion_csv(&set.stage(p), &system, &g)?;
    }
    if let Some(p) = &a.json {
        write_json(&set.stage(p), &g)?;
    }
    if let Some(p) = &a.png {
        distortion_plot(&set.stage(p), &system, &g, a.arrow_scale)?;
    }
    commit(set)?;
    Ok(())
}

pub(super) fn dispersion(a: DispersionArgs) -> Result<()> {
    check_extension("--csv", &a.csv, &["csv"], &system_inputs(&a.system))?;
    check_extension("--png", &a.png, &["png"], &system_inputs(&a.system))?;
    let ws = parse_wavelengths_for("--wavelengths-nm", &a.wavelengths_nm)?;
    // The spread is that of the first and last wavelengths along the curve: an unsorted or repeated list gave
    // the spread of the wrong pair (`450,650,520` reported 450–520 nm; a held-out battery, round 6).
    if let Some(k) = (1..ws.len()).find(|&k| !(ws[k] > ws[k - 1])) {
        return Err(Error::invalid(format!("--wavelengths-nm `{}`: a dispersion curve needs increasing wavelengths ({} then {} nm)", a.wavelengths_nm, ws[k - 1], ws[k])));
    }
    let system = load_system(&a.system)?;
    let field = parse_fields_for(&system, a.field_mm.as_slice(), a.field_deg.as_slice())?.map(|f| f[0]).unwrap_or([0.0, 0.0]);
    let tracer = super::fidelity::tracer_for(&a.backend, &system, &ws, ws.len() as u64)?;
    let c = analysis::dispersion_curve(&system, tracer.as_ref(), field, &ws)?;
    println!("{}: field {}, {}–{} nm: spatio-spectral spreading {:.2} µm ({:.1} px of 10 µm)", system.name(), field_text(&system, field), shown(ws[0]), shown(ws[ws.len() - 1]), c.spread_um, c.spread_um / 10.0);
    let mut set = crate::io::OutputSet::files();
    if let Some(p) = &a.csv {
        let p = &set.stage(p);
        let mut w = CsvWriter::new(p, &["wavelength_nm", "x_mm", "y_mm"])?;
        w.comment(&format!("system {}; chief ray of field {}; spread {} um", system.name(), field_text(&system, field), c.spread_um));
        for k in 0..ws.len() {
            w.row_f64(&[ws[k], c.x_mm[k], c.y_mm[k]])?;
        }
        w.finish()?;
        say_written(p);
    }
    if let Some(p) = &a.png {
        let p = &set.stage(p);
        plot::dispersion_curve(p, &format!("{} spatio-spectral spreading ({:.1} µm)", system.name(), c.spread_um), &c.wavelength_nm, &c.x_mm, &c.y_mm)?;
        say_written(p);
    }
    commit(set)?;
    Ok(())
}

/// The smallest `distortion --half-width-mm`: 1 µm.
use crate::analysis::MIN_GRID_HALF_WIDTH_MM;

pub(super) fn mapping(a: MappingArgs) -> Result<()> {
    check_extension("--npy", &Some(a.npy.clone()), &["npy"], &system_inputs(&a.system))?;
    crate::io::policy::check_companions("--npy", &a.npy, &["npy"], &["_valid.npy", "_wavelengths_nm.npy"])?;
    // The companions follow the output policy of --npy itself, as make-scene's do: a symbolic link there was
    // replaced by a regular file, exit 0 (a held-out battery, round 16).
    let stem = a.npy.file_stem().and_then(|s| s.to_str()).unwrap_or("mapping");
    for (what, suffix) in [("--npy's validity mask", "_valid.npy"), ("--npy's wavelength list", "_wavelengths_nm.npy")] {
        crate::io::policy::check_out_file(what, &a.npy.with_file_name(format!("{stem}{suffix}")), &system_inputs(&a.system))?;
    }
    let ws = parse_wavelengths_for("--wavelengths-nm", &a.wavelengths_nm)?;
    if a.height == 0 || a.width == 0 {
        return Err(Error::invalid(format!("--height {} --width {}: both must be ≥ 1", a.height, a.width)));
    }
    if !(a.pitch_mm.is_finite() && a.pitch_mm > 0.0 && a.pitch_mm <= crate::limits::MAX_LENGTH_MM) {
        return Err(Error::invalid(format!("--pitch-mm {}: must be in (0, {:e}] mm", a.pitch_mm, crate::limits::MAX_LENGTH_MM)));
    }
    let what = format!("--height × --width × --wavelengths-nm ({} × {} × {})", a.height, a.width, ws.len());
    // The cube and its written copy (float32 unless --f64), and with a tracer other than the analytic kernel
    // (a --backend, a GPU --device, or one --tolerance-um may choose) one wavelength's chief-ray batch.
    let batched = a.device != crate::render::Device::Cpu || (a.precision != Some(crate::tracer::Precision::F32) && (a.backend.backend.as_deref().is_some_and(|b| b != "analytic") || a.backend.tolerance_um.is_some()));
    let batch = if batched { crate::limits::bytes_mapping_batch(a.height, a.width) } else { 0.0 };
    crate::limits::check_memory(&what, crate::limits::bytes_mapping_written(a.height, a.width, ws.len(), a.f64) + batch)?;
    crate::limits::check_rays(&what, a.height as f64 * a.width as f64 * ws.len() as f64)?;
    let device = a.device;
    let system = load_system(&a.system)?;
    // The scene pitch in the system's field unit: mm on a finite object plane, the pixel's angle (rad) at infinity.
    let mut cfg = crate::render::RenderConfig::paper(1);
    (cfg.scene_width, cfg.scene_pitch_mm, cfg.scene_fov_deg) = (a.width, a.pitch_mm, a.scene_fov_deg);
    let pitch = crate::render::scene_pitch_for(&system, &cfg)?;
    let a = MappingArgs { pitch_mm: pitch, ..a };
    let (tracer, stride) = match a.precision {
        _ if device != crate::render::Device::Cpu => {
            if a.backend.backend.is_some() || a.backend.tolerance_um.is_some() {
                return Err(Error::invalid(format!("--device {device} traces with the GPU kernels; it cannot be combined with --backend or --tolerance-um")));
            }
            (device.tracer(a.precision.unwrap_or_default())?, 1)
        }
        Some(crate::tracer::Precision::F32) => {
            if a.backend.backend.is_some() || a.backend.tolerance_um.is_some() {
                return Err(Error::invalid("--precision f32 traces with the analytic f32 kernel; it cannot be combined with --backend or --tolerance-um"));
            }
            (crate::tracer::Precision::F32.tracer(crate::tracer::Kernel::default())?, 1)
        }
        _ => super::fidelity::mapping_for(&a.backend, &system, a.height, a.width, a.pitch_mm, &ws)?,
    };
    // f32's rounding on this system, measured (the render's check): a warning above the documented figure.
    if a.precision == Some(crate::tracer::Precision::F32) {
        let level = crate::tracer::Precision::F32.level(crate::tracer::Kernel::default())?;
        if let Some(m) = crate::render::measure_f32_error(&system, a.height, a.width, a.pitch_mm, &ws, level)?.message() {
            eprintln!("warning: {m}");
        }
    }
    let t0 = Instant::now();
    let cube = analysis::mapping_cube_interpolated(&system, tracer.as_ref(), a.height, a.width, a.pitch_mm, &ws, stride)?;
    let secs = t0.elapsed().as_secs_f64();
    let n = a.height * a.width * ws.len();
    if stride > 1 {
        println!("{}: mapping {}×{}×{} = {n} entries in {secs:.2} s ({:.2} M entries/s; chief rays every {stride} pixels, cubic interpolation between)", system.name(), a.height, a.width, ws.len(), n as f64 / secs / 1e6);
    } else {
        println!("{}: mapping {}×{}×{} = {n} chief rays in {secs:.2} s ({:.2} M rays/s), {} did not arrive", system.name(), a.height, a.width, ws.len(), n as f64 / secs / 1e6, cube.invalid_count());
    }
    if cube.invalid_count() == n {
        // Every entry invalid: say why, from the on-axis chief ray at each wavelength (the cube is still written:
        // its validity flags are all false, as they should be).
        let mut why = Vec::new();
        for &w in &ws {
            let out = tracer.trace(&system, &crate::rays::RayBatch::chief_rays(&system, &[[0.0, 0.0]], w)?)?;
            if let Some(l) = analysis::lost_rays(&out.status, &out.surface).first() {
                why.push(format!("{} nm: {} at surface {} ({})", shown(w), l.status.label(), l.surface, l.status.meaning()));
            }
        }
        eprintln!("warning: no chief ray reached the image; the on-axis chief ray: {}", if why.is_empty() { "arrives at every wavelength (only the scene's off-axis points are lost)".to_string() } else { why.iter().take(3).cloned().collect::<Vec<_>>().join("; ") });
    }
    let shape = [a.height, a.width, ws.len(), 2];
    // A valid entry must hold a finite position in the written precision (an f64 beyond f32::MAX would
    // become inf beside a set validity flag).
    let valid_positions = cube.valid.iter().enumerate().filter(|(_, v)| **v != 0).flat_map(|(k, _)| [cube.positions_mm[2 * k], cube.positions_mm[2 * k + 1]]);
    if a.f64 {
        crate::limits::check_finite_array("mapping cube", valid_positions)?;
    } else {
        crate::limits::check_finite_array("mapping cube (float32)", valid_positions.map(|v| v as f32 as f64))?;
    }
    let mut set = crate::io::OutputSet::files();
    let npy = set.stage(&a.npy);
    if a.f64 {
        write_npy_f64(&npy, &shape, &cube.positions_mm)?;
    } else {
        let v: Vec<f32> = cube.positions_mm.iter().map(|&x| x as f32).collect();
        write_npy_f32(&npy, &shape, &v)?;
    }
    let stem = a.npy.file_stem().and_then(|s| s.to_str()).unwrap_or("mapping");
    let valid = a.npy.with_file_name(format!("{stem}_valid.npy"));
    write_npy_u8(&set.stage(&valid), &shape[..3], &cube.valid)?;
    let wl = a.npy.with_file_name(format!("{stem}_wavelengths_nm.npy"));
    write_npy_f64(&set.stage(&wl), &[ws.len()], &ws)?;
    commit(set)?;
    for p in [&a.npy, &valid, &wl] {
        say_written(p);
    }
    Ok(())
}

// ---------------------------------------------------------------- report (tables and plots of a preset)

pub(super) fn report(a: ReportArgs) -> Result<()> {
    // The output policy before any work: --out new, empty or a previous report (or --force), never an input.
    let rule = crate::io::policy::FolderRule { option: "--out", command: "report", marker: "report.json", force: a.force };
    let system = load_system(&a.system)?;
    // Everything is written into a staging folder beside --out and replaces it at the end (all or nothing).
    // Default out/report-<system> (like render's out/render-<system>), not a shared folder such as `out`.
    let out_dir = a.out.clone().unwrap_or_else(|| {
        let name = match (&a.system.preset, &a.system.system) {
            (Some(p), _) => p.clone(),
            (None, Some(f)) => f.file_stem().unwrap_or_default().to_string_lossy().into_owned(),
            _ => "system".into(),
        };
        PathBuf::from("out").join(format!("report-{name}"))
    });
    let set = crate::io::OutputSet::folder(&out_dir, &rule, &super::shared::system_inputs(&a.system))?;
    let out = &set.stage_dir().map(Path::to_path_buf).unwrap_or_else(|| out_dir.clone());
    let name = system.name().to_string();
    let t0 = Instant::now();
    write_atomic(out.join("system.txt"), lde_table(&system).as_bytes())?;
    crate::spec::save_spec_file(&system.spec, out.join("system.toml"))?;
    let fs = system.fields.clone();
    let ws = system.spec.wavelengths_nm.clone();
    let pupil = PupilPattern::Hexapolar { rings: 16 }.points();
    let bands = linspace(450.0, 650.0, 28);
    // One tracer for every analysis of the report (chosen from --tolerance-um over all its wavelengths and rays).
    let all_wavelengths: Vec<f64> = ws.iter().chain(&bands).copied().collect();
    let job_rays = ((pupil.len() + 1) * fs.len() * ws.len() + 169 * ws.len() + bands.len()) as u64;
    let tracer = super::fidelity::tracer_for(&a.backend, &system, &all_wavelengths, job_rays)?;
    let tracer = tracer.as_ref();
    let spots = compute_spots(&system, tracer, &fs, &ws, &pupil, true)?;
    print_spot_table(&system, &spots);
    write_spot_csv(&out.join("spots.csv"), &system, &spots)?;
    spot_plot(&out.join("spots.png"), &system, &format!("{name} spot diagrams (hexapolar, 16 rings)"), &spots, &fs)?;
    let mut grids = Vec::new();
    for &w in &ws {
        let g = if system.object_at_infinity() {
            let deg = system.fields.iter().map(|f| f[0].abs().max(f[1].abs())).fold(0.0, f64::max).to_degrees();
            analysis::grid_distortion_angle(&system, tracer, w, 13, if deg > 0.0 { deg } else { 1.0 })?
        } else {
            analysis::grid_distortion(&system, tracer, w, 13, 2.5)?
        };
        write_distortion_csv(&out.join(format!("distortion_{}nm.csv", w)), &system, &g)?;
        distortion_plot(&out.join(format!("distortion_{}nm.png", w)), &system, &g, 10.0)?;
        println!("distortion at {} nm: max {:.4} %", shown(w), g.max_distortion_pct);
        grids.push(serde_json::json!({"wavelength_nm": w, "reference_mm": g.reference_mm, "abcd": g.abcd, "max_distortion_pct": g.max_distortion_pct}));
    }
    let c = analysis::dispersion_curve(&system, tracer, [0.0, 0.0], &bands)?;
    plot::dispersion_curve(out.join("dispersion.png"), &format!("{name} spatio-spectral spreading ({:.1} µm)", c.spread_um), &c.wavelength_nm, &c.x_mm, &c.y_mm)?;
    say_written(&out.join("dispersion.png"));
    println!("spatio-spectral spreading 450–650 nm: {:.2} µm", c.spread_um);
    write_json(
        &out.join("report.json"),
        &serde_json::json!({
            "system": name, "version": env!("CARGO_PKG_VERSION"),
            "spots": spots.iter().map(|s| spot_summary(&system, s)).collect::<Vec<_>>(),
            "distortion": grids,
            "dispersion": {"wavelength_nm": c.wavelength_nm, "x_mm": c.x_mm, "y_mm": c.y_mm, "spread_um": c.spread_um},
            "seconds": t0.elapsed().as_secs_f64(),
        }),
    )?;
    commit(set)?;
    println!("report of `{name}` written to {} in {:.2} s", out_dir.display(), t0.elapsed().as_secs_f64());
    Ok(())
}

// ---------------------------------------------------------------- bench


/// `--repeat`, `--rays`, `--wavelengths` of a `bench` mode, each in its range (`--repeat` 1..=[`MAX_REPEAT`],
/// `--rays` ≥ 1, `--wavelengths` 1..=[`MAX_WAVELENGTHS`]) or the mode's default.
///
/// [`MAX_REPEAT`]: crate::limits::MAX_REPEAT
/// [`MAX_WAVELENGTHS`]: crate::limits::MAX_WAVELENGTHS
pub(super) fn bench_counts(a: &BenchArgs, repeat: usize, rays: usize, wavelengths: usize) -> Result<(usize, usize, usize)> {
    use crate::limits::{check_count, MAX_REPEAT, MAX_WAVELENGTHS};
    Ok((
        check_count("--repeat", a.repeat.unwrap_or(repeat), MAX_REPEAT)?,
        check_count("--rays", a.rays.unwrap_or(rays), usize::MAX)?,
        check_count("--wavelengths", a.wavelengths.unwrap_or(wavelengths), MAX_WAVELENGTHS)?,
    ))
}

pub(super) fn bench(a: BenchArgs) -> Result<()> {
    if a.mode.as_deref() == Some("tradeoff") {
        if a.system.is_some() {
            return Err(Error::invalid("--system belongs to `diffcassi bench nonsequential` (`tradeoff` takes --preset)"));
        }
        if a.floor {
            return Err(Error::invalid("--floor belongs to `diffcassi bench nonsequential`"));
        }
        if let Some(b) = &a.backends {
            return Err(Error::invalid(format!("--backends {b}: `bench tradeoff` measures every backend and model itself; --backends belongs to plain `diffcassi bench`")));
        }
        if let Some(r) = a.rays {
            return Err(Error::invalid(format!("--rays {r}: `bench tradeoff` sets its own workload sizes (--quick for the small ones); --rays belongs to plain `diffcassi bench` and `bench nonsequential`")));
        }
        return super::fidelity::bench_tradeoff(&a);
    }
    if a.mode.as_deref() == Some("nonsequential") {
        #[cfg(feature = "embree")]
        return super::nonsequential::bench_nonsequential(&a);
        #[cfg(not(feature = "embree"))]
        return Err(Error::invalid("`bench nonsequential` needs the `embree` feature (this build has none)"));
    }
    if a.floor {
        return Err(Error::invalid("--floor belongs to `diffcassi bench nonsequential`"));
    }
    if a.csv.is_some() || a.png.is_some() || a.quick || a.system.is_some() {
        return Err(Error::invalid("--csv, --png, --quick and --system belong to `diffcassi bench tradeoff|nonsequential`"));
    }
    let (repeat, rays, wavelengths) = bench_counts(&a, 3, 100_000, 28)?;
    let backends = a.backends.as_deref().unwrap_or("analytic");
    // Every backend named is parsed (an unknown one refused) before the estimate.
    let configs: Vec<crate::tracer::BackendConfig> = backends.split(',').map(str::parse).collect::<Result<_>>()?;
    let what = format!("--rays {rays} × --wavelengths {wavelengths}");
    let n = rays as f64 * wavelengths as f64;
    crate::limits::check_memory(&what, 2.0 * n * crate::limits::BYTES_PER_RAY)?;
    crate::limits::check_rays(&format!("{what} × --repeat {repeat} × backends × thread counts"), n * (repeat as f64 + 1.0) * 2.0 * configs.len() as f64)?;
    let system = SequentialSystem::build(&crate::presets::spec(&a.preset)?)?;
    let ws = linspace(450.0, 650.0, wavelengths);
    let batch = RayBatch::seeded_workload(&system, rays, &ws, 1000)?;
    // "All threads": the pool `--threads` set (default: every core).
    let cores = rayon::current_num_threads();
    let reference = AnalyticTracer::with_kernel(crate::tracer::Kernel::Scalar).trace(&system, &batch)?;
    println!(
        "preset {}, {} rays ({} per wavelength × {} wavelengths, seeded pupil samples over the system's fields), {} sequential surfaces per ray, best of {}",
        system.name(),
        batch.len(),
        rays,
        ws.len(),
        system.surfaces_per_ray(),
        repeat
    );
    println!("| backend | threads | seconds | M rays/s | M rays per CPU-s (per thread) | vs analytic scalar | max error µm | rms error µm |");
    println!("|---|---|---|---|---|---|---|---|");
    let mut thread_counts = vec![1];
    if cores > 1 {
        thread_counts.push(cores);
    }
    let mut analytic_rps: std::collections::HashMap<usize, f64> = std::collections::HashMap::new();
    // The analytic backend runs once per f64 kernel: scalar (the reference of the ratio column) and the
    // SIMD lanes at every instruction set this CPU has.
    let mut tracers: Vec<(String, bool, Box<dyn crate::tracer::Tracer>)> = Vec::new();
    for cfg in &configs {
        if cfg.backend == crate::tracer::Backend::Analytic {
            tracers.push(("analytic-f64 scalar".into(), true, Box::new(AnalyticTracer::with_kernel(crate::tracer::Kernel::Scalar))));
            for level in crate::tracer::SimdLevel::available() {
                let k = crate::tracer::Kernel::Simd(Some(level));
                tracers.push((format!("analytic-f64 {}", k.name()), false, Box::new(AnalyticTracer::with_kernel(k))));
            }
            // The f32 lane kernel (twice the lanes) at every level: its error column is against f64.
            for level in crate::tracer::SimdLevel::available() {
                tracers.push((format!("analytic-f32 simd-{}", level.name()), false, Box::new(crate::tracer::AnalyticF32Tracer::new(level))));
            }
        } else {
            let t = cfg.build()?;
            tracers.push((t.name(), false, t));
        }
    }
    for (label, is_reference, tracer) in &tracers {
        // Scene construction (Embree) is not part of the timing: build it once.
        let out = tracer.trace(&system, &batch)?;
        let (mut max, mut s2, mut n) = (0.0f64, 0.0, 0usize);
        for i in 0..out.len() {
            if out.status[i] == RayStatus::Ok && reference.status[i] == RayStatus::Ok {
                let e = 1e3 * (out.x[i] - reference.x[i]).hypot(out.y[i] - reference.y[i]);
                max = max.max(e);
                s2 += e * e;
                n += 1;
            }
        }
        for &threads in &thread_counts {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().map_err(|e| Error::invalid(e.to_string()))?;
            let (mut best, mut best_cpu) = (f64::INFINITY, f64::INFINITY);
            for _ in 0..repeat.max(1) {
                let c = cpu_seconds();
                let t = Instant::now();
                let out = pool.install(|| tracer.trace(&system, &batch))?;
                best = best.min(t.elapsed().as_secs_f64());
                if let Some(d) = cpu_interval(c, cpu_seconds()) {
                    best_cpu = best_cpu.min(d);
                }
                std::hint::black_box(out);
            }
            let rps = batch.len() as f64 / best;
            let per_cpu = if best_cpu.is_finite() && best_cpu > 0.0 { format!("{:.2}", batch.len() as f64 / best_cpu / 1e6) } else { "n/a".into() };
            if *is_reference {
                analytic_rps.insert(threads, rps);
            }
            let ratio = analytic_rps.get(&threads).map(|r| format!("{:.2}×", rps / r)).unwrap_or_else(|| "–".into());
            println!("| {label} | {threads} | {best:.3} | {:.2} | {per_cpu} | {ratio} | {max:.2e} | {:.2e} |", rps / 1e6, (s2 / n.max(1) as f64).sqrt());
        }
    }
    Ok(())
}
