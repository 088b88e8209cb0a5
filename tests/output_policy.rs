//! The output policy through the binary (issue 21, docs/robustness.md "Output policy"): `--out` may be new,
//! empty or a previous output of the same command — never an unrelated folder (without `--force`), a file,
//! an input, inside an input or containing one — and a refused command touches nothing; multi-file outputs
//! are staged; a SIGKILL mid-run or between the renames of a folder swap leaves a complete set under the
//! output's name, and a rerun removes the killed run's temporaries. The kills use the test-only hook
//! `DIFFCASSI_TEST_PAUSE_AT` (the process stops itself with SIGSTOP at that point, the test SIGKILLs it).
use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_diffcassi"))
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Every file and folder under `dir` (relative path → contents, `None` for a folder).
fn snapshot(dir: &Path) -> BTreeMap<String, Option<Vec<u8>>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<String, Option<Vec<u8>>>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            let rel = p.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            if p.is_dir() {
                out.insert(rel, None);
                walk(root, &p, out);
            } else {
                out.insert(rel, Some(std::fs::read(&p).unwrap()));
            }
        }
    }
    let mut m = BTreeMap::new();
    walk(dir, dir, &mut m);
    m
}

/// Names of the temporaries (`.NAME.stage-…`, an earlier version's `.tmp`) under `dir`, recursively.
fn temporaries(dir: &Path) -> Vec<String> {
    snapshot(dir)
        .into_keys()
        .filter(|k| k.contains(".stage-") || k.contains(".tmp") || k.contains(".partial-"))
        .collect()
}

/// A 16×16×8 synthetic scene cube at `out` (the datasets and studies of these tests render it).
fn write_scene(out: &Path) {
    let o = run(&["make-scene", "--synthetic", "1", "--size", "16", "--bands", "450:650:8", "--out", s(out)]);
    assert!(o.status.success(), "{}", stderr(&o));
}

fn render_args<'a>(out: &'a Path, seed: &'a str) -> Vec<&'a str> {
    vec![
        "render",
        "--preset",
        "ap",
        "--scene-size",
        "16",
        "--bands",
        "450:650:8",
        "--planes",
        "8",
        "--rays",
        "2",
        "--no-mapping",
        "--synthetic",
        seed,
        "--out",
        s(out),
    ]
}

fn assert_refused(o: &Output, needles: &[&str]) {
    assert_eq!(o.status.code(), Some(1), "exit code; stderr: {}", stderr(o));
    let e = stderr(o);
    assert!(!e.contains("panicked"), "{e}");
    for n in needles {
        assert!(e.contains(n), "`{n}` in the error: {e}");
    }
}

/// Start the binary with `DIFFCASSI_TEST_PAUSE_AT=point`, wait until it stopped itself there, SIGKILL it.
fn kill_at(point: &str, args: &[&str]) {
    let mut child: Child = bin()
        .args(args)
        .env("DIFFCASSI_TEST_PAUSE_AT", point)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let t0 = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let o = child.wait_with_output().unwrap();
            panic!(
                "the process ended ({status}) before stopping at `{point}`: {}",
                stderr(&o)
            );
        }
        let stat =
            std::fs::read_to_string(format!("/proc/{}/stat", child.id())).unwrap_or_default();
        if stat
            .rsplit_once(')')
            .is_some_and(|(_, r)| r.trim_start().starts_with('T'))
        {
            break;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(300),
            "the process did not stop at `{point}` within 300 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    let o = child.wait_with_output().unwrap();
    assert!(!o.status.success());
    assert!(
        stderr(&o).contains(&format!("DIFFCASSI_TEST_PAUSE_AT={point}")),
        "{}",
        stderr(&o)
    );
}

