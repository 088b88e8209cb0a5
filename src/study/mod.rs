//! The study: the reference paper's four-system experiment, end to end (`diffcassi study`, Python
//! `diffcassi.study`). Every scene is rendered through every
//! system with one mask, reconstructed with every operator and solver, and evaluated against the scene:
//!
//! ```text
//! diffcassi study --presets ap,sp,map,msp --operators exact,mapping,shift --scenes data/scenes --scene-size 128 --out out/study
//! diffcassi study --synthetic 2 --scene-size 24 --presets ap,sp --planes 28 --rays 4 --iterations 5 --out out/tiny
//! diffcassi study --synthetic 2 --presets sp --systems my_cassi.toml,lens.zmx --scene-fov-deg 6 --out out/mine
//! ```
//!
//! Systems are presets (`--presets`, rows named as in the paper: SP, mAP…) and files (`--systems`, read as
//! `--system` elsewhere; rows named by the file stem). For a system whose object is at infinity the scenes span
//! `--scene-fov-deg` degrees across their width (as `render --scene-fov-deg`); finite systems keep 10 µm pixels.
//!
//! Layout of `--out`: `study.json` (the marker of a study folder: command, version, configuration, systems), `mask.png` (the mask every render uses), `renders/<system>/<scene>/` (complete render
//! folders, readable by `reconstruct --from`; `<system>` is the preset's name or the file's stem), `recon/<system>/<scene>/<operator>-<solver>/` (`cube.npy`,
//! `rgb.png`, `reconstruct.json`), `cells/<system>/<scene>/<operator>-<solver>.json` (one finished cell:
//! its configuration, metrics and seconds), and, rebuilt from every cell at the end, `study.csv` (one row per
//! scene × system × operator × solver), `study.md` (the paper-shaped table, mean ± std over scenes, and the
//! ablation "reconstruct with the simplified model") and `study_psnr.png` (grouped bars).
//!
//! Resumable: a render whose `render.json` carries the same study configuration (and whose folder reads back
//! whole: acquisition, mask, record), and a cell whose result file carries the same configuration (and whose
//! `recon/` folder holds the `cube.npy` it recorded, `cube_npy_sha256`), are not recomputed; anything else is (the configuration is every setting
//! that changes a number: bands, planes, rays, seeds, mask, Airy, scene size and fit, solver settings; for a
//! system file its resolved spec, so that editing the file recomputes its rows; at infinity the angular extent).
//! The exact operator of a system is traced once (seed = acquisition seed + 1, as `reconstruct`'s default) and
//! reused for all its scenes; so are the other operators.
//!
//! [`run`] is the pipeline; [`StudySettings`] every option, with the defaults; [`StudyProgress`] what a client
//! shows while it runs (the command line draws progress bars, the bindings stay silent). Layout: settings and
//! checks (`settings`), systems (`systems`), scenes (`scenes`), the cells' records (`cells`), the tables
//! (`tables`).
//!
//! ```no_run
//! use diffcassi::study::{self, StudySettings};
//! let s = StudySettings { synthetic: Some(2), scene_size: 24, presets: Some("ap,sp".into()), planes: 28, rays: 4, ..StudySettings::new("out/tiny") };
//! let done = study::run(&s, &study::Silent)?;
//! println!("{} cells computed → {}", done.computed, done.table.display());
//! # Ok::<(), diffcassi::Error>(())
//! ```
mod cells;
mod scenes;
pub mod settings;
mod systems;
mod tables;

pub use settings::{split_list, StudySettings, DEFAULT_PRESETS};
pub use systems::system_label;

use cells::{cell_from_json, file_sha256, read_json, reconstruction_intact, same_config, write_json};
use scenes::{load_scenes, StudyScene};
use settings::{cell_settings, check_limits, check_options_apply, render_config, study_mask};
use systems::{check_scene_fov, load_systems, system_render_config};
use tables::write_tables;

