//! Bad input, round 3 (issue 39, the command line): `bench nonsequential`/`bench tradeoff` outputs checked
//! against their inputs and their counts, budgets and ignored options refused; `ghosts` under the ray and
//! memory budgets (an estimate before the analysis) and its outputs staged and announced together; render's
//! budget counting the detector; inputs that are not regular files (a FIFO, `/dev/zero`, a folder);
//! coatings, `.zmx` files, meshes and negative numbers. Each CLI case runs the real binary: exit code, a
//! message naming the option/field/value, nothing written, no panic, done within 60 s. Tiny sizes throughout.
use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

/// Run `args` in `cwd` with a 60 s limit; (exit code, stdout + stderr, seconds).
fn run_in(cwd: &Path, args: &[String]) -> (Option<i32>, String, f64) {
    let t = Instant::now();
    let mut child = bin().args(args).current_dir(cwd).stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    let mut out = child.stdout.take().unwrap();
    let mut err = child.stderr.take().unwrap();
    let reader = std::thread::spawn(move || {
        use std::io::Read;
        let mut s = String::new();
        let _ = out.read_to_string(&mut s);
        s
    });
    let status = common::wait_with_limit(&mut child, t, Duration::from_secs(60));
    let mut e = String::new();
    use std::io::Read;
    let _ = err.read_to_string(&mut e);
    let o = reader.join().unwrap();
    (status.and_then(|s| s.code()), format!("{o}{e}"), t.elapsed().as_secs_f64())
}

fn args(text: &str, subst: &[(&str, String)]) -> Vec<String> {
    text.split_whitespace()
        .map(|a| {
            let mut a = a.to_string();
            for (k, v) in subst {
                a = a.replace(k, v);
            }
            a
        })
        .collect()
}

fn listing(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    v.sort();
    v
}

/// The fixtures: SP exported as TOML (`sp.toml`), its Zemax prescription CSV (`sp.csv`), SP as `.zmx`.
struct Fixtures {
    _dir: tempfile::TempDir,
    dir: PathBuf,
}

fn fixtures() -> Fixtures {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().to_path_buf();
    for (out, extra) in [("sp.toml", &[][..]), ("sp.zmx", &["--format", "zmx"][..])] {
        let mut a = vec!["export-spec".to_string(), "--preset".into(), "sp".into(), "--out".into(), dir.join(out).display().to_string()];
        a.extend(extra.iter().map(|s| s.to_string()));
        let (code, text, _) = run_in(&dir, &a);
        assert_eq!(code, Some(0), "{text}");
    }
    std::fs::copy(Path::new(env!("CARGO_MANIFEST_DIR")).join("data/presets/SP_single_prism_aligned.prescription.csv"), dir.join("sp.csv")).unwrap();
    Fixtures { _dir: d, dir }
}

struct Case {
    args: &'static str,
    code: i32,
    /// Every one of these must appear in the output.
    says: &'static [&'static str],
}