/// `reconstruct --out` pointing at an unrelated folder, a file, the `--from` folder, a folder inside it or its
/// parent: exit 1, nothing touched anywhere (today's main deleted, renamed away or destroyed them).
#[test]
fn reconstruct_never_replaces_what_it_does_not_own() {
    let d = tempfile::tempdir().unwrap();
    let work = d.path().join("work");
    let from = work.join("render");
    let o = run(&render_args(&from, "0"));
    assert!(o.status.success(), "{}", stderr(&o));
    let mine = d.path().join("mine");
    std::fs::create_dir_all(mine.join("sub")).unwrap();
    std::fs::write(mine.join("notes.txt"), "my notes").unwrap();
    std::fs::write(mine.join("sub/data.bin"), [1u8, 2, 3]).unwrap();
    let file = d.path().join("result.txt");
    std::fs::write(&file, "a file").unwrap();
    let rec = |out: &Path, extra: &[&str]| {
        let mut a = vec![
            "reconstruct",
            "--from",
            s(&from),
            "--operator",
            "shift",
            "--iterations",
            "2",
            "--out",
            s(out),
        ];
        a.extend_from_slice(extra);
        run(&a)
    };
    let before = snapshot(d.path());
    for (out, needles) in [
        (
            mine.clone(),
            vec!["mine", "not a previous `reconstruct` output", "--force"],
        ),
        (file.clone(), vec!["result.txt", "is a file"]),
        (from.clone(), vec!["is the input --from"]),
        (from.join("rec"), vec!["is inside the input --from"]),
        (work.clone(), vec!["contains the input --from"]),
        (from.join("../render/."), vec!["is the input --from"]),
    ] {
        assert_refused(&rec(&out, &[]), &needles);
        assert_eq!(
            snapshot(d.path()),
            before,
            "--out {}: something was touched",
            out.display()
        );
    }
    // --force does not lift the input rule, nor the file rule.
    assert_refused(&rec(&from, &["--force"]), &["--from"]);
    assert_refused(&rec(&file, &["--force"]), &["is a file"]);
    assert_eq!(snapshot(d.path()), before);
    // New, then a previous reconstruction (replaced whole), then --force beside the user's files.
    let out = d.path().join("rec");
    for _ in 0..2 {
        let o = rec(&out, &[]);
        assert!(o.status.success(), "{}", stderr(&o));
        assert!(out.join("reconstruct.json").is_file() && out.join("cube.npy").is_file());
    }
    let o = rec(&mine, &["--force"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(mine.join("notes.txt")).unwrap(),
        "my notes"
    );
    assert_eq!(std::fs::read(mine.join("sub/data.bin")).unwrap(), [1, 2, 3]);
    assert!(mine.join("reconstruct.json").is_file());
    // The folder now holds reconstruct.json: a rerun without --force still keeps the user's files.
    let o = rec(&mine, &[]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(
        std::fs::read_to_string(mine.join("notes.txt")).unwrap(),
        "my notes"
    );
    assert_eq!(std::fs::read(mine.join("sub/data.bin")).unwrap(), [1, 2, 3]);
    assert!(
        temporaries(d.path()).is_empty(),
        "{:?}",
        temporaries(d.path())
    );
}

/// render, report, study and render-dataset refuse an unrelated folder or their input, touching nothing.
#[test]
fn folder_commands_refuse_unrelated_folders_and_inputs() {
    let d = tempfile::tempdir().unwrap();
    let mine = d.path().join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), "my notes").unwrap();
    let scenes = d.path().join("scenes");
    std::fs::create_dir_all(&scenes).unwrap();
    write_scene(&scenes.join("s1.npy"));
    let m = s(&mine);
    let sc = s(&scenes);
    let inside = scenes.join("out");
    let ds = |out: &str| {
        vec![
            "render-dataset",
            "--scenes",
            sc,
            "--preset",
            "ap",
            "--scene-size",
            "16",
            "--bands",
            "450:650:8",
            "--planes",
            "8",
            "--rays",
            "2",
            "--no-mapping",
            "--out",
        ]
        .into_iter()
        .chain([out])
        .map(String::from)
        .collect::<Vec<_>>()
    };
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            render_args(&mine, "0")
                .into_iter()
                .map(String::from)
                .collect(),
            "no render.json",
        ),
        (
            ["report", "--preset", "ap", "--out", m]
                .map(String::from)
                .to_vec(),
            "no report.json",
        ),
        (
            [
                "study",
                "--synthetic",
                "1",
                "--scene-size",
                "8",
                "--presets",
                "ap",
                "--out",
                m,
            ]
            .map(String::from)
            .to_vec(),
            "no study.json",
        ),
        (
            [
                "study",
                "--scenes",
                sc,
                "--scene-size",
                "8",
                "--presets",
                "ap",
                "--out",
                sc,
            ]
            .map(String::from)
            .to_vec(),
            "is the input --scenes",
        ),
        (ds(m), "no dataset.json"),
        (ds(sc), "is the input --scenes"),
        (ds(s(&inside)), "is inside the input --scenes"),
        (ds(s(d.path())), "contains the input --scenes"),
        (
            [
                "render",
                "--preset",
                "ap",
                "--scene",
                &format!("{sc}/s1.npy"),
                "--out",
                sc,
            ]
            .map(String::from)
            .to_vec(),
            "contains the input --scene",
        ),
        (
            [
                "make-scene",
                "--rgb",
                &format!("{m}/p_rgb.png"),
                "--out",
                &format!("{m}/p.npy"),
            ]
            .map(String::from)
            .to_vec(),
            "--rgb",
        ),
        (
            [
                "evaluate",
                "--truth",
                &format!("{sc}/s1.npy"),
                "--estimate",
                &format!("{sc}/s1.npy"),
                "--json",
                &format!("{sc}/s1.npy"),
            ]
            .map(String::from)
            .to_vec(),
            "is the input --truth",
        ),
    ];
    // make-scene --rgb: the preview p_rgb.png would overwrite the photograph.
    std::fs::write(mine.join("p_rgb.png"), b"not really a png").unwrap();
    let before_mine = snapshot(d.path());
    for (args, needle) in &cases {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        assert_refused(&run(&a), &[needle]);
        assert_eq!(
            snapshot(d.path()),
            before_mine,
            "{a:?}: something was touched"
        );
    }
}

