//! The unrolled network in Rust (`reconstruct --solver unrolled`, issue 43 item 2; src/recon/unrolled.rs,
//! src/recon/prior/unrolled.rs, src/recon/pipeline/unrolled.rs): the graph is plain GAP when the learned
//! parts are zero; the committed weights run on a tiny render through the CLI and `reconstruct.json` records the
//! solver and the weights' CRC-32; a same-mask render gives no mask warning; bad weights (another system, band
//! count or wavelengths, another architecture, a truncated or corrupt file, NaN, a wrong shape, a missing or
//! extra tensor) and misplaced options → exit ≠ 0, a message naming the file, field and value, nothing
//! written; `study --solvers gap-tv,unrolled`. Tiny sizes throughout. The numerical agreement with PyTorch is
//! `tests/python/test_unrolled_rust.py`.
use diffcassi::recon::prior::unrolled::{UnrolledNetwork, ARCH};
use diffcassi::recon::solver::Preconditioner;
use diffcassi::recon::unrolled::unrolled;
use diffcassi::prelude::*;
use diffcassi::recon::{CubeShape, ExactOperator, ImageShape, Operator, ShiftOperator};
use diffcassi::render::{Mask, RenderConfig, Renderer, SpectralSampling};
use serde_json::{json, Map, Value};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn committed_path(system: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("diffcassi/weights").join(format!("unrolled-gap-v1-{system}.safetensors"))
}

/// A safetensors file taken apart: its metadata and its tensors (name → (shape, f32 values)).
struct St {
    meta: Map<String, Value>,
    tensors: Vec<(String, Vec<usize>, Vec<f32>)>,
}