use crate::error::{Error, Result};
use crate::recon::metrics::evaluate;
use crate::recon::pipeline::output::{reconstruction_rule, write_reconstruction};
use crate::recon::pipeline::{build_operator, check_solver, is_unrolled, noise_estimate, operator_seed, solve, NoiseModel, OperatorKind, RenderRecord, MC_MISMATCH_PER_RAY, RESIDUAL_DEFINITION};
use crate::recon::Operator;
use crate::render::settings::parse_wavelengths;
use crate::render::{output, Mask, PlaneTransport, RenderConfig, Renderer};
use crate::scene::SpectralCube;
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, Tracer};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// What a client shows while a study runs; every method does nothing by default ([`Silent`]).
pub trait StudyProgress: Sync {
    /// A line of the study's report (what it will compute, what each system rendered).
    fn line(&self, _text: &str) {}
    /// A warning for the user (e.g. unrolled weights trained with another mask).
    fn warning(&self, _text: &str) {}
    /// A system's light transport is being traced once for all its scenes: `rays` in all.
    fn transport_started(&self, _what: &str, _rays: u64) {}
    /// `n` more rays traced.
    fn rays(&self, _n: u64) {}
    fn transport_done(&self) {}
    /// `cells` cells of one system and operator start.
    fn cells_started(&self, _what: &str, _cells: u64) {}
    /// A cell is done: its one-line result (system, scene, operator, solver, PSNR, SSIM, SAM, seconds).
    fn cell_done(&self, _line: &str) {}
    fn cells_done(&self) {}
    /// Asked before each system's renders and each cell: `true` stops the study there (an error; finished
    /// cells are kept, so a later run resumes). Python answers with its pending signals (Ctrl-C).
    fn interrupted(&self) -> bool {
        false
    }
}

/// The error of a study stopped by [`StudyProgress::interrupted`].
fn interrupted(out: &Path) -> Error {
    Error::invalid(format!("the study was interrupted; the cells finished so far are kept in {} (run it again to resume)", out.display()))
}

/// No progress reports.
pub struct Silent;

impl StudyProgress for Silent {}

/// What a run did.
#[derive(Clone, Debug)]
pub struct StudySummary {
    /// Cells computed by this run, and cells reused from an earlier run of the same configuration.
    pub computed: usize,
    pub skipped: usize,
    pub seconds: f64,
    /// The paper-shaped table (`study.md`; `study.csv` and `study_psnr.png` beside it).
    pub table: PathBuf,
}

/// The file every study output folder holds (written first): the output policy recognises a previous study
/// by it ([`crate::io::policy`]).
pub const STUDY_MARKER: &str = "study.json";

/// The exclusive lock on the study folder `out` (existing), or the refusal when another study holds it.
fn lock_study(out: &Path, progress: &dyn StudyProgress) -> Result<Option<crate::io::lock::FolderLock>> {
    use crate::io::lock::{lock_folder, LockAttempt};
    match lock_folder(out, false) {
        Ok(LockAttempt::Held(l)) => Ok(Some(l)),
        Ok(LockAttempt::Busy) => Err(Error::File {
            path: out.display().to_string(),
            message: "another study is writing this folder (it holds the folder's lock); nothing was written. Wait for it to end and run this one again (it resumes the folder), or choose another --out".into(),
        }),
        Ok(LockAttempt::Unsupported(e)) => {
            progress.warning(&format!("{}: the file system cannot lock this folder ({e}): another study started on it at the same time would not be refused", out.display()));
            Ok(None)
        }
        Err(e) => Err(Error::File { path: out.display().to_string(), message: format!("cannot open the folder to lock it: {e}") }),
    }
}

