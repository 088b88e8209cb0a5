//! Bad input, round 6 (30 Nov 2026): what rounds 4–5 left noted, each now refused or fixed — a render folder
//! whose mask file was replaced (reconstructed with the wrong mask, silently), `reconstruct
//! --transport-memory-gb` with a model operator (accepted and ignored), `study` options that none of its
//! solvers takes (`--iterations` with `--solvers unrolled`: ignored by every cell), `cuda:01` (read as
//! `cuda:1`; torch refuses it), and `info`'s flat radius printed as `inf`. Each case runs the real binary:
//! the exit code, a message naming the problem, nothing written.

use crate::cli_run::{ok_cli as ok, refused_cli as refused, run_cli as run};

/// `render.json` records the SHA-256 of the mask's 16-bit codes (`mask_png_sha256`, [`Mask::png_sha256`]);
/// `reconstruct` recomputes it from the mask file it reads and refuses another mask, naming the file and both
/// digests. The render's own mask (and an 8-bit PNG of the same binary mask) pass; a record without the field
/// (an older render) is read as before.
///
/// [`Mask::png_sha256`]: diffcassi::render::Mask::png_sha256
#[test]
fn a_replaced_mask_is_refused_by_reconstruct() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let base = ["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1"];
    let mut a = base.to_vec();
    a.extend(["--mask-seed", "1", "--out", "r"]);
    ok(dir, &a);
    let mut b = base.to_vec();
    b.extend(["--mask-seed", "2", "--out", "other"]);
    ok(dir, &b);
    let json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("r/render.json")).unwrap()).unwrap();
    let recorded = json["mask_png_sha256"].as_str().expect("render.json records mask_png_sha256").to_string();
    let mask = diffcassi::render::Mask::load(&dir.join("r/mask.png")).unwrap();
    assert_eq!(mask.png_sha256(), recorded, "the mask read back from mask.png has the recorded digest");
    ok(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x0"]);
    // The same binary mask as an 8-bit PNG reads the same codes (k/255 → 257·k).
    let bytes8: Vec<u8> = mask.values.iter().map(|&v| (v * 255.0).round() as u8).collect();
    image::GrayImage::from_raw(8, 8, bytes8).unwrap().save(dir.join("r/mask.png")).unwrap();
    ok(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x1"]);
    // Another render's mask: refused, nothing written.
    std::fs::copy(dir.join("other/mask.png"), dir.join("r/mask.png")).unwrap();
    refused(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x2"], &["mask.png", "not the mask this render used", &recorded]);
    assert!(!dir.join("x2").exists());
    // An older record (no digest) is read as before.
    let mut old = json.clone();
    old.as_object_mut().unwrap().remove("mask_png_sha256");
    std::fs::write(dir.join("r/render.json"), serde_json::to_string_pretty(&old).unwrap()).unwrap();
    ok(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x3"]);
    // A digest that is not a string is named.
    let mut bad = json;
    bad["mask_png_sha256"] = serde_json::json!(7);
    std::fs::write(dir.join("r/render.json"), serde_json::to_string_pretty(&bad).unwrap()).unwrap();
    refused(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--iterations", "1", "--out", "x4"], &["mask_png_sha256", "not a string"]);
}

/// `--transport-memory-gb` is the exact operator's (its traced transport): with `shift` or `mapping` it is
/// refused, as `--operator-seed` and `--operator-rays` are; with `exact` it is taken.
#[test]
fn the_transport_budget_is_the_exact_operators() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1", "--out", "r"]);
    for op in ["shift", "mapping"] {
        refused(dir, &["reconstruct", "--from", "r", "--operator", op, "--transport-memory-gb", "2", "--out", "x"], &["--transport-memory-gb 2", "exact operator only", op]);
        assert!(!dir.join("x").exists());
    }
    ok(dir, &["reconstruct", "--from", "r", "--operator", "exact", "--transport-memory-gb", "0", "--iterations", "1", "--out", "x"]);
    refused(dir, &["reconstruct", "--from", "r", "--transport-memory-gb", "nan", "--out", "y"], &["--transport-memory-gb NaN", "finite"]);
}

/// A `study` option no solver of `--solvers` takes is refused before any work: each cell drops the options of
/// other solvers, so `--iterations` with `--solvers unrolled` (whose stages are fixed) was ignored by every
/// cell, and `--sigma-max` with TV solvers likewise. With one solver that takes it, it is accepted (the
/// others drop it, as documented).
#[test]
fn study_refuses_options_none_of_its_solvers_takes() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let tiny = ["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--planes", "4", "--rays", "1", "--operators", "shift"];
    for (extra, needles) in [
        (vec!["--solvers", "unrolled", "--iterations", "5"], vec!["--iterations", "the iterative solvers", "unrolled"]),
        (vec!["--solvers", "unrolled", "--tv-weight", "0.2"], vec!["--tv-weight", "--solvers `unrolled` has none of them"]),
        (vec!["--solvers", "gap-tv,admm-tv", "--sigma-max", "0.2"], vec!["--sigma-max", "pnp-gap and pnp-admm only"]),
        (vec!["--solvers", "gap-tv", "--tv-warmup", "3"], vec!["--tv-warmup", "pnp-gap and pnp-admm only"]),
    ] {
        let mut a = tiny.to_vec();
        a.extend(extra.iter().copied());
        a.extend(["--out", "st"]);
        refused(dir, &a, &needles);
        assert!(!dir.join("st").exists(), "{extra:?}");
    }
}

/// `--device cuda:01` is refused as torch refuses it (`Invalid device string`); the message says why.
#[test]
fn device_ordinals_take_no_leading_zero() {
    let d = tempfile::tempdir().unwrap();
    for dev in ["cuda:01", "cuda:00"] {
        // A usage error (exit 2, as clap's bad values), naming the value.
        let (code, out) = run(d.path(), &["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--device", dev, "--out", "r"]);
        assert_eq!(code, Some(2), "{out}");
        assert!(out.contains(dev) && out.contains("no leading zero") && !out.contains("panicked"), "{out}");
        assert!(!d.path().join("r").exists());
    }
}

/// `info` writes an infinite radius or thickness as OpticStudio's Lens Data Editor does, `Infinity` (it printed
/// `inf`).
#[test]
fn info_writes_infinity_as_opticstudio_does() {
    let d = tempfile::tempdir().unwrap();
    let out = ok(d.path(), &["info", "--preset", "sp"]);
    let table: Vec<&str> = out.lines().filter(|l| l.contains("Standard")).collect();
    assert!(!table.is_empty(), "{out}");
    assert!(table.iter().any(|l| l.contains("Infinity")), "{out}");
    assert!(table.iter().all(|l| !l.split_whitespace().any(|w| w == "inf")), "{out}");
}

// ------------------------------------------------------------------ the round-6 prober's findings

/// A `.zmx` whose coded-mask tag was edited out of its exact form (`pitch 10um`) is refused naming the surface
/// and the form: read as a plain comment it turned the dual-disperser system into a maskless one (exit 0,
/// transmission 1). The exact tag still reads back.
#[test]
fn a_mistyped_coded_mask_tag_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["export-spec", "--preset", "ddsp", "--format", "zmx", "--out", "dd.zmx"]);
    let text = std::fs::read_to_string(dir.join("dd.zmx")).unwrap();
    assert!(text.contains("CODED MASK pitch 10 um, nearest sampling"), "the export writes the tag");
    ok(dir, &["info", "--system", "dd.zmx"]);
    for (from, to) in [
        ("pitch 10 um", "pitch 10um"),
        ("pitch 10 um", "pitch 10 mm"),
        ("nearest sampling", "cubic sampling"),
        ("CODED MASK pitch", "CODED MASK PITCH"),
        ("CODED MASK pitch", "CODED  MASK pitch"),
        ("CODED MASK pitch", "CODED_MASK pitch"),
        ("CODED MASK pitch", "MASK pitch"),
    ] {
        std::fs::write(dir.join("bad.zmx"), text.replace(from, to)).unwrap();
        refused(dir, &["render", "--system", "bad.zmx", "--scene-size", "8", "--planes", "2", "--rays", "1", "--out", "r"], &["COMM", "CODED MASK pitch P um, nearest sampling"]);
        assert!(!dir.join("r").exists(), "{to}");
    }
    // A comment that only mentions a mask stays a comment (the system then has no mask surface).
    let tag = text.lines().find(|l| l.contains("CODED MASK pitch")).unwrap().trim().to_string();
    for plain in ["COMM [coded mask plane]", "COMM plane [CODED MASK]", "COMM see the coded mask pitch note"] {
        std::fs::write(dir.join("plain.zmx"), text.replace(&tag, plain)).unwrap();
        ok(dir, &["info", "--system", "plain.zmx"]);
    }
}