/// make-scene writes cube, wavelength list and preview all or nothing: a failure at the preview (today: after
/// the new cube and wavelengths were written) or a SIGKILL before the renames leaves the old set byte for
/// byte; a rerun leaves no temporary files.
#[test]
fn make_scene_is_staged() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("x.npy");
    let make = |bands: &str| {
        run(&[
            "make-scene",
            "--synthetic",
            "3",
            "--size",
            "8",
            "--bands",
            bands,
            "--out",
            s(&out),
        ])
    };
    let o = make("450:650:5");
    assert!(o.status.success(), "{}", stderr(&o));
    let old = snapshot(d.path());
    assert_eq!(old.len(), 3, "{:?}", old.keys());
    // The preview's name is taken by a folder: refused before anything is written.
    std::fs::remove_file(d.path().join("x_rgb.png")).unwrap();
    std::fs::create_dir(d.path().join("x_rgb.png")).unwrap();
    let held = snapshot(d.path());
    assert_refused(&make("450:650:8"), &["x_rgb.png", "folder"]);
    assert_eq!(snapshot(d.path()), held);
    std::fs::remove_dir(d.path().join("x_rgb.png")).unwrap();
    let o = make("450:650:5");
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(snapshot(d.path()), old);
    // SIGKILL with every file staged and none moved.
    kill_at(
        "commit",
        &[
            "make-scene",
            "--synthetic",
            "3",
            "--size",
            "8",
            "--bands",
            "450:650:8",
            "--out",
            s(&out),
        ],
    );
    let after = snapshot(d.path());
    assert_eq!(temporaries(d.path()).len(), 3, "{:?}", after.keys());
    for (k, v) in &old {
        assert_eq!(after.get(k), Some(v), "{k} changed");
    }
    let o = make("450:650:8");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        temporaries(d.path()).is_empty(),
        "{:?}",
        temporaries(d.path())
    );
    let cube = diffcassi::scene::load_scene(&out, None).unwrap();
    assert_eq!(cube.bands(), 8);
}

/// A render SIGKILLed mid-run (every file staged, nothing moved) keeps the old set byte for byte, and the
/// rerun removes the killed run's staging folder.
#[test]
fn killed_render_keeps_the_old_set_and_the_rerun_cleans_up() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let o = run(&render_args(&out, "0"));
    assert!(o.status.success(), "{}", stderr(&o));
    let old = snapshot(&out);
    kill_at("commit", &render_args(&out, "1"));
    assert_eq!(snapshot(&out), old);
    let temps = temporaries(d.path());
    assert!(
        temps.iter().any(|t| t.starts_with(".out.stage-")),
        "the killed run's staging folder: {temps:?}"
    );
    let o = run(&render_args(&out, "1"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        temporaries(d.path()).is_empty(),
        "{:?}",
        temporaries(d.path())
    );
    assert_ne!(snapshot(&out), old);
}

