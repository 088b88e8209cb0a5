//! Bad input, round 2 (issue 21, part B): every size, count and budget `render` checks is checked, with the
//! same messages and before allocating, by `make-scene`, `study`, `reconstruct --from` (every field of a
//! tampered `render.json`) and `bench-render`; options that were accepted and ignored are refused; unclear
//! errors name the option or field and its value. Each case runs the real binary: exit code, a message
//! naming the option/field/value, nothing written, no panic, done within 60 s. Tiny sizes throughout.
use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

/// Run `args` in `cwd` with a 60 s limit; (exit code, stderr).
fn run_in(cwd: &Path, args: &[String]) -> (Option<i32>, String) {
    let t = Instant::now();
    let mut child = bin()
        .args(args)
        .current_dir(cwd)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let status = common::wait_with_limit(&mut child, t, Duration::from_secs(60));
    let mut err = String::new();
    use std::io::Read;
    let _ = child.stderr.take().unwrap().read_to_string(&mut err);
    (status.and_then(|s| s.code()), err)
}

/// A tiny render folder (16×16 scene, 4 bands, 4 planes, 2 rays) under `dir`.
fn tiny_render(dir: &Path) -> PathBuf {
    let out = dir.join("render");
    let args: Vec<String> = "render --preset sp --scene-size 16 --planes 4 --bands 450:650:4 --rays 2 --no-mapping --out".split_whitespace().map(String::from).chain([out.display().to_string()]).collect();
    let (code, err) = run_in(dir, &args);
    assert_eq!(code, Some(0), "{err}");
    out
}

/// A valid PNG of 20000×20000 pixels (1-bit grey, all zero; 48 KB, made by zlib at level 9 from 20000 rows of
/// 2501 zero bytes): decoding it would take 400 M pixels; its header must be enough to refuse it.
fn huge_png() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/png/huge-20000x20000-1bit.png")
}

struct Case {
    args: &'static str,
    code: i32,
    /// Every one of these must appear in stderr.
    says: &'static [&'static str],
}