/// `--discrepancy` beyond 1000 is refused (τ·δ/‖y‖ overflowed: reconstruct.json wrote `null`, exit 0).
#[test]
fn a_huge_discrepancy_factor_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1", "--out", "r"]);
    refused(dir, &["reconstruct", "--from", "r", "--discrepancy", "1e308", "--out", "x"], &["--discrepancy 1e308", "[0, 1000]"]);
    assert!(!dir.join("x").exists());
    ok(dir, &["reconstruct", "--from", "r", "--operator", "shift", "--discrepancy", "1000", "--iterations", "2", "--out", "x"]);
}

/// The `ghosts` analysis refuses a dual-disperser system as `render --ghosts` does (it analysed the coded mask
/// as air and printed energies, exit 0).
#[test]
fn ghosts_refuse_a_mask_surface() {
    let d = tempfile::tempdir().unwrap();
    refused(d.path(), &["ghosts", "--preset", "ddsp", "--order", "2", "--rings", "1", "--extended-grid", "1", "--json", "g.json"], &["coded mask on surface", "the ghost analysis does not model a mask surface"]);
    assert!(!d.path().join("g.json").exists());
}

/// `reconstruct` rebuilds an f32 render's operator in f32: with `--operator-seed same` it is the oracle (the
/// truth's residual ‖y − Φx‖/‖y‖ at f32 rounding, ~1e-7), where an f64 operator left 2.9e-4 while recording
/// `"oracle": true`.
#[test]
fn an_f32_render_is_reconstructed_with_an_f32_operator() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["make-scene", "--synthetic", "1", "--size", "16", "--bands", "450:650:6", "--out", "a.npy"]);
    let common = ["render", "--preset", "sp", "--scene", "a.npy", "--scene-size", "16", "--bands", "450:650:6", "--planes", "6", "--rays", "2"];
    for (precision, limit) in [("f64", 1e-6), ("f32", 1e-5)] {
        let out = format!("r{precision}");
        let mut a = common.to_vec();
        a.extend(["--precision", precision, "--out", &out]);
        ok(dir, &a);
        let rec = format!("x{precision}");
        ok(dir, &["reconstruct", "--from", &out, "--operator-seed", "same", "--iterations", "2", "--truth", "a.npy", "--out", &rec]);
        let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(&rec).join("reconstruct.json")).unwrap()).unwrap();
        let r = j["stopping"]["truth_residual"].as_f64().unwrap_or_else(|| panic!("{j}"));
        assert!(r < limit, "{precision}: the oracle's truth residual {r:e} ≥ {limit:e}");
    }
}