/// A SIGKILL inside the swap of an output folder (after the exchange, before the old set is removed) leaves a
/// complete set under the output's name — the new one — and the rerun removes the old set left beside it.
#[test]
fn kill_inside_the_swap_leaves_a_complete_set() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("out");
    let o = run(&render_args(&out, "0"));
    assert!(o.status.success(), "{}", stderr(&o));
    let old = snapshot(&out);
    let reference = d.path().join("reference");
    let o = run(&render_args(&reference, "1"));
    assert!(o.status.success(), "{}", stderr(&o));
    kill_at("swap", &render_args(&out, "1"));
    let now = snapshot(&out);
    let names = |m: &BTreeMap<String, Option<Vec<u8>>>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(names(&now), names(&old), "a complete set");
    assert!(diffcassi::render::output::outputs_complete(&out));
    // The new set: the acquisition equals the same render's into another folder (render.json holds timings).
    assert_eq!(
        now["acquisition.exr"],
        snapshot(&reference)["acquisition.exr"]
    );
    assert_ne!(now["acquisition.exr"], old["acquisition.exr"]);
    assert!(!temporaries(d.path()).is_empty());
    let o = run(&render_args(&out, "1"));
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        temporaries(d.path()).is_empty(),
        "{:?}",
        temporaries(d.path())
    );
}

/// dataset-status with an empty scene list is an error saying so (today: "0 scenes … all done", exit 0).
#[test]
fn dataset_status_without_scenes_fails() {
    let d = tempfile::tempdir().unwrap();
    let scenes = d.path().join("scenes");
    let empty = d.path().join("empty");
    std::fs::create_dir_all(&scenes).unwrap();
    std::fs::create_dir_all(&empty).unwrap();
    write_scene(&scenes.join("s1.npy"));
    // One dataset command, run into a given output folder.
    let render_dataset = |out: &std::path::Path| {
        run(&["render-dataset", "--scenes", s(&scenes), "--preset", "ap", "--scene-size", "16", "--bands", "450:650:8", "--planes", "8", "--rays", "2", "--no-mapping", "--out", s(out)])
    };
    let ds = d.path().join("ds");
    let o = render_dataset(&ds);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&["dataset-status", s(&ds), "--scenes", s(&scenes)]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = run(&["dataset-status", s(&ds), "--scenes", s(&empty)]);
    assert_refused(&o, &["no scenes"]);
    // A shard killed (or a sibling started) before dataset.json exists left only the dataset's own files:
    // accepted as the same command's output.
    let early = d.path().join("early");
    std::fs::create_dir_all(early.join(".s1.partial-elsewhere-1-2")).unwrap();
    std::fs::copy(ds.join("mask.png"), early.join("mask.png")).unwrap();
    let o = render_dataset(&early);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(
        early.join("s1/render.json").is_file() && !early.join(".s1.partial-elsewhere-1-2").exists()
    );
    // A rerun into its own output is accepted by the policy (the dataset is complete: nothing to render).
    let o = render_dataset(&ds);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(!stderr(&o).contains("not a previous"), "{}", stderr(&o));
}

/// `design`/`calibrate` write `--report` and `--system-out` as one staged set under the policy: never an input
/// spec file, never a folder, not both the same file; a successful run writes both and leaves no temporary.
#[test]
fn design_and_calibrate_outputs_follow_the_policy() {
    let d = tempfile::tempdir().unwrap();
    let spec = d.path().join("sp.toml");
    assert!(run(&["export-spec", "--preset", "sp", "--out", s(&spec)]).status.success());
    let before = snapshot(d.path());
    let cal = |extra: &[&str]| {
        let mut args = vec!["calibrate", "--from", s(&spec), "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small"];
        args.extend_from_slice(extra);
        run(&args)
    };
    assert_refused(&cal(&["--system-out", s(&spec)]), &["--system-out", "input"]);
    let same = d.path().join("x.json");
    assert_refused(&cal(&["--report", s(&same), "--system-out", s(&same)]), &["same file"]);
    assert_refused(&run(&["design", "amici", "--iterations", "1", "--report", s(d.path())]), &["--report"]);
    assert_eq!(snapshot(d.path()), before, "a refused design/calibrate touched its folder");
    let (report, fitted) = (d.path().join("cal.json"), d.path().join("fitted.toml"));
    let o = run(&["calibrate", "--from", "sp", "--observed", "msp", "--free", "prism_tilt_x", "--setup", "small", "--report", s(&report), "--system-out", s(&fitted)]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(report.is_file() && fitted.is_file());
    assert!(temporaries(d.path()).is_empty(), "{:?}", temporaries(d.path()));
}