/// `{out}` is a fresh path in the empty folder the case runs in; `{fx}` the fixtures folder (sp.toml, sp.csv,
/// sp.zmx), whose files must come out unchanged.
const CASES: &[Case] = &[
    // bench nonsequential: outputs never inputs; counts, budgets and ignored options.
    Case { args: "bench nonsequential --quick --system {fx}/sp.toml --csv {fx}/sp.toml", code: 1, says: &["--csv", "sp.toml", ".csv"] },
    Case { args: "bench nonsequential --quick --system {fx}/sp.csv --csv {fx}/sp.csv", code: 1, says: &["--csv is the input --system"] },
    Case { args: "bench nonsequential --rays 1000000000000", code: 1, says: &["--rays 1000000000000", "--max-memory-gb"] },
    Case { args: "bench nonsequential --repeat 1000000000", code: 1, says: &["--repeat 1000000000", "1..=1000"] },
    Case { args: "bench nonsequential --quick --backends embree-user", code: 1, says: &["--backends embree-user"] },
    Case { args: "bench nonsequential --quick --backends bogus", code: 1, says: &["--backends bogus"] },
    Case { args: "bench nonsequential --quick --wavelengths 100000000", code: 1, says: &["--wavelengths 100000000", "1..=100000"] },
    Case { args: "bench nonsequential --quick --rays 10", code: 1, says: &["--quick", "--rays 10"] },
    Case { args: "--max-rays 1000 bench nonsequential --quick", code: 1, says: &["--quick", "--max-rays"] },
    Case { args: "bench nonsequential --png {out}.png", code: 1, says: &["--png", "tradeoff"] },
    // bench tradeoff: the same rules.
    Case { args: "bench tradeoff --quick --rays 5", code: 1, says: &["--rays 5"] },
    Case { args: "bench tradeoff --quick --backends analytic", code: 1, says: &["--backends analytic"] },
    Case { args: "bench tradeoff --quick --repeat 0", code: 1, says: &["--repeat 0", "1..=1000"] },
    Case { args: "bench tradeoff --quick --wavelengths 0", code: 1, says: &["--wavelengths 0"] },
    Case { args: "bench tradeoff --quick --csv {fx}/sp.toml", code: 1, says: &["--csv", "sp.toml", ".csv"] },
    Case { args: "bench tradeoff --quick --csv {out}.csv --png {fx}", code: 1, says: &["--png", ".png"] },
    Case { args: "--max-rays 1000 bench tradeoff --quick", code: 1, says: &["bench tradeoff --quick", "--max-rays"] },
    Case { args: "bench --backends bogus", code: 1, says: &["bogus"] },
    Case { args: "bench --repeat 100000", code: 1, says: &["--repeat 100000", "1..=1000"] },
    // ghosts: the budgets from an estimate (trees × paths per tree), before the analysis.
    Case { args: "--max-rays 1000 ghosts --preset sp --csv {out}.csv", code: 1, says: &["--rings 6", "--extended-grid 5", "--max-rays"] },
    Case { args: "--max-memory-gb 0.001 ghosts --preset ap --order 4 --rings 64 --extended-grid 64 --csv {out}.csv", code: 1, says: &["--order 4", "--rings 64", "--max-memory-gb"] },
    Case { args: "ghosts --preset sp --threshold -1e-7 --csv {out}.csv", code: 1, says: &["--threshold -1e-7", "[0, 1)"] },
    Case { args: "ghosts --preset sp --rings 0 --csv {out}.csv", code: 1, says: &["--rings 0", "1..=64"] },
    Case { args: "ghosts --preset sp --extended-grid 65 --csv {out}.csv", code: 1, says: &["--extended-grid 65", "1..=64"] },
    // Negative numbers and unit suffixes reach the option's own check.
    Case { args: "render --preset sp --scene-size 8 --planes 4 --ghosts 2 --coating -1=R0.1 --out {out}", code: 2, says: &["--coating", "-1=R0.1", "target `-1`"] },
    Case { args: "render --preset sp --scene-size 8 --planes 4 --ghosts 2 --coating 3=mgf2@550nm --out {out}", code: 2, says: &["--coating", "`550nm` is not a number of nm"] },
    Case { args: "render --preset sp --scene-size 8 --planes 4 --ghosts 2 --coating 0=R0.1 --out {out}", code: 1, says: &["--coating", "surface 0 is the object surface"] },
    // mapping --device: a name it knows, not beside --backend/--tolerance-um, and (CI has no GPU) cuda refused
    // with what is missing.
    Case { args: "mapping --preset sp --height 4 --width 4 --device tpu --npy {out}.npy", code: 2, says: &["'tpu'", "--device", "cpu, cuda or cuda:N"] },
    Case { args: "mapping --preset sp --height 4 --width 4 --device cpu-twin --backend analytic --npy {out}.npy", code: 1, says: &["--device cpu-twin", "--backend"] },
    Case { args: "mapping --preset sp --height 4 --width 4 --device cuda --tolerance-um 1 --npy {out}.npy", code: 1, says: &["--device cuda", "--tolerance-um"] },
    // Inputs are regular files of bounded size.
    Case { args: "import-zmx /dev/zero --out {out}.toml", code: 1, says: &["/dev/zero", "character device"] },
    Case { args: "info --system {fx}", code: 1, says: &["is a folder, not a regular file"] },
    Case { args: "import-zmx {fx}/sp.zmx --glass-dir {fx}/nowhere --out {out}.toml", code: 1, says: &["--glass-dir", "nowhere", "no such folder"] },
    Case { args: "import-zmx {fx}/sp.zmx --glass-dir {fx}/sp.toml --out {out}.toml", code: 1, says: &["--glass-dir", "sp.toml", "is a file"] },
];