/// A resumed `render-dataset` renders again a scene whose file changed since (it was kept, and `dataset-status
/// --scenes` said done); the same bytes written again (a touched file) are still done.
#[test]
fn a_changed_scene_is_not_kept_by_a_resumed_dataset() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir(dir.join("sc")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "1", "--size", "8", "--bands", "450:650:4", "--out", "sc/a.npy"]);
    let ds = ["render-dataset", "--scenes", "sc", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--bands", "450:650:4", "--out", "ds"];
    ok(dir, &ds);
    let first = std::fs::read(dir.join("ds/a/acquisition.exr")).unwrap();
    // Touched: the same bytes, another modification time.
    let bytes = std::fs::read(dir.join("sc/a.npy")).unwrap();
    std::thread::sleep(std::time::Duration::from_millis(20));
    std::fs::write(dir.join("sc/a.npy"), &bytes).unwrap();
    let out = ok(dir, &ds);
    assert!(out.contains("\"skipped\""), "{out}");
    ok(dir, &["dataset-status", "ds", "--scenes", "sc"]);
    // Replaced: another scene of the same shape.
    std::fs::remove_file(dir.join("sc/a.npy")).unwrap();
    std::fs::remove_file(dir.join("sc/a_rgb.png")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "2", "--size", "8", "--bands", "450:650:4", "--out", "sc/a.npy"]);
    refused(dir, &["dataset-status", "ds", "--scenes", "sc"], &["a.npy changed since it was rendered"]);
    refused(dir, &ds, &["a.npy changed since it was rendered", "--on-mismatch rerender"]);
    let mut again = ds.to_vec();
    again.extend(["--on-mismatch", "rerender"]);
    ok(dir, &again);
    assert_ne!(std::fs::read(dir.join("ds/a/acquisition.exr")).unwrap(), first, "the new scene was rendered");
    ok(dir, &["dataset-status", "ds", "--scenes", "sc"]);
    // With --scene-wavelengths the list beside the cube is not read, so a change to it is no change of the scene.
    let mut given = ds[..ds.len() - 2].to_vec();
    given.extend(["--scene-wavelengths", "450:650:4", "--out", "ds2"]);
    ok(dir, &given);
    std::fs::write(dir.join("sc/a_wavelengths_nm.npy"), std::fs::read(dir.join("sc/a_wavelengths_nm.npy")).unwrap().iter().rev().copied().collect::<Vec<u8>>()).unwrap();
    let out = ok(dir, &given);
    assert!(out.contains("\"skipped\""), "{out}");
    // A per-band PNG folder: its .png files are the scene, a stray file beside them is not.
    std::fs::create_dir(dir.join("pf")).unwrap();
    std::fs::create_dir(dir.join("pf/c")).unwrap();
    for (k, w) in ["500", "550", "600"].iter().enumerate() {
        image::GrayImage::from_pixel(8, 8, image::Luma([60 + 40 * k as u8])).save(dir.join(format!("pf/c/band_{w}.png"))).unwrap();
    }
    std::fs::write(dir.join("pf/c/wavelengths.txt"), "500\n550\n600\n").unwrap();
    let pf = ["render-dataset", "--scenes", "pf", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--bands", "500:600:3", "--out", "ds3"];
    ok(dir, &pf);
    std::fs::write(dir.join("pf/c/.DS_Store"), "x").unwrap();
    let out = ok(dir, &pf);
    assert!(out.contains("\"skipped\""), "{out}");
    image::GrayImage::from_pixel(8, 8, image::Luma([7])).save(dir.join("pf/c/band_550.png")).unwrap();
    refused(dir, &pf, &["scene input: band_550.png changed since it was rendered", "from scene files that have changed since"]);
}