/// `{out}` is a fresh output path in an empty folder, `{render}` a valid tiny render folder, `{png}` the
/// 20000×20000 PNG, `{rgb}` a small RGB photograph.
const CASES: &[Case] = &[
    // make-scene: sizes by the memory budget, before allocating; the uplift methods' wavelength ranges.
    Case {
        args: "make-scene --synthetic 1 --size 100000 --out {out}.npy",
        code: 1,
        says: &["--size 100000", "--max-memory-gb"],
    },
    Case {
        args: "make-scene --colour-checker --size 100000 --out {out}.npy",
        code: 1,
        says: &["--size 100000", "--max-memory-gb"],
    },
    Case {
        args: "make-scene --rgb {png} --size 16 --out {out}.npy",
        code: 1,
        says: &["20000×20000", "--max-memory-gb"],
    },
    Case {
        args: "make-scene --rgb {rgb} --bands 100:5000:28 --size 8 --out {out}.npy",
        code: 1,
        says: &["--bands", "100 nm", "380–720 nm", "Smits"],
    },
    Case {
        args: "make-scene --colour-checker --bands 300:700:5 --size 8 --out {out}.npy",
        code: 1,
        says: &["--bands", "300 nm", "380–780 nm", "ColorChecker"],
    },
    // study: render's limits with render's messages, before any scene is generated.
    Case {
        args: "study --synthetic 1 --scene-size 100000 --out {out}",
        code: 1,
        says: &["--scene-size 100000", "--max-memory-gb"],
    },
    Case {
        args: "study --synthetic 100000000 --scene-size 8 --out {out}",
        code: 1,
        says: &["--synthetic 100000000", "1..=1000000"],
    },
    Case {
        args: "study --synthetic 100000 --scene-size 128 --out {out}",
        code: 1,
        says: &["100000 scenes", "--max-memory-gb"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --airy-diameter-px 1000000 --out {out}",
        code: 1,
        says: &["--airy-diameter-px 1000000", "(0, 100]"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --planes 10000000 --out {out}",
        code: 1,
        says: &["--planes 10000000", "1..=100000"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 512 --planes 100000 --rays 1000 --out {out}",
        code: 1,
        says: &["--rays 1000", "--max-rays"],
    },
    // study: options accepted and ignored.
    Case {
        // (with --synthetic, --fit is refused by clap since round 6: the synthetic scenes are not fitted)
        args: "study --scenes /nonexistent-scenes --scene-size 8 --fit stretch --out {out}",
        code: 1,
        says: &["--fit `stretch`", "crop or resize"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --transport-memory-gb nan --out {out}",
        code: 1,
        says: &["--transport-memory-gb NaN"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --transport-memory-gb -1 --out {out}",
        code: 1,
        says: &["--transport-memory-gb -1"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --transport-memory-gb inf --out {out}",
        code: 1,
        says: &["--transport-memory-gb inf"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --solvers admm-tv --accelerated --out {out}",
        code: 1,
        says: &["--accelerated", "gap-tv", "admm-tv"],
    },
    Case {
        args: "study --synthetic 1 --scene-size 8 --scene-wavelengths 450:650:4 --out {out}",
        code: 1,
        says: &["--scene-wavelengths", "--synthetic"],
    },
    // reconstruct: options accepted and ignored.
    Case {
        args: "reconstruct --from {render} --tolerance-um 1 --out {out}",
        code: 1,
        says: &["--tolerance-um 1", "--backend"],
    },
    Case {
        args: "reconstruct --from {render} --operator shift --operator-seed 3 --out {out}",
        code: 1,
        says: &["--operator-seed", "shift"],
    },
    Case {
        args: "reconstruct --from {render} --solver admm-tv --accelerated --out {out}",
        code: 1,
        says: &["--accelerated", "gap-tv", "admm-tv"],
    },
    Case {
        args: "reconstruct --from {render} --transport-memory-gb nan --out {out}",
        code: 1,
        says: &["--transport-memory-gb NaN"],
    },
    Case {
        args: "--max-rays 100 reconstruct --from {render} --out {out}",
        code: 1,
        says: &["rays_per_pixel", "--max-rays"],
    },
    // render: an option of scene files accepted and ignored with the synthetic scene.
    Case {
        args:
            "render --preset sp --scene-size 8 --planes 4 --scene-wavelengths 450:650:4 --out {out}",
        code: 1,
        says: &["--scene-wavelengths", "synthetic"],
    },
    // bench-render: a count silently raised to 1.
    Case {
        args: "bench-render --scene-size 8 --planes 4 --rays 1 --scenes 0",
        code: 1,
        says: &["--scenes 0"],
    },
    Case {
        args: "bench-render --scene-size 8 --planes 4 --rays 1 --scenes 100000000",
        code: 1,
        says: &["--scenes 100000000"],
    },
];

fn expand(text: &str, subst: &[(&str, String)]) -> Vec<String> {
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

/// Every case: the exit code, a message naming the option/field and value, no panic, and nothing written
/// into the empty folder it runs in (the render fixture lives elsewhere and must stay intact).
#[test]
fn bad_invocations_are_refused_before_any_work() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path());
    let png = huge_png();
    let rgb = fx.path().join("small_rgb.png");
    image::RgbImage::from_fn(6, 5, |x, y| {
        image::Rgb([(x * 40) as u8, (y * 50) as u8, 128])
    })
    .save(&rgb)
    .unwrap();
    let render_json = std::fs::read(render.join("render.json")).unwrap();
    let mut failures = Vec::new();
    for case in CASES {
        let dir = tempfile::tempdir().unwrap();
        let subst = [
            ("{out}", dir.path().join("result").display().to_string()),
            ("{render}", render.display().to_string()),
            ("{png}", png.display().to_string()),
            ("{rgb}", rgb.display().to_string()),
        ];
        let args = expand(case.args, &subst);
        let t = Instant::now();
        let (code, err) = run_in(dir.path(), &args);
        let written: Vec<String> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        let missing: Vec<&&str> = case.says.iter().filter(|s| !err.contains(**s)).collect();
        if code != Some(case.code)
            || !missing.is_empty()
            || !written.is_empty()
            || err.contains("panicked")
        {
            failures.push(format!("`{}`: exit {code:?} (want {}), missing {missing:?}, wrote {written:?}, {:.1} s, stderr: {err}", case.args, case.code, t.elapsed().as_secs_f64()));
        }
    }
    assert_eq!(
        std::fs::read(render.join("render.json")).unwrap(),
        render_json,
        "the input render folder was changed"
    );
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        CASES.len(),
        failures.join("\n")
    );
}

/// `reconstruct --from` a folder whose `render.json` was tampered: each invalid field is refused naming the
/// field and its value (not "the folder does not match this diffcassi version"), before allocating —
/// planes 10⁹, rays 10¹⁵, 10⁶×10⁶ scenes, `airy.reference_nm: 0` (a panic before), and the rest.
#[test]
fn tampered_render_json_names_the_field() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path());
    let original: serde_json::Value =
        serde_json::from_slice(&std::fs::read(render.join("render.json")).unwrap()).unwrap();
    type Edit = fn(&mut serde_json::Value);
    let cases: &[(&str, Edit, &[&str])] = &[
        (
            "planes 1e9",
            |j| j["planes"] = 1_000_000_000u64.into(),
            &["field `planes` = 1000000000", "1..=100000"],
        ),
        (
            "rays 1e15",
            |j| j["rays_per_pixel"] = 1_000_000_000_000_000u64.into(),
            &["rays_per_pixel", "1000000000000000", "--max-rays"],
        ),
        (
            "rays 0",
            |j| j["rays_per_pixel"] = 0.into(),
            &["field `rays_per_pixel` = 0"],
        ),
        (
            "scene 1e6²",
            |j| {
                j["scene_height"] = 1_000_000.into();
                j["scene_width"] = 1_000_000.into();
            },
            &[
                "scene_height × scene_width",
                "1000000 × 1000000",
                "--max-memory-gb",
            ],
        ),
        (
            "airy reference 0",
            |j| j["airy"]["reference_nm"] = 0.0.into(),
            &["airy.reference_nm = 0", "100–20000 nm"],
        ),
        (
            "airy diameter 1e6",
            |j| j["airy"]["diameter_px"] = 1e6.into(),
            &["airy.diameter_px = 1000000", "(0, 100]"],
        ),
        (
            "airy rings 9",
            |j| j["airy"]["rings"] = 9.into(),
            &["airy.rings = 9"],
        ),
        (
            "airy rings -1",
            |j| j["airy"]["rings"] = (-1).into(),
            &["airy.rings` = -1"],
        ),
        (
            "pitch -1",
            |j| j["scene_pitch_mm"] = (-1.0).into(),
            &["field `scene_pitch_mm` = -1 mm"],
        ),
        (
            "detector pitch 1e300",
            |j| j["detector_pitch_mm"] = 1e300.into(),
            &["field `detector_pitch_mm` = 1e300 mm"],
        ),
        (
            "band 0 nm",
            |j| j["bands_nm"][0] = 0.0.into(),
            &["field `bands_nm`: band 0 = 0 nm", "100–20000 nm"],
        ),
        (
            "detector 1e9 rows",
            |j| j["detector"]["height"] = 1_000_000_000.into(),
            &["field `detector` is 1000000000×", "1..=65535"],
        ),
        (
            "detector margin 1e12",
            |j| j["detector_extra_px"] = 1_000_000_000_000u64.into(),
            &["field `detector_extra_px` = 1000000000000"],
        ),
        (
            "planes text",
            |j| j["planes"] = "many".into(),
            &["field `planes` = \"many\""],
        ),
        // The noise block (the stopping rule's sensor term is computed from it; a damaged one made the term 0) and
        // the mask's file name (a path out of the folder read another mask): found by a held-out battery.
        (
            "noise sources bogus",
            |j| j["noise"] = serde_json::json!({"sources": ["bogus"], "electrons_per_unit": 10.0}),
            &["field `noise.sources`", "\"bogus\""],
        ),
        (
            "noise a string",
            |j| j["noise"] = "garbage".into(),
            &["field `noise` = \"garbage\""],
        ),
        (
            "noise exposure 0",
            |j| j["noise"] = serde_json::json!({"sources": ["shot"], "electrons_per_unit": 0.0}),
            &["field `noise.electrons_per_unit` = 0.0"],
        ),
        (
            "noise read -1",
            |j| j["noise"] = serde_json::json!({"sources": ["shot", "read"], "electrons_per_unit": 5.0, "read_noise_e": -1.0}),
            &["field `noise.read_noise_e` = -1.0"],
        ),
        (
            "noise adc twice",
            |j| j["noise"] = serde_json::json!({"sources": ["adc", "adc"], "electrons_per_unit": 5.0, "adc_gain_e_per_dn": 2.0}),
            &["lists \"adc\" twice"],
        ),
        (
            "mask file outside",
            |j| j["mask_file"] = "../other/mask.png".into(),
            &["field `mask_file` = \"../other/mask.png\"", "plain file name"],
        ),
        (
            "mask file absolute",
            |j| j["mask_file"] = "/etc/passwd".into(),
            &["field `mask_file` = \"/etc/passwd\""],
        ),
    ];
    let mut failures = Vec::new();
    for (name, edit, says) in cases {
        let dir = tempfile::tempdir().unwrap();
        let from = dir.path().join("from");
        std::fs::create_dir(&from).unwrap();
        for f in ["acquisition.exr", "mask.png"] {
            std::fs::copy(render.join(f), from.join(f)).unwrap();
        }
        let mut j = original.clone();
        edit(&mut j);
        std::fs::write(
            from.join("render.json"),
            serde_json::to_vec_pretty(&j).unwrap(),
        )
        .unwrap();
        let out = dir.path().join("rec");
        let args = vec![
            "reconstruct".into(),
            "--from".into(),
            from.display().to_string(),
            "--iterations".into(),
            "2".into(),
            "--out".into(),
            out.display().to_string(),
        ];
        let (code, err) = run_in(dir.path(), &args);
        let missing: Vec<&&str> = says.iter().filter(|s| !err.contains(**s)).collect();
        if code != Some(1)
            || !missing.is_empty()
            || out.exists()
            || err.contains("panicked")
            || err.contains("does not match this diffcassi version")
        {
            failures.push(format!(
                "{name}: exit {code:?}, missing {missing:?}, wrote {}, stderr: {err}",
                out.exists()
            ));
        }
    }
    assert!(
        failures.is_empty(),
        "{} of {} cases failed:\n{}",
        failures.len(),
        cases.len(),
        failures.join("\n")
    );
    // The untouched folder still reconstructs (the checks refuse only what is invalid).
    let out = fx.path().join("rec");
    let (code, err) = run_in(
        fx.path(),
        &[
            "reconstruct".into(),
            "--from".into(),
            render.display().to_string(),
            "--iterations".into(),
            "2".into(),
            "--out".into(),
            out.display().to_string(),
        ],
    );
    assert_eq!(code, Some(0), "{err}");
}

/// An acquisition too large for the solver's f32 sums is refused up front, naming the file, the value and
/// the limit, instead of "the solver produced a non-finite value".
#[test]
fn huge_acquisition_is_refused_naming_the_limit() {
    let fx = tempfile::tempdir().unwrap();
    let render = tiny_render(fx.path());
    let acq = render.join("acquisition.exr");
    let img = diffcassi::io::exr::read_exr(&acq).unwrap();
    let scaled = |value: f32| {
        let mut channels = img.channels.clone();
        for c in &mut channels {
            let peak = c.data.iter().fold(0.0f32, |m, v| m.max(*v));
            for v in &mut c.data {
                *v = (*v as f64 / peak as f64 * value as f64) as f32;
            }
        }
        diffcassi::io::exr::write_exr(&acq, img.width, img.height, &channels).unwrap();
        // The record names the acquisition it wrote: this test's acquisition stands in for a render's own.
        let jp = render.join("render.json");
        let mut j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&jp).unwrap()).unwrap();
        j["acquisition_f32le_sha256"] = serde_json::json!(diffcassi::render::engine::acquisition_sha256(&channels[0].data));
        std::fs::write(&jp, serde_json::to_string_pretty(&j).unwrap()).unwrap();
    };
    // Three GAP-TV iterations of the render into `out`.
    let reconstruct = |out: &std::path::Path| {
        let args = ["reconstruct", "--from", &render.display().to_string(), "--iterations", "3", "--out", &out.display().to_string()].map(String::from);
        run_in(fx.path(), &args)
    };
    // At the limit the reconstruction is finite and written…
    scaled(3.4e29);
    let ok = fx.path().join("rec-ok");
    let (code, err) = reconstruct(&ok);
    assert_eq!(code, Some(0), "{err}");
    // …beyond it, refused before the operator is built.
    scaled(1e36);
    let out = fx.path().join("rec");
    let (code, err) = reconstruct(&out);
    assert_eq!(code, Some(1), "{err}");
    assert!(
        err.contains("acquisition.exr")
            && err.contains("acquisition values must be within ±3.403e29")
            && err.contains("e30"),
        "{err}"
    );
    assert!(!err.contains("non-finite") && !out.exists(), "{err}");
}