/// Every case: the exit code, a message naming the option/field and value, no panic, nothing written into
/// the empty folder it runs in, the fixtures unchanged.
#[test]
fn bad_invocations_are_refused_before_any_work() {
    let fx = fixtures();
    let before: Vec<(String, Vec<u8>)> = listing(&fx.dir).into_iter().map(|n| (n.clone(), std::fs::read(fx.dir.join(&n)).unwrap())).collect();
    let mut failures = Vec::new();
    for case in CASES {
        if case.args.contains("nonsequential") && !cfg!(feature = "embree") {
            continue; // `bench nonsequential` needs Embree
        }
        let dir = tempfile::tempdir().unwrap();
        let subst = [("{out}", dir.path().join("result").display().to_string()), ("{fx}", fx.dir.display().to_string())];
        let a = args(case.args, &subst);
        let (code, text, secs) = run_in(dir.path(), &a);
        let written = listing(dir.path());
        let missing: Vec<&&str> = case.says.iter().filter(|s| !text.contains(**s)).collect();
        if code != Some(case.code) || !missing.is_empty() || !written.is_empty() || text.contains("panicked") || text.contains("wrote ") {
            failures.push(format!("`{}`: exit {code:?} (want {}), missing {missing:?}, wrote {written:?}, {secs:.1} s, output: {text}", case.args, case.code));
        }
    }
    let after: Vec<(String, Vec<u8>)> = listing(&fx.dir).into_iter().map(|n| (n.clone(), std::fs::read(fx.dir.join(&n)).unwrap())).collect();
    assert!(before == after, "the fixtures changed");
    assert!(failures.is_empty(), "{} of {} cases failed:\n{}", failures.len(), CASES.len(), failures.join("\n"));
}

/// `import-zmx` on a named pipe returns at once (it used to block forever waiting for a writer).
#[test]
fn a_fifo_input_is_refused_at_once() {
    let d = tempfile::tempdir().unwrap();
    let fifo = d.path().join("lens.zmx");
    let c = std::ffi::CString::new(fifo.to_str().unwrap()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
    for a in [vec!["import-zmx".to_string(), fifo.display().to_string(), "--out".into(), "x.toml".into()], vec!["info".into(), "--system".into(), fifo.display().to_string()]] {
        let (code, text, secs) = run_in(d.path(), &a);
        assert_eq!(code, Some(1), "{a:?}: {text}");
        assert!(text.contains("lens.zmx") && text.contains("named pipe"), "{text}");
        assert!(secs < 20.0, "{secs} s");
    }
    assert_eq!(listing(d.path()), vec!["lens.zmx"]);
}

/// `ghosts --csv g.csv --json ro/g.json` where `ro` cannot hold files: refused before the analysis, nothing
/// written or announced (it printed "wrote g.csv" and then failed).
#[test]
fn ghosts_outputs_are_checked_and_committed_together() {
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("ro"), "a file, not a folder").unwrap();
    let a = args("ghosts --preset sp --rings 1 --extended-grid 1 --csv g.csv --json ro/g.json", &[]);
    let (code, text, _) = run_in(d.path(), &a);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("ro/g.json") && text.contains("--json") && !text.contains("wrote"), "{text}");
    assert!(!text.contains("ghosts of"), "the analysis ran before the refusal: {text}");
    assert_eq!(listing(d.path()), vec!["ro"]);
    // The same set written: both announced after both are in place.
    std::fs::remove_file(d.path().join("ro")).unwrap();
    let (code, text, _) = run_in(d.path(), &a);
    assert_eq!(code, Some(0), "{text}");
    assert!(text.contains("wrote g.csv") && text.contains("wrote ro/g.json"), "{text}");
}