/// `make-scene --out x.NPY` beside another cube `x.npy` is refused: the two share `x_wavelengths_nm.npy` and
/// `x_rgb.png` (the other cube then read this one's wavelengths).
#[test]
fn make_scene_refuses_a_cube_sharing_another_ones_sidecars() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    ok(dir, &["make-scene", "--synthetic", "1", "--size", "8", "--bands", "450:650:3", "--out", "x.npy"]);
    let list = std::fs::read(dir.join("x_wavelengths_nm.npy")).unwrap();
    for other in ["x.NPY", "x.exr"] {
        refused(dir, &["make-scene", "--synthetic", "2", "--size", "8", "--bands", "500:600:3", "--out", other], &["x.npy", "same stem"]);
        assert!(!dir.join(other).exists(), "{other}");
    }
    assert_eq!(std::fs::read(dir.join("x_wavelengths_nm.npy")).unwrap(), list);
    // Writing x.npy again is replacing it (and its own sidecars); a folder of the same stem is no cube.
    ok(dir, &["make-scene", "--synthetic", "2", "--size", "8", "--bands", "500:600:3", "--out", "x.npy"]);
    std::fs::create_dir(dir.join("w.npy")).unwrap();
    ok(dir, &["make-scene", "--synthetic", "2", "--size", "8", "--bands", "500:600:3", "--out", "w.exr"]);
}

