//! `render-dataset` sharding, JSON Lines, configuration checks and all-or-nothing scene folders, and
//! `dataset-status` on intact and corrupted outputs, through the command line (issue 17; issue 16 class 4).
//! Tiny sizes (16×16 scenes, 4 planes, 2 rays) so the file runs in seconds. The real Slurm test is
//! tests/slurm/run.sh.
use diffcassi::scene;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const OPTS: [&str; 10] = ["--preset", "sp", "--scene-size", "16", "--planes", "4", "--bands", "450:650:4", "--rays", "2"];

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_diffcassi"));
    for v in ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "DIFFCASSI_DEBUG_SCENE_DELAY_MS"] {
        c.env_remove(v);
    }
    c
}

fn run(args: &[&str]) -> Output {
    bin().args(args).output().expect("the binary runs")
}

fn render_dataset(scenes: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut a = vec!["render-dataset", "--scenes", scenes.to_str().unwrap(), "--out", out.to_str().unwrap()];
    a.extend(OPTS);
    a.extend(extra);
    run(&a)
}

fn status(out: &Path) -> (Option<i32>, serde_json::Value) {
    let o = run(&["dataset-status", out.to_str().unwrap(), "--json"]);
    (o.status.code(), serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null))
}

/// (scene, status) of each JSON line on stdout; every stdout line must be JSON.
fn lines(o: &Output) -> Vec<(String, String)> {
    String::from_utf8_lossy(&o.stdout)
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON: {l}: {e}"));
            assert!(v["seconds"].as_f64().is_some() && v["output"].as_str().is_some(), "{l}");
            (v["scene"].as_str().unwrap().to_string(), v["status"].as_str().unwrap().to_string())
        })
        .collect()
}

fn make_scenes(dir: &Path, n: usize) {
    std::fs::create_dir_all(dir).unwrap();
    let ws = scene::synthetic_wavelengths();
    for i in 0..n {
        scene::save_npy(&scene::synthetic_scene(16, 16, &ws, i as u64), &dir.join(format!("s{i:02}.npy"))).unwrap();
    }
}

/// Every file under `dir` (relative path → bytes), render.json without its timing fields.
fn snapshot(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    fn walk(root: &Path, d: &Path, out: &mut Vec<(PathBuf, Vec<u8>)>) {
        for e in std::fs::read_dir(d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                walk(root, &p, out);
            } else {
                let mut bytes = std::fs::read(&p).unwrap();
                if p.file_name().unwrap() == "render.json" {
                    let mut v: serde_json::Value = serde_json::from_slice(&bytes).unwrap();
                    for k in ["threads", "seconds_total", "seconds_render", "timings", "rays_per_second", "transport_seconds", "seconds_scene", "transport_cached"] {
                        v.as_object_mut().unwrap().remove(k);
                    }
                    bytes = serde_json::to_vec(&v).unwrap();
                }
                out.push((p.strip_prefix(root).unwrap().to_path_buf(), bytes));
            }
        }
    }
    let mut v = Vec::new();
    walk(dir, dir, &mut v);
    v.sort();
    v
}