/// `bench tradeoff --csv --png`: one staged set, both announced once both are in place.
#[test]
fn tradeoff_outputs_are_one_set() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("t.png")).unwrap();
    let a = args("bench tradeoff --quick --wavelengths 1 --repeat 1 --csv t.csv --png t.png", &[]);
    let (code, text, _) = run_in(d.path(), &a);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("--png") && !text.contains("wrote"), "{text}");
    assert_eq!(listing(d.path()), vec!["t.png"]);
}

fn edit_spec(fx: &Fixtures, name: &str, edit: impl Fn(&str) -> String) -> PathBuf {
    let t = std::fs::read_to_string(fx.dir.join("sp.toml")).unwrap();
    let p = fx.dir.join(name);
    std::fs::write(&p, edit(&t)).unwrap();
    p
}

/// Insert `line` into the `k`-th `[[surfaces]]` table (0 = the object).
fn in_surface(t: &str, k: usize, line: &str) -> String {
    let at = t.match_indices("[[surfaces]]").nth(k).unwrap().0 + "[[surfaces]]\n".len();
    format!("{}{line}\n{}", &t[..at], &t[at..])
}

/// Spec checks: a coating where it would do nothing (object, image surface), an absorbing mechanics surface
/// with a reflectance, a mesh scale of 1e-300; `.zmx`: `CURV 1e308`, `MODE NSC` with `--ignore-unsupported`,
/// and the export of a coated spec to `.zmx`.
#[test]
fn specs_and_zmx_name_the_field_and_value() {
    let fx = fixtures();
    let surfaces = std::fs::read_to_string(fx.dir.join("sp.toml")).unwrap().matches("[[surfaces]]").count();
    let image = surfaces - 1;
    let v = |x: &[&str]| x.iter().map(|s| s.to_string()).collect::<Vec<String>>();
    let cases: Vec<(PathBuf, Vec<String>)> = vec![
        (edit_spec(&fx, "c0.toml", |t| in_surface(t, 0, "coating = { reflectance = 0.1 }")), v(&["surface 0", "coating", "the object surface"])),
        (edit_spec(&fx, "ci.toml", |t| in_surface(t, image, "coating = { reflectance = 0.1 }")), v(&[&format!("surface {image} is"), "coating", "the image surface"])),
        (edit_spec(&fx, "abs.toml", |t| format!("{t}\n[mechanics]\nsurface = {{ model = \"absorbing\", reflectance = 0.5 }}\n")), v(&["absorbing", "reflectance", "0.5"])),
        (
            edit_spec(&fx, "scale.toml", |t| format!("{t}\n[mechanics]\ngenerate = false\n[[mechanics.meshes]]\npath = \"cube.obj\"\nscale = 1e-300\n")),
            v(&["mechanics.meshes[0].scale = 1e-300", "1e-6 ≤ |scale|"]),
        ),
    ];
    for (spec, says) in &cases {
        let (code, text, _) = run_in(&fx.dir, &["info".into(), "--system".into(), spec.display().to_string()]);
        assert_eq!(code, Some(1), "{}: {text}", spec.display());
        for s in says {
            assert!(text.contains(s.as_str()), "{}: `{s}` not in {text}", spec.display());
        }
    }
    // .zmx: an absurd curvature, a non-sequential file (even with --ignore-unsupported).
    let zmx = std::fs::read_to_string(fx.dir.join("sp.zmx")).unwrap();
    let k = zmx.find("CURV ").expect("a CURV record");
    let end = k + zmx[k..].find('\n').unwrap();
    let line = zmx[..k].matches('\n').count() + 1;
    std::fs::write(fx.dir.join("curv.zmx"), format!("{}CURV 1e308 0 0 0 0\n{}", &zmx[..k], &zmx[end + 1..])).unwrap();
    std::fs::write(fx.dir.join("nsc.zmx"), zmx.replace("MODE SEQ", "MODE NSC")).unwrap();
    let out = fx.dir.join("o.toml");
    let zcases: Vec<(Vec<String>, Vec<String>)> = vec![
        (args("import-zmx {fx}/curv.zmx --out {o}", &[("{fx}", fx.dir.display().to_string()), ("{o}", out.display().to_string())]), vec![format!("line {line} `CURV`"), "1e308".into(), "plausible".into()]),
        (args("info --system {fx}/curv.zmx", &[("{fx}", fx.dir.display().to_string())]), vec!["`CURV`".into(), "1e308".into()]),
        (args("import-zmx {fx}/nsc.zmx --ignore-unsupported --out {o}", &[("{fx}", fx.dir.display().to_string()), ("{o}", out.display().to_string())]), vec!["MODE NSC".into(), "--ignore-unsupported".into()]),
        (args("export-spec --system {fx}/coated.toml --out {o}.zmx", &[("{fx}", fx.dir.display().to_string()), ("{o}", fx.dir.join("o").display().to_string())]), vec!["surface 1 has a coating".into(), ".zmx".into()]),
    ];
    edit_spec(&fx, "coated.toml", |t| in_surface(t, 1, "coating = { reflectance = 0.01 }"));
    for (a, says) in &zcases {
        let (code, text, _) = run_in(&fx.dir, a);
        assert_eq!(code, Some(1), "{a:?}: {text}");
        for s in says {
            assert!(text.contains(s.as_str()), "{a:?}: `{s}` not in {text}");
        }
    }
    assert!(!out.exists() && !fx.dir.join("o.zmx").exists());
}