fn parse(bytes: &[u8]) -> St {
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: Map<String, Value> = serde_json::from_slice(&bytes[8..8 + n]).unwrap();
    let data = &bytes[8 + n..];
    let mut meta = Map::new();
    let mut tensors = Vec::new();
    for (k, v) in header {
        if k == "__metadata__" {
            meta = v.as_object().unwrap().clone();
            continue;
        }
        let shape: Vec<usize> = v["shape"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect();
        let o: Vec<usize> = v["data_offsets"].as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect();
        let vals = data[o[0]..o[1]].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
        tensors.push((k, shape, vals));
    }
    St { meta, tensors }
}

fn serialize(st: &St) -> Vec<u8> {
    let mut header = Map::new();
    let mut data: Vec<u8> = Vec::new();
    for (k, shape, vals) in &st.tensors {
        let a = data.len();
        data.extend(vals.iter().flat_map(|v| v.to_le_bytes()));
        header.insert(k.clone(), json!({"dtype": "F32", "shape": shape, "data_offsets": [a, data.len()]}));
    }
    header.insert("__metadata__".into(), Value::Object(st.meta.clone()));
    let mut h = serde_json::to_vec(&header).unwrap();
    while h.len() % 8 != 0 {
        h.push(b' ');
    }
    let mut out = (h.len() as u64).to_le_bytes().to_vec();
    out.extend(h);
    out.extend(data);
    out
}

fn committed(system: &str) -> St {
    parse(&std::fs::read(committed_path(system)).unwrap())
}

fn set_meta(st: &mut St, k: &str, v: &str) {
    st.meta.insert(k.into(), Value::String(v.into()));
}

/// The forward pass with the learned parts zero (every stage's linear path and tail, as the untrained
/// PyTorch network) is K plain GAP steps from x₀ = Φᵀ(y ⊙ D⁻¹), with λ_k the file's steps.
#[test]
fn zero_denoisers_give_plain_gap_with_the_learned_steps() {
    let mut st = committed("sp");
    for (k, _, v) in st.tensors.iter_mut() {
        if k.contains(".linear.") || k.contains(".tail.") {
            v.iter_mut().for_each(|x| *x = 0.0);
        }
        if k == "steps" {
            *v = vec![1.0, 0.5, 1.5, 0.8, 1.2, 0.9];
        }
    }
    let net = UnrolledNetwork::from_bytes(&serialize(&st), "zeroed").unwrap();
    // A tiny exact operator (SP, 10×10×28, one plane per band, 2 rays, Airy): ΦΦᵀ is not diagonal.
    let (h, w, b) = (10, 10, 28);
    let system = SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap();
    let tracer = AnalyticTracer::default();
    let bands = diffcassi::analysis::linspace(450.0, 650.0, b);
    let mut cfg = RenderConfig::paper(h);
    cfg.spectral = SpectralSampling::new(bands.clone(), 1).unwrap();
    cfg.rays_per_pixel = 2;
    let renderer = Renderer::new(&system, &tracer, cfg, Mask::random(h, w, 0.5, 3).unwrap()).unwrap();
    let op = ExactOperator::new(renderer, &bands, 1 << 30).unwrap();
    let truth: Vec<f32> = (0..h * w * b).map(|i| 0.2 + 0.6 * ((i * 7919 % 97) as f32 / 97.0)).collect();
    let y = (&op as &dyn Operator).apply(&truth).unwrap();
    let out = unrolled(&op, &y, &net, &mut |_, _, _| {}).unwrap();
    // The reference: plain GAP steps.
    let pre = Preconditioner::new(&op);
    let e: Vec<f32> = y.iter().zip(&pre.inverse).map(|(a, w)| a * w).collect();
    let mut x = (&op as &dyn Operator).adjoint(&e).unwrap();
    for lam in [1.0f32, 0.5, 1.5, 0.8, 1.2, 0.9] {
        let phi = (&op as &dyn Operator).apply(&x).unwrap();
        let r: Vec<f32> = y.iter().zip(&phi).zip(&pre.inverse).map(|((a, p), w)| (a - p) * w).collect();
        let g = (&op as &dyn Operator).adjoint(&r).unwrap();
        for (xi, gi) in x.iter_mut().zip(&g) {
            *xi += lam * gi;
        }
    }
    let peak = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let err = out.cube.iter().zip(&x).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    assert!(err <= 1e-5 * peak, "max |unrolled − plain GAP| = {err}, peak {peak}");
    assert_eq!(out.residuals.len(), 6);
    assert!(out.final_residual < out.residuals[0], "{:?} → {}", out.residuals, out.final_residual);
    // Positively homogeneous with the real weights: N(a·y) = a·N(y).
    let real = UnrolledNetwork::committed("sp").unwrap();
    let a = unrolled(&op, &y, &real, &mut |_, _, _| {}).unwrap().cube;
    let y3: Vec<f32> = y.iter().map(|v| 3.0 * v).collect();
    let a3 = unrolled(&op, &y3, &real, &mut |_, _, _| {}).unwrap().cube;
    let peak = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(a.iter().zip(&a3).all(|(p, q)| (3.0 * p - q).abs() <= 1e-4 * 3.0 * peak));
    // … down to a = 0: a dark frame reconstructs as zero (a scale of 1 there let the stages' biases through, a
    // bright cube — a held-out battery), every stage reported, the residual 0 of 0.
    let mut stages = 0;
    let z = unrolled(&op, &vec![0.0; y.len()], &real, &mut |_, _, _| stages += 1).unwrap();
    assert!(z.cube.iter().all(|&v| v == 0.0) && z.cube.len() == a.len(), "a dark frame reconstructed as a non-zero cube");
    assert_eq!((stages, z.residuals.len(), z.final_residual, z.scale), (6, 6, 0.0, 0.0));
    // A negative acquisition: the scale is mean|x₀|, so N(−y) is finite and no larger than N(y)'s order.
    let yn: Vec<f32> = y.iter().map(|v| -v).collect();
    let n = unrolled(&op, &yn, &real, &mut |_, _, _| {}).unwrap();
    assert!(n.scale > 0.0 && n.cube.iter().all(|v| v.is_finite() && v.abs() <= 10.0 * peak));
    // The library refuses a band-count mismatch.
    let op4 = ShiftOperator::new(CubeShape { height: 8, width: 8, bands: 4 }, ImageShape { height: 8, width: 11 }, &Mask::random(8, 8, 0.5, 3).unwrap(), 0, (0..4).collect(), 1, 1).unwrap();
    let e = unrolled(&op4, &vec![0.5; 88], &real, &mut |_, _, _| {}).err().unwrap().to_string();
    assert!(e.contains("is for 28 bands") && e.contains("has 4"), "{e}");
}

// ---- the CLI ----

fn bin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn render(dir: &Path, preset: &str, bands: &str, extra: &[&str]) {
    let mut args = vec!["render", "--preset", preset, "--scene-size", "16", "--bands", bands, "--planes", "28", "--rays", "1", "--no-mapping", "--out", s(dir)];
    args.extend_from_slice(extra);
    let o = bin(&args);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn read_json(p: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap()
}

/// The committed weights on a tiny SP render: the cube, `reconstruct.json` with the solver, the weights and
/// their CRC-32, the per-stage residuals and the checks; the warnings (another mask and size, planes, rays)
/// on stderr and in the record. With `--truth`, the PSNR of every stage.
#[test]
fn cli_unrolled_committed_weights_and_record() {
    let d = tempfile::tempdir().unwrap();
    let r = d.path().join("render");
    render(&r, "sp", "450:650:28", &[]);
    let out = d.path().join("rec");
    let o = bin(&["reconstruct", "--from", s(&r), "--solver", "unrolled", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(err.contains("warning:") && err.contains("metadata `mask_sha256`") && err.contains("trained with another mask (at 128×128)"), "{err}");
    assert!(err.contains("metadata `planes` = 112") && err.contains("metadata `rays` = 20"), "{err}");
    let j = read_json(&out.join("reconstruct.json"));
    assert_eq!(j["solver"], "unrolled");
    let crc = crc32fast::hash(&std::fs::read(committed_path("sp")).unwrap());
    assert_eq!(j["weights_crc32"].as_u64(), Some(crc as u64));
    assert!(j["weights"].as_str().unwrap().contains("unrolled-gap-v1-sp.safetensors"));
    assert_eq!(j["solver_settings"]["network"]["name"], ARCH);
    assert_eq!(j["solver_settings"]["network"]["weights_crc32"].as_u64(), Some(crc as u64));
    assert_eq!(j["residual"].as_array().unwrap().len(), 6);
    assert_eq!(j["iterations_run"], 6);
    assert_eq!(j["stopping"]["stopped_by"], "stages");
    assert_eq!(j["solver_settings"]["checks"]["mask_sha256"]["match"], false);
    assert_eq!(j["solver_settings"]["checks"]["operator_seed"], json!({"weights": 1, "operator": 1, "weights_acquisition_seed": 1000}));
    assert_eq!(j["warnings"].as_array().unwrap().len(), 3, "{}", j["warnings"]);
    assert!(out.join("cube.npy").is_file() && out.join("rgb.png").is_file());
    let (shape, cube) = diffcassi::io::read_npy_f64(out.join("cube.npy")).unwrap();
    assert_eq!(shape, vec![16, 16, 28]);
    assert!(cube.iter().all(|v| v.is_finite()));
    // The same with the file given explicitly (the embedded copy is the file) and a truth: the same cube.
    let out2 = d.path().join("rec2");
    let truth = d.path().join("truth.npy");
    let o = bin(&["make-scene", "--synthetic", "0", "--size", "16", "--bands", "450:650:28", "--out", s(&truth)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = bin(&["reconstruct", "--from", s(&r), "--solver", "unrolled", "--weights", s(&committed_path("sp")), "--truth", s(&truth), "--out", s(&out2)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j2 = read_json(&out2.join("reconstruct.json"));
    assert_eq!(j2["weights_crc32"], j["weights_crc32"]);
    assert_eq!(j2["stopping"]["psnr_per_iteration"].as_array().unwrap().len(), 6);
    assert_eq!(diffcassi::io::read_npy_f64(out2.join("cube.npy")).unwrap().1, cube);
}

/// A render whose mask and system are the ones the weights record (same SHA-256s) and whose planes and rays
/// match: no warning; a file's CRC-32 is the file's.
#[test]
fn cli_unrolled_same_mask_no_warning() {
    let d = tempfile::tempdir().unwrap();
    let mask = Mask::random(16, 16, 0.5, 9).unwrap();
    let mask_path = d.path().join("mask.npy");
    diffcassi::io::write_npy_f64(&mask_path, &[16, 16], &mask.values.iter().map(|v| *v as f64).collect::<Vec<_>>()).unwrap();
    let r = d.path().join("render");
    render(&r, "sp", "450:650:28", &["--mask", s(&mask_path)]);
    let mut st = committed("sp");
    set_meta(&mut st, "mask_sha256", &diffcassi::io::sha256::sha256_f32_hex(&mask.values));
    set_meta(&mut st, "planes", "28");
    set_meta(&mut st, "rays", "1");
    set_meta(&mut st, "system_sha256", &diffcassi::spec::system_sha256(&SequentialSystem::build(&presets::spec("sp").unwrap()).unwrap().spec).unwrap());
    let bytes = serialize(&st);
    let w = d.path().join("w.safetensors");
    std::fs::write(&w, &bytes).unwrap();
    let out = d.path().join("rec");
    let o = bin(&["reconstruct", "--from", s(&r), "--solver", "unrolled", "--weights", s(&w), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("warning"), "{}", stderr(&o));
    let j = read_json(&out.join("reconstruct.json"));
    assert_eq!(j["solver_settings"]["checks"]["mask_sha256"]["match"], true);
    assert_eq!(j["warnings"].as_array().unwrap().len(), 0);
    assert_eq!(j["weights_crc32"].as_u64(), Some(crc32fast::hash(&bytes) as u64));
}

/// Bad weights and misplaced options: exit ≠ 0, the message names the file, field and value; nothing written.
#[test]
fn cli_unrolled_bad_input() {
    let d = tempfile::tempdir().unwrap();
    let sp = d.path().join("sp");
    render(&sp, "sp", "450:650:28", &[]);
    let eight = d.path().join("eight");
    render(&eight, "sp", "450:650:8", &[]);
    let shifted = d.path().join("shifted");
    render(&shifted, "sp", "460:660:28", &[]);
    let ap = d.path().join("ap");
    render(&ap, "ap", "450:650:28", &[]);
    let file = |name: &str, bytes: &[u8]| -> PathBuf {
        let p = d.path().join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let full = std::fs::read(committed_path("sp")).unwrap();
    let truncated = file("truncated.safetensors", &full[..full.len() / 2]);
    let junk = file("junk.safetensors", b"\x10\x00\x00\x00\x00\x00\x00\x00{not json}");
    let edit = |name: &str, f: &dyn Fn(&mut St)| -> PathBuf {
        let mut st = committed("sp");
        f(&mut st);
        file(name, &serialize(&st))
    };
    let arch = edit("arch.safetensors", &|st| set_meta(st, "arch", "spectral-unet-v2"));
    let nan = edit("nan.safetensors", &|st| st.tensors.iter_mut().filter(|t| t.0 == "steps").for_each(|t| t.2[1] = f32::NAN));
    let shape = edit("shape.safetensors", &|st| set_meta(st, "width", "8"));
    let stages = edit("stages.safetensors", &|st| set_meta(st, "stages", "7"));
    let extra = edit("extra.safetensors", &|st| st.tensors.push(("bonus".into(), vec![2], vec![1.0, 2.0])));
    let no_system = edit("nosystem.safetensors", &|st| {
        st.meta.remove("system");
    });
    let bad_bands_nm = edit("bandsnm.safetensors", &|st| set_meta(st, "bands_nm", "[1, 2]"));
    let msp = committed_path("msp");
    let pnp = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/recon/prior/weights/spectral-unet-v2-28.safetensors");
    let missing = d.path().join("missing.safetensors");
    let folder = d.path().join("folder.safetensors");
    std::fs::create_dir(&folder).unwrap();
    let cases: Vec<(&Path, Vec<&str>, Vec<String>)> = vec![
        (&sp, vec!["--weights", s(&msp)], vec!["unrolled-gap-v1-msp.safetensors".into(), "metadata `system` = `msp`".into(), "the acquisition is from `sp`".into(), "refused".into()]),
        (&ap, vec![], vec!["no committed unrolled-gap-v1 weights for system `ap`".into(), "--weights".into()]),
        (&eight, vec![], vec!["metadata `bands` = 28".into(), "the acquisition has 8".into()]),
        (&shifted, vec![], vec!["metadata `bands_nm`: band 0 is 450 nm, the acquisition's is 460 nm".into()]),
        (&sp, vec!["--weights", s(&truncated)], vec!["truncated.safetensors".into(), "not a valid safetensors file".into()]),
        (&sp, vec!["--weights", s(&junk)], vec!["junk.safetensors".into(), "not a valid safetensors file".into()]),
        (&sp, vec!["--weights", s(&arch)], vec!["arch.safetensors".into(), "metadata `arch` = `spectral-unet-v2`".into()]),
        (&sp, vec!["--weights", s(&pnp)], vec!["spectral-unet-v2-28.safetensors".into(), "metadata `arch` = `spectral-unet-v2`".into()]),
        (&sp, vec!["--weights", s(&nan)], vec!["nan.safetensors".into(), "tensor `steps` value 1 is NaN".into()]),
        (&sp, vec!["--weights", s(&shape)], vec!["shape.safetensors".into(), "tensor `denoisers.0.head.weight` has shape [16, 28, 3, 3], expected [8, 28, 3, 3]".into()]),
        (&sp, vec!["--weights", s(&stages)], vec!["stages.safetensors".into(), "tensor `denoisers.6.linear.weight` is missing".into()]),
        (&sp, vec!["--weights", s(&extra)], vec!["extra.safetensors".into(), "tensor `bonus` is not part of unrolled-gap-v1".into()]),
        (&sp, vec!["--weights", s(&no_system)], vec!["nosystem.safetensors".into(), "metadata field `system` is missing".into()]),
        (&sp, vec!["--weights", s(&bad_bands_nm)], vec!["bandsnm.safetensors".into(), "metadata `bands_nm` has 2 finite values of 2, `bands` = 28".into()]),
        (&sp, vec!["--weights", s(&missing)], vec!["missing.safetensors".into(), "cannot read the unrolled weights".into()]),
        (&sp, vec!["--weights", s(&folder)], vec!["folder.safetensors".into(), "is a directory".into()]),
        (&sp, vec!["--iterations", "5"], vec!["--iterations: not options of --solver unrolled".into()]),
        (&sp, vec!["--denoiser", s(&pnp), "--plain"], vec!["--plain, --denoiser".into()]),
    ];
    for (i, (from, extra, needles)) in cases.iter().enumerate() {
        let out = d.path().join(format!("out{i}"));
        let mut args = vec!["reconstruct", "--from", s(from), "--solver", "unrolled", "--out", s(&out)];
        args.extend(extra.iter().copied());
        let o = bin(&args);
        let e = stderr(&o);
        assert!(!o.status.success(), "case {i} {extra:?}: accepted");
        for n in needles {
            assert!(e.contains(n.as_str()), "case {i} {extra:?}: `{n}` not in: {e}");
        }
        assert!(!out.exists(), "case {i}: {} written", out.display());
    }
    // --weights with another solver, and --out onto the weights file.
    let out = d.path().join("o");
    let o = bin(&["reconstruct", "--from", s(&sp), "--solver", "gap-tv", "--weights", s(&msp), "--out", s(&out)]);
    assert!(!o.status.success() && stderr(&o).contains("--weights applies to --solver unrolled only"), "{}", stderr(&o));
    assert!(!out.exists());
    let good = file("good.safetensors", &full);
    let o = bin(&["reconstruct", "--from", s(&sp), "--solver", "unrolled", "--weights", s(&good), "--out", s(&good)]);
    assert!(!o.status.success() && stderr(&o).contains("--weights"), "{}", stderr(&o));
    assert_eq!(std::fs::read(&good).unwrap(), full);
}

/// `study --solvers gap-tv,unrolled`: one row per solver, the unrolled cells from the committed weights
/// (their CRC-32 in the study's configuration); weights for one system refused for another before any work.
#[test]
fn cli_study_with_unrolled() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let o = bin(&["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--operators", "exact", "--solvers", "gap-tv,unrolled", "--planes", "28", "--rays", "1", "--iterations", "3", "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let csv = std::fs::read_to_string(out.join("study.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().skip(1).collect();
    assert_eq!(rows.len(), 2, "{csv}");
    assert!(rows.iter().any(|r| r.contains(",exact,gap-tv,")) && rows.iter().any(|r| r.contains(",exact,unrolled,")), "{csv}");
    let rec = out.join("recon/sp").read_dir().unwrap().next().unwrap().unwrap().path().join("exact-unrolled/reconstruct.json");
    let j = read_json(&rec);
    assert_eq!(j["solver"], "unrolled");
    assert_eq!(j["residual"].as_array().unwrap().len(), 6);
    let out2 = d.path().join("study2");
    let o = bin(&["study", "--synthetic", "1", "--scene-size", "16", "--presets", "msp", "--operators", "exact", "--solvers", "unrolled", "--weights", s(&committed_path("sp")), "--planes", "28", "--rays", "1", "--out", s(&out2)]);
    assert!(!o.status.success() && stderr(&o).contains("metadata `system` = `sp`"), "{}", stderr(&o));
    assert!(!out2.exists());
}

/// A system is its prescription, not its name: the committed SP weights accept the preset (also read back
/// from a TOML file) and refuse a file whose spec is named `sp` with one thickness moved, naming the field
/// that differs; a weights file recording `system_sha256` is held to it, one recording none runs with a
/// warning that only the name was checked; `study --systems` refuses the moved file before any work.
#[test]
fn weights_check_the_prescription_not_only_the_name() {
    use diffcassi::spec::{load_spec_file, save_spec_file, system_sha256};
    let d = tempfile::tempdir().unwrap();
    let preset = diffcassi::presets::spec("sp").unwrap();
    let file = d.path().join("sp.toml");
    save_spec_file(&preset, &file).unwrap();
    let same = SequentialSystem::build(&load_spec_file(&file).unwrap()).unwrap().spec;
    let net = UnrolledNetwork::committed("sp").unwrap();
    let (sha, warning) = net.check_system(&same).unwrap();
    assert_eq!((sha.as_str(), warning), (system_sha256(&SequentialSystem::build(&preset).unwrap().spec).unwrap().as_str(), None));
    // One gap moved by 0.5 mm, the name kept.
    let k = (1..preset.surfaces.len()).find(|&i| preset.surfaces[i].thickness_mm.value > 1.0).unwrap();
    let mut moved = same.clone();
    moved.surfaces[k].thickness_mm.value += 0.5;
    let e = net.check_system(&moved).unwrap_err().to_string();
    for n in ["unrolled-gap-v1-sp.safetensors", "refused", "a system is its prescription", &format!("first difference from the preset `sp`: surfaces[{k}].thickness_mm")] {
        assert!(e.contains(n), "`{n}` not in: {e}");
    }
    // A file that records the prescription it was trained for is held to it, whatever the name says.
    let with = |sha: &str| {
        let mut st = committed("sp");
        set_meta(&mut st, "system_sha256", sha);
        UnrolledNetwork::from_bytes(&serialize(&st), "recorded").unwrap()
    };
    assert!(with(&system_sha256(&moved).unwrap()).check_system(&moved).is_ok());
    assert!(with(&system_sha256(&moved).unwrap()).check_system(&same).unwrap_err().to_string().contains("refused"));
    let e = UnrolledNetwork::from_bytes(&serialize(&{
        let mut st = committed("sp");
        set_meta(&mut st, "system_sha256", "12ab");
        st
    }), "short").err().unwrap().to_string();
    assert!(e.contains("metadata `system_sha256` = `12ab` is not 64 hex digits"), "{e}");
    // A file that records none: its name is all that is checked, and said.
    let (_, warning) = UnrolledNetwork::from_bytes(&serialize(&committed("sp")), "bare").unwrap().check_system(&moved).unwrap();
    assert!(warning.is_some_and(|w| w.contains("metadata `system_sha256` not recorded")));
    // The study refuses the moved file before any work.
    let moved_file = d.path().join("moved").join("sp.toml");
    std::fs::create_dir(moved_file.parent().unwrap()).unwrap();
    save_spec_file(&moved, &moved_file).unwrap();
    let out = d.path().join("study");
    let o = bin(&["study", "--synthetic", "1", "--scene-size", "16", "--systems", s(&moved_file), "--operators", "exact", "--solvers", "unrolled", "--planes", "28", "--rays", "1", "--out", s(&out)]);
    assert!(!o.status.success() && stderr(&o).contains(&format!("surfaces[{k}].thickness_mm")), "{}", stderr(&o));
    assert!(!out.exists());
}

/// A v2 (`unrolled-dauhst-v2`) weights file for SP at `bands` bands: every tensor of
/// `DauhstV2::tensor_shapes`, values from a fixed sequence (small, both signs; the layer norms' scales near 1),
/// the estimators' last layer set so that μ = softplus(0.5) and σ = softplus(−2).
fn v2_file(stages: usize, bands: usize, width: usize) -> St {
    use diffcassi::recon::prior::unrolled_v2::DauhstV2;
    let mut tensors = Vec::new();
    let mut seed = 0x9e37_79b9_7f4a_7c15u64;
    for (name, shape) in DauhstV2::tensor_shapes(stages, bands, width).unwrap() {
        let n: usize = shape.iter().product();
        let mut vals: Vec<f32> = (0..n)
            .map(|_| {
                seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                ((seed >> 40) as f32 / (1u64 << 24) as f32 - 0.5) * 0.2
            })
            .collect();
        if name.ends_with(".n1.weight") || name.ends_with(".n2.weight") || name.ends_with("temperature") {
            vals.iter_mut().for_each(|v| *v += 1.0);
        }
        if name.ends_with("mlp.2.weight") {
            vals.iter_mut().for_each(|v| *v *= 0.1);
        }
        if name.ends_with("mlp.2.bias") {
            vals = vec![0.5, -2.0];
        }
        tensors.push((name, shape, vals));
    }
    let mut meta = Map::new();
    for (k, v) in [("arch", "unrolled-dauhst-v2".to_string()), ("system", "sp".into()), ("stages", stages.to_string()), ("bands", bands.to_string()), ("width", width.to_string())] {
        meta.insert(k.into(), Value::String(v));
    }
    St { meta, tensors }
}

/// `reconstruct --solver unrolled --weights V2` runs the v2 graph (issue 43: the best learned method through the
/// CLI and `study`): the record names the architecture and each stage's (μ, σ); a v2 file with a tensor missing,
/// an extra one or a wrong shape is refused naming it, nothing written. The numbers against PyTorch:
/// tests/python/test_unrolled_rust.py.
#[test]
fn cli_unrolled_v2_weights() {
    let d = tempfile::tempdir().unwrap();
    let r = d.path().join("render");
    render(&r, "sp", "450:650:28", &[]);
    let w = d.path().join("v2.safetensors");
    std::fs::write(&w, serialize(&v2_file(2, 28, 4))).unwrap();
    let out = d.path().join("rec");
    let o = bin(&["reconstruct", "--from", s(&r), "--solver", "unrolled", "--weights", s(&w), "--out", s(&out)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let j = read_json(&out.join("reconstruct.json"));
    assert_eq!(j["solver_settings"]["network"]["name"], "unrolled-dauhst-v2");
    let est = j["solver_settings"]["estimates"].as_array().unwrap();
    assert_eq!(est.len(), 2);
    for e in est {
        let (mu, sigma) = (e["mu"].as_f64().unwrap(), e["sigma"].as_f64().unwrap());
        assert!((mu - 0.974).abs() < 0.05 && (sigma - 0.127).abs() < 0.05, "{e}");
    }
    assert_eq!(j["residual"].as_array().unwrap().len(), 2);
    let (shape, cube) = diffcassi::io::read_npy_f64(out.join("cube.npy")).unwrap();
    assert_eq!(shape, vec![16, 16, 28]);
    assert!(cube.iter().all(|v| v.is_finite()) && cube.iter().any(|v| *v != 0.0));
    let net = UnrolledNetwork::from_file(&w).unwrap();
    assert_eq!((net.arch(), net.stages()), ("unrolled-dauhst-v2", 2));
    // Damaged files: refused, naming the tensor; nothing written.
    let mut missing = v2_file(2, 28, 4);
    missing.tensors.retain(|(n, ..)| n != "priors.1.mid.0.attn.temperature");
    let mut extra = v2_file(2, 28, 4);
    extra.tensors.push(("bonus".into(), vec![1], vec![0.0]));
    let mut shaped = v2_file(2, 28, 4);
    let t = shaped.tensors.iter_mut().find(|(n, ..)| n == "estimators.0.mlp.0.weight").unwrap();
    t.1 = vec![16, 64];
    for (name, st, want) in [("missing", missing, "tensor `priors.1.mid.0.attn.temperature` is missing (unrolled-dauhst-v2 needs it"), ("extra", extra, "tensor `bonus` is not part of unrolled-dauhst-v2"), ("shaped", shaped, "tensor `estimators.0.mlp.0.weight` has shape [16, 64], expected [32, 32]")] {
        let f = d.path().join(format!("{name}.safetensors"));
        std::fs::write(&f, serialize(&st)).unwrap();
        let o2 = d.path().join(format!("rec-{name}"));
        let o = bin(&["reconstruct", "--from", s(&r), "--solver", "unrolled", "--weights", s(&f), "--out", s(&o2)]);
        assert!(!o.status.success() && stderr(&o).contains(want), "{name}: {}", stderr(&o));
        assert!(!o2.exists(), "{name}: nothing written");
    }
}