/// Run (or resume) the study `a` describes, reporting to `progress`; see the module docs.
pub fn run(a: &StudySettings, progress: &dyn StudyProgress) -> Result<StudySummary> {
    let t0 = Instant::now();
    // ---- validate everything before any work ----
    let systems = load_systems(a)?;
    check_scene_fov(a, &systems)?;
    // (the library names the setting `--operator`; here the entry is one of --operators)
    let operators = split_list(&a.operators, "operators")?
        .iter()
        .map(|o| OperatorKind::parse(o).map_err(|e| Error::invalid(format!("--operators `{}`: {}", a.operators, e.to_string().replace("--operator `", "entry `")))))
        .collect::<Result<Vec<_>>>()?;
    let solvers = split_list(&a.solvers, "solvers")?;
    for s in &solvers {
        // (the library names the setting `--solver`; here the entry is one of --solvers)
        check_solver(&cell_settings(a, s)).map_err(|e| Error::invalid(format!("--solvers `{}`: {}", a.solvers, e.to_string().replace("--solver `", "entry `"))))?;
    }
    check_options_apply(a, &solvers)?;
    if let (Some(e), false) = (a.noise_estimate.map(NoiseModel::name), operators.contains(&OperatorKind::Exact)) {
        return Err(Error::invalid(format!("--noise-estimate {e}: applies to the exact operator only, and --operators `{}` has none", a.operators)));
    }
    if a.tuning.weights.is_some() && !solvers.iter().any(|s| is_unrolled(s)) {
        return Err(Error::invalid(format!("--weights applies to the unrolled solver only, and --solvers `{}` has none", a.solvers)));
    }
    // The unrolled network: weights for every system (its own committed file, or the --weights file's system).
    if solvers.iter().any(|s| is_unrolled(s)) {
        for s in &systems {
            crate::recon::pipeline::unrolled::check_system(a.tuning.weights.as_deref(), &s.system.spec).map_err(|e| s.error(format!("--solvers unrolled: {e}")))?;
        }
    }
    if a.tuning.iterations == Some(0) {
        return Err(Error::invalid("--iterations must be ≥ 1"));
    }
    if a.scene_size == 0 {
        return Err(Error::invalid("--scene-size must be ≥ 1"));
    }
    // The output policy before any work: --out new, empty, a previous study (or --force), never an input.
    let mut inputs: Vec<(&str, &Path)> = a.scenes.iter().map(|p| ("--scenes", p.as_path())).collect();
    inputs.extend(a.mask.as_deref().map(|p| ("--mask", p)));
    inputs.extend(a.tuning.denoiser.as_deref().map(|p| ("--denoiser", p)));
    inputs.extend(a.tuning.weights.as_deref().map(|p| ("--weights", p)));
    inputs.extend(a.systems.iter().map(|p| ("--systems", p.as_path())));
    inputs.extend(a.glass_catalogs.iter().map(|p| ("--glass-catalog", p.as_path())));
    crate::io::policy::check_out_folder(&a.out, &crate::io::policy::FolderRule { option: "--out", command: "study", marker: STUDY_MARKER, force: a.force }, &inputs)?;
    let bands = parse_wavelengths("--bands", &a.bands)?;
    check_limits(a, &bands, &solvers)?;
    // The unrolled network's band count before any render, as the PnP denoiser's below (a mismatch failed after
    // the renders: a held-out battery, round 6).
    if solvers.iter().any(|s| is_unrolled(s)) {
        for s in &systems {
            let net = crate::recon::prior::unrolled::UnrolledNetwork::load(a.tuning.weights.as_deref(), &s.system.spec.name)?;
            if net.meta.bands != bands.len() {
                return Err(s.error(format!("--solvers unrolled: the network {} was trained for {} bands, but --bands `{}` gives {}", net.source, net.meta.bands, a.bands, bands.len())));
            }
            // And their wavelengths (the same count at 380–720 nm failed after the renders; round 9).
            net.check_bands(&bands).map_err(|e| s.error(format!("--solvers unrolled: --bands `{}`: {e}", a.bands)))?;
        }
    }
    // The PnP denoiser's band count before any render (a mismatch failed after the renders and the other
    // solvers' cells: hours in at paper scale; a held-out battery, round 6).
    if solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp())) {
        let d = crate::recon::prior::network::SpectralUNet::load_pnp(a.tuning.denoiser.as_deref())?;
        if d.bands != bands.len() {
            return Err(Error::invalid(format!(
                "--solvers `{}`: the PnP denoiser{} was trained for {} bands, but --bands `{}` gives {}",
                a.solvers,
                a.tuning.denoiser.as_deref().map(|p| format!(" {}", p.display())).unwrap_or_default(),
                d.bands,
                a.bands,
                bands.len()
            )));
        }
    }
    let cfg = render_config(a, &bands)?;
    // Each system's render configuration (the angular extent for an object at infinity), checked now.
    let cfgs = systems.iter().map(|s| system_render_config(&cfg, s, a.scene_fov_deg)).collect::<Result<Vec<_>>>()?;
    let mask = study_mask(a)?;
    let scenes = load_scenes(a, &bands)?;
    // Every cell is scored with SSIM, whose window needs the scene at least that wide (it failed after the
    // renders; a held-out battery, round 8). Checked after the scenes and the networks, whose errors say more.
    let min_size = 2 * crate::recon::metrics::SSIM_RADIUS_PX + 1;
    if a.scene_size < min_size {
        return Err(Error::invalid(format!("--scene-size {}: must be ≥ {min_size} (every cell is scored with SSIM, whose Gaussian window is {min_size}×{min_size} pixels)", a.scene_size)));
    }
    let tracer = AnalyticTracer::default();
    // Each system's renderer, built once now: a render plane outside a glass's range (bands reaching past
    // it), a detector too large or beyond the memory budget is refused before anything is written (it
    // failed after study.json and mask.png: found moving the study into the library).
    for (s, c) in systems.iter().zip(&cfgs) {
        Renderer::new(&s.system, &tracer, c.clone(), mask.clone()).map_err(|e| s.error(e))?;
    }
    let op_seed = operator_seed(a.seed, None)?;
    let budget = a.transport_memory_gb * 1e9;
    // Every setting that changes a number.
    let mut config = json!({
        // Synthetic scenes are generated at the study's size: no fit (null, not the default `resize`).
        "scene_size": a.scene_size, "fit": if a.synthetic.is_some() { None } else { Some(&a.fit) }, "bands_nm": bands, "planes": a.planes, "rays": a.rays, "seed": a.seed,
        "operator_seed": op_seed, "mask": mask.description, "mask_open_pixels": mask.values.iter().filter(|&&v| v > 0.0).count(),
        "airy_diameter_px": a.airy_diameter_px, "iterations": a.tuning.iterations, "tv_weight": a.tuning.tv_weight, "accelerated": a.tuning.accelerated, "plain": a.tuning.plain, "tracer": tracer.name(),
    });
    // PnP settings join the configuration only when a PnP solver runs (so TV-only studies stay resumable
    // from folders written before PnP existed); the weights enter by content (CRC-32), not only by path.
    if solvers.iter().any(|s| s.parse::<crate::recon::SolverKind>().is_ok_and(|k| k.is_pnp())) {
        let crc = crate::recon::prior::network::weights_crc32(a.tuning.denoiser.as_deref())?;
        if let Some(o) = config.as_object_mut() {
            o.insert("pnp".into(), json!({"denoiser": a.tuning.denoiser.as_ref().map(|p| p.display().to_string()), "weights_crc32": crc, "sigma_max": a.tuning.sigma_max, "sigma_min": a.tuning.sigma_min, "sigma_auto": a.tuning.sigma_auto, "tv_warmup": a.tuning.tv_warmup,
                "equivariant": a.tuning.equivariant, "equivariant_seed": a.tuning.equivariant_seed,
                // The library's PnP defaults too: a cell computed under other defaults is recomputed.
                "defaults": crate::recon::SolverConfig::pnp_gap()}));
        }
    }
    // The unrolled network's weights by content (CRC-32 per system), only when it runs.
    if solvers.iter().any(|s| is_unrolled(s)) {
        let mut crcs = serde_json::Map::new();
        for s in &systems {
            let net = crate::recon::prior::unrolled::UnrolledNetwork::load(a.tuning.weights.as_deref(), s.system.name())?;
            crcs.insert(s.system.name().to_string(), json!(net.crc32));
        }
        if let Some(o) = config.as_object_mut() {
            o.insert("unrolled".into(), json!({"weights": a.tuning.weights.as_ref().map(|p| p.display().to_string()), "weights_crc32": crcs}));
        }
    }
    if let (Some(t), Some(o)) = (a.tuning.tolerance, config.as_object_mut()) {
        o.insert("tolerance".into(), json!(t));
    }
    if let Some(o) = config.as_object_mut() {
        // The stopping rule: τ as given and the library's TV defaults (a cell computed under other defaults
        // is recomputed). The defaults are labelled as such: the study's own iterations and weights are the
        // top-level keys (a block named `gap_tv` read as what ran; a held-out battery, round 7).
        o.insert("stopping".into(), json!({"discrepancy": a.tuning.discrepancy, "library_defaults": {"gap_tv": crate::recon::SolverConfig::gap_tv(), "admm_tv": crate::recon::SolverConfig::admm_tv()}, "mc_mismatch_per_ray": MC_MISMATCH_PER_RAY, "noise_estimate": a.noise_estimate.unwrap_or(NoiseModel::Spread).name(), "spread_every": crate::recon::solver::SPREAD_EVERY}));
    }
    if let (Some(w), Some(o)) = (&a.scene_wavelengths, config.as_object_mut()) {
        o.insert("scene_wavelengths".into(), json!(w));
    }
    // A mask file enters by content (its 16-bit codes' SHA-256, as render.json records it): the same path with
    // other contents reused the earlier renders and cells (a held-out battery, round 7). A random mask is its
    // seed and opening.
    if let (Some(_), Some(o)) = (&a.mask, config.as_object_mut()) {
        o.insert("mask_png_sha256".into(), json!(mask.png_sha256()));
    }
    // Renders depend on everything but the operator seed and the solver settings.
    let render_key = {
        let mut r = config.clone();
        if let Some(o) = r.as_object_mut() {
            for k in ["operator_seed", "iterations", "tv_weight", "accelerated", "plain", "pnp", "unrolled", "tolerance", "stopping"] {
                o.remove(k);
            }
        }
        r
    };
    std::fs::create_dir_all(&a.out).map_err(|e| Error::File { path: a.out.display().to_string(), message: format!("cannot create: {e}") })?;
    // One study at a time in a folder, for the whole run: two studies with other settings both ran and study.csv
    // mixed their cells while study.json recorded one (a held-out battery, round 16). The kernel releases the
    // lock when a run ends or is killed, so a study resumed afterwards goes on as before.
    let _lock = lock_study(&a.out, progress)?;
    // The marker that makes --out recognisable as a study (resumed by the next run), written first.
    // Each system: where it came from and what it adds to the configuration of its renders and cells.
    let listed: Vec<Value> = systems.iter().map(|s| {
        let mut v = json!({"label": s.label, "folder": s.key, "preset": s.preset, "file": s.file.as_ref().map(|p| p.display().to_string()), "name": s.system.name(), "object_at_infinity": s.system.object_at_infinity()});
        for (k, x) in s.configuration(a.scene_fov_deg) {
            v[k] = x;
        }
        v
    }).collect();
    let mut marker = json!({"command": "study", "version": env!("CARGO_PKG_VERSION"), "configuration": config, "systems": listed});
    if let Some(f) = a.scene_fov_deg {
        marker["scene_fov_deg"] = json!(f);
    }
    write_json(&a.out.join(STUDY_MARKER), &marker)?;
    mask.save_png(&a.out.join("mask.png"))?;
    progress.line(&format!(
        "study: {} scenes {}×{} × {} systems × {} operators × {} solvers = {} cells → {}",
        scenes.len(), a.scene_size, a.scene_size, systems.len(), operators.len(), solvers.len(),
        scenes.len() * systems.len() * operators.len() * solvers.len(), a.out.display()
    ));
    let mut computed = 0usize;
    let mut skipped = 0usize;
    for (si, sys) in systems.iter().enumerate() {
        let (system, folder, label) = (&sys.system, &sys.key, &sys.label);
        // This system's configuration: the study's plus its own (a file's spec, an angular extent).
        let (mut config, mut render_key) = (config.clone(), render_key.clone());
        for (k, v) in sys.configuration(a.scene_fov_deg) {
            config[k] = v.clone();
            render_key[k] = v;
        }
        if progress.interrupted() {
            return Err(interrupted(&a.out));
        }
        // ---- renders ----
        let dirs: Vec<PathBuf> = scenes.iter().map(|s| a.out.join("renders").join(folder).join(&s.name)).collect();
        let todo: Vec<usize> = (0..scenes.len())
            .filter(|&i| {
                let j = read_json(&dirs[i].join("render.json"));
                let same_scene = j.as_ref().and_then(|j| j.get("scene_sha256")).and_then(Value::as_str) == Some(scenes[i].digest.as_str());
                // … and readable as a render folder (its acquisition, mask and record intact: a deleted or
                // replaced mask.png stopped the study at its first cell; a held-out battery, round 8).
                !(output::outputs_complete(&dirs[i])
                    && same_scene
                    && same_config(j.as_ref().and_then(|j| j.get("study_config")), &render_key)
                    && j.as_ref().is_some_and(|j| output::acquisition_intact(&dirs[i], j))
                    && RenderRecord::load(&dirs[i]).is_ok())
            })
            .collect();
        let tr = Instant::now();
        render_scenes(system, &tracer, &cfgs[si], &mask, &scenes, &dirs, &todo, &render_key, budget, progress)?;
        if !todo.is_empty() {
            progress.line(&format!("{}: rendered {} scenes in {:.1} s", label, todo.len(), tr.elapsed().as_secs_f64()));
        }
        // ---- cells ----
        let cell_path = |s: &str, op: OperatorKind, solver: &str| a.out.join("cells").join(folder).join(s).join(format!("{}-{solver}.json", op.name()));
        // A cell is done for this configuration and this scene's content.
        // … and its reconstruction folder holds the cube it recorded (a run that failed between writing the
        // folder and the cell left another run's cube under a cell counted as done; a held-out battery,
        // round 8). Cells written before the digest existed are computed once more.
        let done = |p: &Path, digest: &str| {
            read_json(p).is_some_and(|j| {
                same_config(j.get("config"), &config) && j.get("scene_sha256").and_then(Value::as_str) == Some(digest) && cell_from_json(&j).is_some() && reconstruction_intact(&a.out, &j)
            })
        };
        let record = RenderRecord::load(&dirs[0])?; // all scenes of a system share system, configuration and mask
        for &op_kind in &operators {
            let pending: Vec<(usize, &String)> = scenes.iter().enumerate().flat_map(|(i, s)| solvers.iter().map(move |v| (i, v)).filter(move |(_, v)| !done(&cell_path(&s.name, op_kind, v), &s.digest))).collect();
            skipped += scenes.len() * solvers.len() - pending.len();
            if pending.is_empty() {
                continue;
            }
            // The unrolled network, checked against this system's renders (they share system, bands and mask).
            let unrolled = if pending.iter().any(|(_, v)| is_unrolled(v)) {
                let p = std::sync::Arc::new(crate::recon::pipeline::unrolled::prepare(a.tuning.weights.as_deref(), &record, op_seed)?);
                for w in &p.check.warnings {
                    progress.warning(&format!("{label}: {w}"));
                }
                Some(p)
            } else {
                None
            };
            let t_op = Instant::now();
            // (an operator that cannot model this system is refused naming the system file and the operator)
            let op: Box<dyn Operator + '_> = build_operator(op_kind, &record, &tracer, op_seed, budget as u64, &|_| {}).map_err(|e| sys.error(format!("--operators {}: {e}", op_kind.name())))?;
            // The data-driven δ (exact operator, `--noise-estimate spread`): the operator's twin (not for the
            // unrolled network, which has no δ).
            let twin_plan = noise_estimate(&record, op_kind, op_seed, record.config.rays_per_pixel, record.config.rays_per_pixel, a.noise_estimate.unwrap_or(NoiseModel::Spread)).spread;
            let twin: Option<Box<dyn Operator + '_>> = match &twin_plan {
                Some(p) if pending.iter().any(|(_, v)| !is_unrolled(v)) => Some(build_operator(op_kind, &record, &tracer, p.twin_seed, budget as u64, &|_| {})?),
                _ => None,
            };
            let seconds_operator = t_op.elapsed().as_secs_f64();
            progress.cells_started(&format!("{} / {}", label, op_kind.name()), pending.len() as u64);
            for (i, solver) in pending {
                if progress.interrupted() {
                    progress.cells_done();
                    return Err(interrupted(&a.out));
                }
                let scene = &scenes[i];
                let rec = RenderRecord::load(&dirs[i])?;
                let mut settings = cell_settings(a, solver);
                if is_unrolled(solver) {
                    settings.unrolled = unrolled.clone();
                }
                let rays = rec.config.rays_per_pixel;
                settings.noise = Some(noise_estimate(&rec, op_kind, op_seed, rays, rays, settings.noise_model.unwrap_or(NoiseModel::Spread)));
                let solved = solve(op.as_ref(), &rec.acquisition, &settings, &|_, _| {}, twin.as_deref())?;
                for w in solved.warnings() {
                    progress.warning(&format!("{label} {} {} {solver}: {w}", scene.name, op_kind.name()));
                }
                let c = op.cube_shape();
                let estimate = SpectralCube::new(c.height, c.width, bands.clone(), solved.cube, "reconstructed cube")?;
                let ev = evaluate(&scene.cube, &estimate).map_err(|e| Error::invalid(format!("study: scene `{}` ({label}, {}, {solver}): {e}", scene.name, op_kind.name())))?;
                let final_residual = solved.final_residual;
                let rjson = json!({
                    "from": dirs[i].display().to_string(), "system": system.name(), "operator": op_kind.name(), "operator_seed": op_seed,
                    "acquisition_seed": a.seed, "oracle": op_seed == a.seed, "tracer": tracer.name(), "solver": solver, "solver_settings": solved.settings,
                    "shape": {"height": c.height, "width": c.width, "bands": c.bands}, "bands_nm": bands, "residual": solved.residuals,
                    "residual_definition": RESIDUAL_DEFINITION, "final_residual": final_residual, "stopping": solved.stopping, "threads": rayon::current_num_threads(),
                    "seconds_operator": seconds_operator, "seconds_solve": solved.seconds, "seconds": solved.seconds,
                });
                let rdir = a.out.join("recon").join(folder).join(&scene.name).join(format!("{}-{solver}", op_kind.name()));
                let set = crate::io::OutputSet::folder(&rdir, &reconstruction_rule(false), &[])?;
                write_reconstruction(set, &estimate, &rjson, false)?;
                let cube_sha256 = file_sha256(&rdir.join("cube.npy")).ok_or_else(|| Error::File { path: rdir.join("cube.npy").display().to_string(), message: "cannot be read back after writing".into() })?;
                let cell = json!({
                    "config": config, "preset": sys.preset, "system": label, "system_file": sys.file.as_ref().map(|p| p.display().to_string()), "scene": scene.name, "scene_sha256": scene.digest, "operator": op_kind.name(), "solver": solver,
                    "metrics": ev.metrics, "warnings": ev.warnings, "truth_resampled": ev.truth_resampled, "iterations": solved.residuals.len(), "stopped_by": solved.stopping.get("stopped_by"), "final_residual": final_residual,
                    "seconds_solve": solved.seconds, "seconds_operator": seconds_operator, "reconstruction": rdir.strip_prefix(&a.out).unwrap_or(&rdir).display().to_string(),
                    "cube_npy_sha256": cube_sha256,
                });
                write_json(&cell_path(&scene.name, op_kind, solver), &cell)?;
                computed += 1;
                progress.cell_done(&format!("{} {} {} {}: PSNR {:.2} dB, SSIM {:.3}, SAM {:.2}°, {:.1} s", label, scene.name, op_kind.name(), solver, ev.metrics.psnr_db, ev.metrics.ssim, ev.metrics.sam_deg, solved.seconds));
            }
            progress.cells_done();
        }
    }
    // ---- collect every cell of this configuration ----
    let mut cells = Vec::new();
    for sys in &systems {
        for s in &scenes {
            for &op in &operators {
                for v in &solvers {
                    let p = a.out.join("cells").join(&sys.key).join(&s.name).join(format!("{}-{v}.json", op.name()));
                    let c = read_json(&p).and_then(|j| cell_from_json(&j)).ok_or_else(|| Error::File { path: p.display().to_string(), message: "missing or unreadable cell result".into() })?;
                    cells.push(c);
                }
            }
        }
    }
    let labels: Vec<String> = systems.iter().map(|s| s.label.clone()).collect();
    write_tables(a, &labels, &operators, &solvers, &scenes, &cells, t0.elapsed().as_secs_f64())?;
    Ok(StudySummary { computed, skipped, seconds: t0.elapsed().as_secs_f64(), table: a.out.join("study.md") })
}