/// Options that change nothing are refused: `study --mask` with `--opening`/`--mask-seed`, `study --fit` with
/// `--synthetic`, `reconstruct --noise-estimate` with a model operator (the record said `model` whatever was
/// asked), `--equivariant-seed` without equivariant PnP, `render --full-well-e` with `--electrons-per-unit` and no
/// ADC (recorded, unused), `study --noise-estimate` without an exact operator.
#[test]
fn options_that_change_nothing_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    diffcassi::io::write_npy_f32(dir.join("m.npy"), &[16, 16], &vec![1.0f32; 256]).unwrap();
    let study = ["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--planes", "4", "--rays", "1", "--solvers", "gap-tv"];
    for (extra, needle) in [
        (vec!["--operators", "shift", "--mask", "m.npy", "--opening", "0.3"], "--opening"),
        (vec!["--operators", "shift", "--mask", "m.npy", "--mask-seed", "7"], "--mask-seed"),
        (vec!["--operators", "shift", "--fit", "crop"], "--synthetic"),
        (vec!["--operators", "shift,mapping", "--noise-estimate", "model"], "--noise-estimate model: applies to the exact operator only"),
    ] {
        let mut a = study.to_vec();
        a.extend(extra.iter().copied());
        a.extend(["--out", "st"]);
        let (code, out) = run(dir, &a);
        assert_ne!(code, Some(0), "{extra:?}: {out}");
        assert!(out.contains(needle) && !out.contains("panicked"), "{extra:?}: {out}");
        assert!(!dir.join("st").exists(), "{extra:?}");
    }
    ok(dir, &["render", "--preset", "sp", "--scene-size", "8", "--planes", "4", "--rays", "1", "--out", "r"]);
    refused(dir, &["reconstruct", "--from", "r", "--operator", "mapping", "--noise-estimate", "spread", "--out", "x"], &["--noise-estimate spread", "exact operator only", "mapping"]);
    refused(dir, &["reconstruct", "--from", "r", "--solver", "pnp-gap", "--equivariant-seed", "3", "--out", "x"], &["--equivariant-seed 3", "give --equivariant too"]);
    assert!(!dir.join("x").exists());
    let noise = ["render", "--preset", "sp", "--scene-size", "8", "--planes", "2", "--rays", "1", "--noise", "shot", "--electrons-per-unit", "500"];
    let mut a = noise.to_vec();
    a.extend(["--full-well-e", "1", "--out", "n"]);
    refused(dir, &a, &["--full-well-e 1", "no effect"]);
    let mut b = noise.to_vec();
    b.extend(["--out", "n"]);
    ok(dir, &b);
}

/// Refused before any work (they failed after seconds of calibration, a printed table header, or renders):
/// `render --tolerance-um --kernel scalar`, `bench-render --parts` empty or repeated, `study --opening 0`.
#[test]
fn late_failures_come_first() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let t = std::time::Instant::now();
    refused(dir, &["render", "--preset", "sp", "--scene-size", "8", "--tolerance-um", "1", "--kernel", "scalar", "--out", "r"], &["--tolerance-um 1", "--kernel scalar"]);
    assert!(t.elapsed().as_secs_f64() < 5.0, "refused only after the calibration: {:?}", t.elapsed());
    for parts in ["", "mapping,mapping"] {
        let (code, out) = run(dir, &["bench-render", "--scene-size", "8", "--planes", "2", "--rays", "1", "--parts", parts]);
        assert_eq!(code, Some(1), "{out}");
        assert!(out.contains("--parts") && !out.contains("| what |"), "{parts:?}: {out}");
    }
    refused(dir, &["study", "--synthetic", "1", "--scene-size", "8", "--presets", "sp", "--planes", "2", "--rays", "1", "--opening", "0", "--operators", "shift", "--out", "st"], &["--opening 0", "closed mask"]);
    assert!(!dir.join("st/renders").exists());
    // The unrolled network's bands, as the PnP denoiser's, before any render.
    for solvers in ["gap-tv,unrolled", "gap-tv,pnp-gap"] {
        refused(dir, &["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--planes", "3", "--rays", "1", "--bands", "500:600:3", "--operators", "shift", "--solvers", solvers, "--out", "st"], &["trained for 28 bands", "--bands `500:600:3` gives 3"]);
        assert!(!dir.join("st/renders").exists(), "{solvers}");
    }
}