/// Meshes: an STL longer than its header says, OBJ text named .stl, coordinates of 1e300 and a placed part
/// beyond ±1e6 mm each name what is wrong.
#[test]
fn mesh_errors_say_what_is_wrong() {
    use diffcassi::mechanics::mesh_io::parse_mesh;
    // One binary triangle plus 50 extra bytes.
    let mut stl = vec![0u8; 80];
    stl.extend(1u32.to_le_bytes());
    let mut tri = vec![0u8; 12];
    for v in [[0.0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in v {
            tri.extend(c.to_le_bytes());
        }
    }
    tri.extend([0u8; 2]);
    stl.extend(&tri);
    stl.extend(&tri);
    let e = parse_mesh(&stl, "long.stl", false).unwrap_err().to_string();
    assert!(e.contains("longer than its header says") && e.contains("50 bytes after the last triangle") && !e.contains("truncated"), "{e}");
    let obj = b"# a cube\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";
    let e = parse_mesh(obj, "cube.stl", false).unwrap_err().to_string();
    assert!(e.contains("not an ASCII STL") && e.contains("OBJ") && !e.contains("triangles"), "{e}");
    let huge = b"v 0 0 0\nv 1e300 0 0\nv 0 1 0\nf 1 2 3\n";
    let e = parse_mesh(huge, "huge.obj", false).unwrap_err().to_string();
    assert!(e.contains("vertex 1") && e.contains("1e300") && !e.contains("degenerate"), "{e}");
    // A valid file placed beyond ±1e6 mm by its scale: the vertex, the scale and the landing point named.
    let d = tempfile::tempdir().unwrap();
    std::fs::write(d.path().join("t.obj"), "v 0 0 0\nv 1e4 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let part = diffcassi::spec::MeshPartSpec { path: "t.obj".into(), translate_mm: [0.0; 3], rotate_deg: [0.0; 3], scale: 1e6, surface: diffcassi::spec::SurfaceModel::Absorbing, closed: false };
    let e = diffcassi::mechanics::Mechanics::user_part(&part, d.path()).unwrap_err().to_string();
    assert!(e.contains("vertex 1") && e.contains("scale 1000000") && e.contains("1e10"), "{e}");
}

/// `render`'s memory budget counts the detector: SP with a conic of 130 on the doublet's first surface (a
/// mutation like the fuzz's `k: 180`) spreads an 8×8 scene over a 5181×5098 detector; under `--max-memory-gb 1`
/// it is refused naming the detector, before its buffers are allocated (it rendered at 3.7 GB before), and
/// within a larger budget it renders.
#[test]
fn render_budget_counts_the_detector() {
    let fx = fixtures();
    let spec = edit_spec(&fx, "k130.toml", |t| in_surface(t, 16, "conic = 130.0"));
    let d = tempfile::tempdir().unwrap();
    let a = args("--max-memory-gb 1 render --system {s} --scene-size 8 --planes 4 --bands 450:650:4 --rays 1 --out r", &[("{s}", spec.display().to_string())]);
    let (code, text, _) = run_in(d.path(), &a);
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("5181×5098 detector (the dispersed footprint of the 8×8 scene") && text.contains("--max-memory-gb 1"), "{text}");
    assert!(listing(d.path()).is_empty());
    // The unmutated system's detector is small: the same render within the same budget succeeds.
    let a = args("--max-memory-gb 1 render --system {s} --scene-size 8 --planes 4 --bands 450:650:4 --rays 1 --out r", &[("{s}", fx.dir.join("sp.toml").display().to_string())]);
    let (code, text, _) = run_in(d.path(), &a);
    assert_eq!(code, Some(0), "{text}");
}

/// Found by a held-out battery (30 Nov 2026): `make-scene` wrote band lists every reader refuses (decreasing,
/// repeated) — now refused naming `--bands`; a scene whose bands all lie outside the render's planes (a
/// 1000–1300 nm cube rendered at 450–650 nm) rendered as its end band's constant — now refused naming both
/// ranges; shot noise at a mean count below ~1e-16 e⁻ wrote −1 electron, and a tiny exposure with read noise
/// wrote inf — now 0, and an error naming the exposure. Nothing written in each refusal.
#[test]
fn scene_bands_and_noise_extremes_are_refused_or_exact() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let s = |v: &str| v.to_string();
    for bands in ["650:450:4", "500:500:3", "450,450,500"] {
        let (code, out, _) = run_in(dir, &[s("make-scene"), s("--synthetic"), s("1"), s("--size"), s("8"), s("--bands"), s(bands), s("--out"), s("f.npy")]);
        assert_eq!(code, Some(1), "{bands}: {out}");
        assert!(out.contains(&format!("--bands `{bands}`")) && out.contains("increase strictly"), "{bands}: {out}");
        assert!(listing(dir).is_empty(), "{bands}: wrote {:?}", listing(dir));
    }
    // A SWIR cube rendered in the visible: refused, no folder.
    let ws = [1000.0, 1100.0, 1200.0, 1300.0];
    let cube = diffcassi::scene::SpectralCube::new(8, 8, ws.to_vec(), vec![0.5; 8 * 8 * 4], "test").unwrap();
    diffcassi::scene::save_npy(&cube, &dir.join("swir.npy")).unwrap();
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene swir.npy --scene-size 8 --bands 450:650:4 --planes 4 --rays 2 --out r", &[]));
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("1000 – 1300 nm") && out.contains("outside the render's planes"), "{out}");
    assert!(!dir.join("r").exists());
    // A scene covering part of the render's planes (450–583 nm at 450–650 nm): rendered, with a warning and a
    // record (its spectrum is held at 583 nm beyond); one at the render's bands: neither.
    let part = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 494.4, 538.9, 583.3], vec![0.5; 8 * 8 * 4], "test").unwrap();
    diffcassi::scene::save_npy(&part, &dir.join("part.npy")).unwrap();
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene part.npy --scene-size 8 --bands 450:650:4 --planes 8 --rays 2 --out p", &[]));
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("warning: ") && out.contains("lie beyond the scene's bands (450.0–583.3 nm)"), "{out}");
    let rec: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("p/render.json")).unwrap()).unwrap();
    let x = &rec["spectral_extrapolation"];
    assert!(x["planes"].as_u64().unwrap() >= 1 && x["beyond_nm"].as_f64().unwrap() > 66.0 && x["of_planes"] == 8, "{x}");
    let full = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 516.7, 583.3, 650.0], vec![0.5; 8 * 8 * 4], "test").unwrap();
    diffcassi::scene::save_npy(&full, &dir.join("full.npy")).unwrap();
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene full.npy --scene-size 8 --bands 450:650:4 --planes 8 --rays 2 --out f", &[]));
    assert_eq!(code, Some(0), "{out}");
    assert!(!out.contains("beyond the scene's bands"), "{out}");
    let rec: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("f/render.json")).unwrap()).unwrap();
    assert!(rec.get("spectral_extrapolation").is_none());
    // A dim background under shot noise: never a negative count (exposure given so that λ ≈ 1e-19 e⁻ there).
    let mut data = vec![1e-22f32; 8 * 8 * 4];
    data[(4 * 8 + 4) * 4..(4 * 8 + 4) * 4 + 4].fill(1.0);
    let dim = diffcassi::scene::SpectralCube::new(8, 8, vec![450.0, 516.0, 583.0, 650.0], data, "test").unwrap();
    diffcassi::scene::save_npy(&dim, &dir.join("dim.npy")).unwrap();
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene dim.npy --scene-size 8 --bands 450:650:4 --planes 4 --rays 2 --noise shot --out n", &[]));
    assert_eq!(code, Some(0), "{out}");
    let img = diffcassi::io::exr::read_exr(&dir.join("n/acquisition.exr")).unwrap();
    assert!(img.channels[0].data.iter().all(|v| *v >= 0.0), "a negative photon count was written");
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene dim.npy --scene-size 8 --bands 450:650:4 --planes 4 --rays 2 --noise read --read-noise-e 2 --electrons-per-unit 1e-300 --out n2", &[]));
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("f32's range") && out.contains("electrons per unit"), "{out}");
    assert!(!dir.join("n2").exists());
}