/// Render the scenes whose render folder is missing or stale, tracing the transport once when it fits.
#[allow(clippy::too_many_arguments)]
fn render_scenes(system: &SequentialSystem, tracer: &dyn Tracer, cfg: &RenderConfig, mask: &Mask, scenes: &[StudyScene], dirs: &[PathBuf], todo: &[usize], config: &Value, budget_bytes: f64, progress: &dyn StudyProgress) -> Result<()> {
    if todo.is_empty() {
        return Ok(());
    }
    let renderer = Renderer::new(system, tracer, cfg.clone(), mask.clone())?;
    let probe_bytes = renderer.trace_plane(renderer.config.spectral.planes() / 2)?.bytes() as f64 * renderer.config.spectral.planes() as f64 * 1.25;
    let t = Instant::now();
    let cached: Option<Vec<PlaneTransport>> = if todo.len() > 1 && probe_bytes <= budget_bytes {
        progress.transport_started(&format!("{}: tracing the light transport", system.name()), renderer.rays_per_render());
        let tr = renderer.trace_all(&|k| progress.rays(k));
        progress.transport_done();
        let tr = tr?;
        Some(tr)
    } else {
        None
    };
    let transport_seconds = t.elapsed().as_secs_f64();
    for &i in todo {
        let ts = Instant::now();
        let acq = match &cached {
            Some(tr) => renderer.render_cached(&scenes[i].cube, tr, false, &|_| {})?,
            None => renderer.render(&scenes[i].cube, false, &|_| {})?,
        };
        let dir = &dirs[i];
        std::fs::create_dir_all(dir).map_err(|e| Error::File { path: dir.display().to_string(), message: format!("cannot create: {e}") })?;
        let scale = output::write_images(dir, &renderer, &acq)?;
        renderer.mask.save_png(&dir.join("mask.png"))?;
        let mut j = output::sidecar(&renderer, &acq, None, &scenes[i].source, scale, ts.elapsed().as_secs_f64(), rayon::current_num_threads());
        if let Some(o) = j.as_object_mut() {
            o.insert("study_config".into(), config.clone());
            o.insert("scene_sha256".into(), json!(scenes[i].digest));
            o.insert("transport_cached".into(), json!(cached.is_some()));
            o.insert("transport_seconds".into(), json!(transport_seconds));
            o.insert("noise".into(), Value::Null);
        }
        output::write_sidecar(dir, &j)?;
    }
    Ok(())
}