/// `evaluate` says when the field's [0, 1] clamp makes PSNR and SSIM meaningless (a truth beyond 1), on stderr
/// and in its JSON `warnings`; within [0, 1] it says nothing.
#[test]
fn evaluate_warns_where_the_clamp_makes_psnr_meaningless() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let ws = vec![500.0, 600.0];
    for (name, scale) in [("unit", 0.5f32), ("big", 100.0)] {
        let cube = diffcassi::scene::SpectralCube::new(12, 12, ws.clone(), (0..288).map(|i| scale * (1.0 + (i % 8) as f32) / 8.0).collect(), name).unwrap();
        diffcassi::scene::save_npy(&cube, &dir.join(format!("{name}.npy"))).unwrap();
        let out = ok(dir, &["evaluate", "--truth", &format!("{name}.npy"), "--estimate", &format!("{name}.npy"), "--json", &format!("{name}.json")]);
        let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join(format!("{name}.json"))).unwrap()).unwrap();
        let warned = out.contains("warning: the truth's maximum is 100 > 1");
        assert_eq!(warned, name == "big", "{out}");
        assert_eq!(j["warnings"].as_array().map_or(0, |w| w.len()), usize::from(name == "big"), "{j}");
    }
}

/// The analysis and design commands (a held-out battery of them, round 6): `calibrate --free glass_nd:…
/// --system-out` wrote the nominal system; `calibrate` ignored a spec's own catalogues (so `design amici`'s
/// output could not be calibrated); it read a system at infinity's setup fields as angles; `design amici
/// --final-thickness-weight 1.7e308` wrote `null`; `mapping --npy a.NPY` replaced `a.npy`'s companions;
/// `dispersion` of an unsorted list reported the wrong pair's spread; `distortion --half-width-mm 1e-12` reported
/// noise as 100 % distortion; `--pupil grid:2` traced no ray.
#[test]
fn analysis_and_design_commands_refuse_what_they_got_wrong() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    refused(dir, &["calibrate", "--from", "sp", "--observed", "msp", "--free", "glass_nd:N-BK7", "--setup", "small", "--system-out", "c.toml"], &["--system-out c.toml", "glass_nd"]);
    assert!(!dir.join("c.toml").exists());
    ok(dir, &["design", "amici", "--iterations", "3", "--system-out", "d.toml"]);
    let out = ok(dir, &["calibrate", "--from", "d.toml", "--observed", "d.toml", "--free", "s3.tilt_y_deg", "--setup", "small"]);
    assert!(out.contains("residual"), "{out}");
    let dg = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/fixtures/zmx/double_gauss_US583336.zmx");
    refused(dir, &["calibrate", "--from", dg, "--observed", dg, "--free", "s2.radius_mm", "--setup", "small"], &["object is at infinity", "finite object"]);
    refused(dir, &["design", "amici", "--iterations", "3", "--final-thickness-weight", "1.7e308", "--report", "dd.json"], &["--final-thickness-weight 1.7e308", "[0, 1e6]"]);
    assert!(!dir.join("dd.json").exists());
    ok(dir, &["mapping", "--preset", "sp", "--height", "2", "--width", "2", "--wavelengths-nm", "450:650:3", "--npy", "a.npy"]);
    let list = std::fs::read(dir.join("a_wavelengths_nm.npy")).unwrap();
    refused(dir, &["mapping", "--preset", "sp", "--height", "2", "--width", "2", "--wavelengths-nm", "520", "--npy", "a.NPY"], &["a.npy", "same stem"]);
    refused(dir, &["mapping", "--preset", "sp", "--height", "2", "--width", "2", "--wavelengths-nm", "520", "--npy", "a_valid.npy"], &["a_valid.npy is the companion (_valid.npy) of"]);
    assert_eq!(std::fs::read(dir.join("a_wavelengths_nm.npy")).unwrap(), list);
    refused(dir, &["dispersion", "--preset", "sp", "--wavelengths-nm", "450,650,520"], &["increasing wavelengths", "650 then 520"]);
    refused(dir, &["distortion", "--preset", "sp", "--grid", "3", "--half-width-mm", "1e-12"], &["--half-width-mm 1e-12", "[1e-3"]);
    refused(dir, &["spot", "--preset", "sp", "--wavelength-nm", "520", "--field-mm", "0,0", "--pupil", "grid:2"], &["grid:2 has no point inside the pupil"]);
}