/// Spec plausibility from the same battery: an entrance pupil of 1e308 mm (a `.zmx` `ENPD 1e308` traced 468 of
/// 469 rays out of range) and a radius of rotation of 1e-300 mm are refused, naming the field.
#[test]
fn implausible_pupils_and_radii_are_refused() {
    let mut s = common::singlet_at_infinity(false);
    s.aperture = diffcassi::spec::SystemAperture::EntrancePupilDiameter(1e308);
    let e = diffcassi::system::SequentialSystem::build(&s).unwrap_err().to_string();
    assert!(e.contains("entrance_pupil_diameter = 1e308 mm"), "{e}");
    let mut t = common::singlet_at_infinity(false);
    t.surfaces[1].kind = diffcassi::spec::SurfaceKind::Toroidal;
    t.surfaces[1].rotation_radius_mm = Some(diffcassi::spec::Cell::fixed(1e-300));
    let t = diffcassi::system::SequentialSystem::build(&t).map(|_| ());
    let e = t.unwrap_err().to_string();
    assert!(e.contains("rotation_radius_mm = 1e-300 mm") && e.contains("1 nm"), "{e}");
}

/// `reconstruct --truth` reads the truth's wavelengths (a held-out battery: a truth at other wavelengths with the
/// render's band count gave the same PSNRs as the true one): at the render's bands it is used as it is, at other
/// bands covering them it is resampled (other PSNRs), and bands that miss one of the render's are refused.
#[test]
fn reconstruct_truth_is_taken_at_the_render_bands() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    let data: Vec<f32> = (0..8 * 8 * 4).map(|i| 0.2 + 0.6 * ((i * 7919 % 97) as f32 / 97.0)).collect();
    let save = |name: &str, ws: [f64; 4]| diffcassi::scene::save_npy(&diffcassi::scene::SpectralCube::new(8, 8, ws.to_vec(), data.clone(), "test").unwrap(), &dir.join(name)).unwrap();
    save("t.npy", [450.0, 516.6666666666666, 583.3333333333334, 650.0]);
    save("wide.npy", [400.0, 500.0, 600.0, 700.0]);
    save("narrow.npy", [500.0, 550.0, 600.0, 650.0]);
    let (code, out, _) = run_in(dir, &args("render --preset sp --scene t.npy --scene-size 8 --bands 450:650:4 --planes 4 --rays 2 --out r", &[]));
    assert_eq!(code, Some(0), "{out}");
    let psnr = |truth: &str, o: &str| -> (Option<i32>, String, Option<f64>) {
        let (code, out, _) = run_in(dir, &args(&format!("reconstruct --from r --iterations 2 --truth {truth} --out {o}"), &[]));
        let j: Option<serde_json::Value> = std::fs::read(dir.join(o).join("reconstruct.json")).ok().and_then(|b| serde_json::from_slice(&b).ok());
        fn find(v: &serde_json::Value) -> Option<f64> {
            match v {
                serde_json::Value::Object(o) => o.get("truth_residual").and_then(|x| x.as_f64()).or_else(|| o.values().find_map(find)),
                serde_json::Value::Array(a) => a.iter().find_map(find),
                _ => None,
            }
        }
        let p = j.as_ref().and_then(find);
        (code, out, p)
    };
    let (c1, o1, same) = psnr("t.npy", "a");
    let (c2, o2, wide) = psnr("wide.npy", "b");
    assert_eq!((c1, c2), (Some(0), Some(0)), "{o1}\n{o2}");
    let (same, wide) = (same.expect("truth_residual"), wide.expect("truth_residual"));
    assert!((same - wide).abs() > 1e-6 * same.abs().max(1e-12), "a truth at other wavelengths gave the same residual: {same} {wide}");
    let (c3, o3, _) = psnr("narrow.npy", "c");
    assert_eq!(c3, Some(1), "{o3}");
    assert!(o3.contains("--truth") && o3.contains("do not cover the render's band at 450 nm"), "{o3}");
    assert!(!dir.join("c").exists());
}