#[test]
fn bad_shards_are_usage_errors() {
    let d = tempfile::tempdir().unwrap();
    make_scenes(&d.path().join("sc"), 1);
    for (shard, needle) in [("4/4", "out of range"), ("0/0", "≥ 1"), ("a/b", "`a`"), ("slurm", "SLURM_ARRAY_TASK_ID"), ("1", "K/N"), ("-1/2", "-1")] {
        let o = render_dataset(&d.path().join("sc"), &d.path().join("o"), &[&format!("--shard={shard}")]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "--shard {shard}: {e}");
        assert!(e.contains("--shard") && e.contains(needle), "--shard {shard}: {e}");
        assert!(!e.contains("panicked"));
    }
    // Inside a resubmitted single array index Slurm reports a count of 1: the error says to give N.
    let mut c = bin();
    c.env("SLURM_ARRAY_TASK_ID", "2").env("SLURM_ARRAY_TASK_COUNT", "1");
    let o = c.args(["render-dataset", "--scenes", "x", "--out", "y", "--preset", "sp", "--shard", "slurm"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("slurm/N"), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(!d.path().join("o").exists(), "nothing written on a usage error");
    let o = run(&["render-dataset", "--scenes", "x", "--out", "y", "--preset", "sp", "--on-mismatch", "ignore"]);
    assert_eq!(o.status.code(), Some(2));
    let o = run(&["dataset-status", d.path().join("nope").to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("nope"));
}

/// Four shards (one through `--shard slurm`) give the same files as one unsharded run, each scene once.
#[test]
fn shards_reproduce_the_single_run_and_status_is_clean() {
    let d = tempfile::tempdir().unwrap();
    let sc = d.path().join("scenes");
    make_scenes(&sc, 7);
    let (whole, sharded) = (d.path().join("whole"), d.path().join("sharded"));
    let o = render_dataset(&sc, &whole, &[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(lines(&o).len(), 7);
    let mut seen = Vec::new();
    for k in 0..4 {
        let o = if k == 2 {
            let mut c = bin();
            c.env("SLURM_ARRAY_TASK_ID", "2").env("SLURM_ARRAY_TASK_COUNT", "4").args(["render-dataset", "--scenes", sc.to_str().unwrap(), "--out", sharded.to_str().unwrap(), "--shard", "slurm"]).args(OPTS);
            c.output().unwrap()
        } else {
            render_dataset(&sc, &sharded, &["--shard", &format!("{k}/4")])
        };
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        for (s, st) in lines(&o) {
            assert_eq!(st, "rendered");
            let i: usize = s[1..].parse().unwrap();
            assert_eq!(i % 4, k, "{s} in shard {k}");
            seen.push(s);
        }
    }
    seen.sort();
    assert_eq!(seen, (0..7).map(|i| format!("s{i:02}")).collect::<Vec<_>>());
    assert_eq!(snapshot(&whole), snapshot(&sharded));
    let (code, v) = status(&sharded);
    assert_eq!(code, Some(0), "{v}");
    assert_eq!(v["counts"]["done"], 7);
    // A second pass of any shard renders nothing.
    let o = render_dataset(&sc, &sharded, &["--shard", "1/4"]);
    assert!(o.status.success());
    assert_eq!(lines(&o), vec![("s01".to_string(), "skipped".to_string()), ("s05".to_string(), "skipped".to_string())]);
}

/// A different seed is refused by default (nothing written) and replaces the scenes with `rerender`.
#[test]
fn another_configuration_is_refused_or_rerendered() {
    let d = tempfile::tempdir().unwrap();
    let sc = d.path().join("scenes");
    make_scenes(&sc, 2);
    let out = d.path().join("out");
    assert!(render_dataset(&sc, &out, &[]).status.success());
    let before = snapshot(&out);
    let o = render_dataset(&sc, &out, &["--seed", "5"]);
    assert_eq!(o.status.code(), Some(1));
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(e.contains("seed: recorded 0 ≠ requested 5") && e.contains("--on-mismatch rerender") && e.contains("s00"), "{e}");
    assert!(o.stdout.is_empty());
    assert_eq!(snapshot(&out), before, "refusal wrote something");
    // Sampling, mask and output-set changes are mismatches too.
    for extra in [&["--sampling", "independent"][..], &["--opening", "0.4"][..], &["--mask-seed", "1"][..], &["--cube"][..]] {
        let o = render_dataset(&sc, &out, extra);
        assert_eq!(o.status.code(), Some(1), "{extra:?}");
    }
    let o = render_dataset(&sc, &out, &["--seed", "5", "--on-mismatch", "rerender"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(lines(&o).iter().filter(|(_, s)| s == "rendered").count(), 2);
    let fresh = d.path().join("fresh");
    assert!(render_dataset(&sc, &fresh, &["--seed", "5"]).status.success());
    assert_eq!(snapshot(&out), snapshot(&fresh));
    assert_eq!(status(&out).0, Some(0));
}

/// dataset-status finds truncated EXR/NPY, a bad render.json, missing files and leftovers; render-dataset
/// then renders exactly the damaged and missing scenes and removes what killed tasks left.
#[test]
fn status_finds_corruption_and_a_rerun_repairs_it() {
    let d = tempfile::tempdir().unwrap();
    let sc = d.path().join("scenes");
    make_scenes(&sc, 6);
    let out = d.path().join("out");
    assert!(render_dataset(&sc, &out, &[]).status.success());
    let reference = snapshot(&out);
    let cut = |p: PathBuf, keep: usize| {
        let b = std::fs::read(&p).unwrap();
        std::fs::write(&p, &b[..keep.min(b.len() - 1)]).unwrap();
    };
    cut(out.join("s00/acquisition.exr"), 200);
    cut(out.join("mapping.npy"), 100);
    let j = out.join("s01/render.json");
    let text = std::fs::read_to_string(&j).unwrap().replace("\"rays_per_pixel\": 2", "\"rays_per_pixel\": 3");
    std::fs::write(&j, text).unwrap();
    cut(out.join("s02/render.json"), 50);
    std::fs::remove_file(out.join("s03/acquisition.png")).unwrap();
    std::fs::remove_dir_all(out.join("s04")).unwrap();
    // What a task killed in the middle of s04 leaves.
    std::fs::create_dir_all(out.join(".s04.partial-node7-4242")).unwrap();
    std::fs::write(out.join(".s04.partial-node7-4242/acquisition.exr"), b"half").unwrap();

    let (code, v) = status(&out);
    assert_eq!(code, Some(1));
    let st = |s: &str| v["scenes"].as_array().unwrap().iter().find(|x| x["scene"] == s).unwrap().clone();
    assert_eq!(v["counts"], serde_json::json!({"scenes": 6, "done": 1, "missing": 1, "corrupt": 4}));
    assert_eq!(v["shared"]["status"], "corrupt");
    assert!(v["shared"]["problems"][0].as_str().unwrap().contains("mapping.npy: 100 bytes"), "{v}");
    assert!(st("s00")["problems"][0].as_str().unwrap().contains("acquisition.exr: 200 bytes"), "{v}");
    assert!(st("s01")["problems"][0].as_str().unwrap().contains("rays_per_pixel: recorded 3 ≠ requested 2"), "{v}");
    assert!(st("s02")["problems"][0].as_str().unwrap().contains("not valid JSON"), "{v}");
    assert!(st("s03")["problems"][0].as_str().unwrap().contains("acquisition.png: missing"), "{v}");
    assert_eq!(st("s04")["status"], "missing");
    assert_eq!(st("s05")["status"], "done");
    assert_eq!(v["leftovers"].as_array().unwrap().len(), 1);
    // The text form names the problems too, and the scene list can come from the scenes folder.
    let o = run(&["dataset-status", out.to_str().unwrap(), "--scenes", sc.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let t = String::from_utf8_lossy(&o.stdout);
    assert!(t.contains("corrupt  s00: acquisition.exr") && t.contains("missing  s04") && t.contains("1 done, 1 missing, 4 corrupt"), "{t}");

    // s01 mismatches (its render.json claims 3 rays): refused by default, repaired with rerender. The
    // damaged ones are rendered again in any case.
    assert_eq!(render_dataset(&sc, &out, &[]).status.code(), Some(1));
    let o = render_dataset(&sc, &out, &["--on-mismatch", "rerender"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut rendered: Vec<String> = lines(&o).into_iter().filter(|(_, s)| s == "rendered").map(|(n, _)| n).collect();
    rendered.sort();
    assert_eq!(rendered, ["s00", "s01", "s02", "s03", "s04"]);
    assert_eq!(snapshot(&out), reference);
    let (code, v) = status(&out);
    assert_eq!(code, Some(0), "{v}");
    assert!(v["leftovers"].as_array().unwrap().is_empty());
}

/// A scene that cannot be read fails alone: a `failed` line, no folder, the others rendered, exit 1.
#[test]
fn a_failing_scene_does_not_stop_the_others() {
    let d = tempfile::tempdir().unwrap();
    let sc = d.path().join("scenes");
    make_scenes(&sc, 3);
    std::fs::write(sc.join("s01.npy"), b"\x93NUMPY broken").unwrap();
    let out = d.path().join("out");
    let o = render_dataset(&sc, &out, &[]);
    assert_eq!(o.status.code(), Some(1));
    let v: Vec<serde_json::Value> = String::from_utf8_lossy(&o.stdout).lines().map(|l| serde_json::from_str(l).unwrap()).collect();
    assert_eq!(v.len(), 3);
    assert_eq!(v[1]["status"], "failed");
    assert!(v[1]["error"].as_str().unwrap().contains("s01.npy"), "{}", v[1]);
    assert!(!out.join("s01").exists());
    assert!(out.join("s02/render.json").is_file());
    assert!(diffcassi::render::dataset::leftovers(&out).is_empty());
    assert_eq!(status(&out).1["counts"]["missing"], 1);
}

/// A scene whose output folder would take a name of the dataset's own outputs (`mapping.npy.npy` → the folder
/// `mapping.npy`, replacing the shared mapping cube; `dataset.json.npy` → the manifest, after which no run could
/// resume) is refused before anything is written, naming the scene and the reserved names (found by a held-out
/// battery: such a run replaced the shared outputs and exited 0).
#[test]
fn a_scene_named_like_a_shared_output_is_refused() {
    for reserved in diffcassi::render::dataset::ROOT_OUTPUTS {
        let d = tempfile::tempdir().unwrap();
        let sc = d.path().join("scenes");
        make_scenes(&sc, 1);
        std::fs::copy(sc.join("s00.npy"), sc.join(format!("{reserved}.npy"))).unwrap();
        let out = d.path().join("out");
        let o = render_dataset(&sc, &out, &[]);
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{reserved}: {e}");
        assert!(e.contains(&format!("{reserved}.npy")) && e.contains(&format!("named `{reserved}`")) && e.contains("rename the scene"), "{reserved}: {e}");
        assert!(!out.exists(), "{reserved}: the refused run wrote {}", out.display());
    }
}