/// `RAYON_NUM_THREADS` above the `--threads` limit started that many threads (100 000 hung a render: a
/// held-out battery): refused, naming the variable, exit 2; `--threads` (which sets the pool) still wins.
#[test]
fn a_huge_rayon_num_threads_is_refused() {
    let run = |args: &[&str]| bin().args(args).env("RAYON_NUM_THREADS", "100000").output().unwrap();
    let o = run(&["info", "--preset", "sp"]);
    let e = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(e.contains("RAYON_NUM_THREADS=100000") && e.contains("1..=1024"), "{e}");
    let o = run(&["--threads", "2", "info", "--preset", "sp"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // Not a whole number (rayon ignores it silently: a typo ran on every core): refused alike (round 5).
    for v in ["abc", "-1", "2.5", "99999999999999999999"] {
        let o = bin().args(["info", "--preset", "sp"]).env("RAYON_NUM_THREADS", v).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{v}: {e}");
        assert!(e.contains(&format!("RAYON_NUM_THREADS={v}: must be a whole number")), "{v}: {e}");
    }
    for v in ["", "0", "2"] {
        let o = bin().args(["info", "--preset", "sp"]).env("RAYON_NUM_THREADS", v).output().unwrap();
        assert!(o.status.success(), "{v:?}: {}", String::from_utf8_lossy(&o.stderr));
    }
}
