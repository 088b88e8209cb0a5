//! Round 16 (2 Dec 2026): concurrent runs into one output folder and the Slurm variables' messages (a
//! held-out battery). Two `render-dataset` runs with different settings both found no dataset.json, both
//! wrote and both exited 0 over a mixed folder; two `study` runs mixed their cells in one study.csv; a bad
//! `SLURM_ARRAY_TASK_COUNT` was reported under `SLURM_ARRAY_TASK_ID`. Every test here holds the folder's
//! lock itself (no race between two runs decides its outcome): a run that finds the lock held says so on
//! stderr, and the test releases the lock once every run has said it.
use diffcassi::io::lock::{lock_folder, FolderLock, LockAttempt};
use diffcassi::scene;
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

const OPTS: [&str; 10] = ["--preset", "sp", "--scene-size", "16", "--planes", "4", "--bands", "450:650:4", "--rays", "2"];
const WAITING: &str = "waiting for another render-dataset run";

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_diffcassi"));
    for v in ["SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "SLURM_ARRAY_TASK_MIN", "SLURM_ARRAY_TASK_MAX", "SLURM_ARRAY_TASK_STEP", "DIFFCASSI_DEBUG_SCENE_DELAY_MS"] {
        c.env_remove(v);
    }
    c
}

fn make_scenes(dir: &Path, n: usize) {
    std::fs::create_dir_all(dir).unwrap();
    let ws = scene::synthetic_wavelengths();
    for i in 0..n {
        scene::save_npy(&scene::synthetic_scene(16, 16, &ws, i as u64), &dir.join(format!("s{i:02}.npy"))).unwrap();
    }
}

fn hold(dir: &Path) -> FolderLock {
    std::fs::create_dir_all(dir).unwrap();
    match lock_folder(dir, false).unwrap() {
        LockAttempt::Held(l) => l,
        other => panic!("cannot lock {}: {other:?}", dir.display()),
    }
}

/// A `render-dataset` run started in the background; its stderr is read line by line.
struct Bg {
    child: Child,
    lines: std::sync::mpsc::Receiver<String>,
    stderr: String,
}

fn spawn_dataset(scenes: &Path, out: &Path, extra: &[&str]) -> Bg {
    let mut c = bin();
    c.args(["render-dataset", "--scenes", scenes.to_str().unwrap(), "--out", out.to_str().unwrap(), "--threads", "1"]).args(OPTS).args(extra);
    let mut child = c.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().unwrap();
    let err = child.stderr.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(err).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    Bg { child, lines: rx, stderr: String::new() }
}

impl Bg {
    /// Read stderr until a line holds `needle` (a minute at most: the runs block on the lock, not on a timer).
    fn wait_for(&mut self, needle: &str) {
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(60) {
            match self.lines.recv_timeout(Duration::from_millis(100)) {
                Ok(l) => {
                    self.stderr.push_str(&l);
                    self.stderr.push('\n');
                    if l.contains(needle) {
                        return;
                    }
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                Err(_) => panic!("the run ended before `{needle}`: {}", self.stderr),
            }
        }
        panic!("no `{needle}` within a minute: {}", self.stderr);
    }

    fn finish(mut self) -> (Option<i32>, String) {
        let code = self.child.wait().unwrap().code();
        while let Ok(l) = self.lines.recv_timeout(Duration::from_secs(10)) {
            self.stderr.push_str(&l);
            self.stderr.push('\n');
        }
        (code, self.stderr)
    }
}

fn status_clean(out: &Path, scenes: usize) -> serde_json::Value {
    let o = bin().args(["dataset-status", out.to_str().unwrap(), "--json"]).output().unwrap();
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or(serde_json::Value::Null);
    assert_eq!(o.status.code(), Some(0), "{v}\n{}", String::from_utf8_lossy(&o.stderr));
    let m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(m["scenes"].as_array().unwrap().len(), scenes);
    m
}

/// Two runs with different seeds into one folder, both waiting on its lock: exactly one claims the folder
/// and renders; the other sees its dataset.json and is refused as a mismatch (exit 1, nothing written).
/// Both exited 0 before, with dataset.json recording one seed over the other's scenes.
#[test]
fn two_configurations_into_one_dataset_folder_one_is_refused() {
    let d = tempfile::tempdir().unwrap();
    let (sc, out) = (d.path().join("sc"), d.path().join("out"));
    make_scenes(&sc, 3);
    let lock = hold(&out);
    let mut a = spawn_dataset(&sc, &out, &["--seed", "0"]);
    let mut b = spawn_dataset(&sc, &out, &["--seed", "1"]);
    a.wait_for(WAITING);
    b.wait_for(WAITING);
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "nothing written while the lock is held");
    drop(lock);
    let (ca, ea) = a.finish();
    let (cb, eb) = b.finish();
    let (won, lost, lost_err) = match (ca, cb) {
        (Some(0), Some(1)) => (0, 1, eb),
        (Some(1), Some(0)) => (1, 0, ea),
        _ => panic!("exactly one run must succeed: {ca:?} {cb:?}\n{ea}\n{eb}"),
    };
    assert!(lost_err.contains("rendered with another configuration") && lost_err.contains("dataset.json") && lost_err.contains("seed") && lost_err.contains("Nothing was written"), "{lost_err}");
    let m = status_clean(&out, 3);
    assert_eq!(m["configuration"]["seed"], serde_json::json!(won), "{m}");
    for i in 0..3 {
        let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join(format!("s{i:02}/render.json"))).unwrap()).unwrap();
        assert_eq!(r["configuration"]["seed"], serde_json::json!(won));
        assert_ne!(r["configuration"]["seed"], serde_json::json!(lost));
    }
}

/// Shards of one configuration (a Slurm array) waiting on the folder's lock together all render their scenes
/// (the lock is held only to check and claim the folder, and to move each scene in).
#[test]
fn concurrent_shards_of_one_configuration_still_work() {
    let d = tempfile::tempdir().unwrap();
    let (sc, out) = (d.path().join("sc"), d.path().join("out"));
    make_scenes(&sc, 4);
    let lock = hold(&out);
    let mut shards: Vec<Bg> = (0..2).map(|k| spawn_dataset(&sc, &out, &["--shard", &format!("{k}/2")])).collect();
    for s in &mut shards {
        s.wait_for(WAITING);
    }
    drop(lock);
    for s in shards {
        let (code, err) = s.finish();
        assert_eq!(code, Some(0), "{err}");
    }
    status_clean(&out, 4);
}

/// A run that claimed the folder loses it to a run with other settings and `--on-mismatch rerender` while
/// rendering: its scene is not moved in under the other configuration's dataset.json (the scene fails,
/// exit 1, naming the claim). The test plays the other run: it takes the lock while the scene waits to be
/// moved in, and records another seed in dataset.json.
#[test]
fn a_scene_is_not_committed_under_another_runs_claim() {
    let d = tempfile::tempdir().unwrap();
    let (sc, out) = (d.path().join("sc"), d.path().join("out"));
    make_scenes(&sc, 1);
    let mut c = bin();
    c.env("DIFFCASSI_DEBUG_SCENE_DELAY_MS", "3000");
    c.args(["render-dataset", "--scenes", sc.to_str().unwrap(), "--out", out.to_str().unwrap(), "--threads", "1", "--seed", "0"]).args(OPTS);
    let mut child = c.stdout(Stdio::piped()).stderr(Stdio::piped()).spawn().unwrap();
    // The scene's temporary folder is complete (render.json written last): the run now waits to move it in.
    let t = Instant::now();
    let lock = loop {
        let partial = std::fs::read_dir(&out).ok().into_iter().flatten().flatten().find(|e| e.file_name().to_string_lossy().starts_with(".s00.partial-"));
        if partial.is_some_and(|p| p.path().join("render.json").exists()) {
            break hold(&out);
        }
        assert!(t.elapsed() < Duration::from_secs(60) && child.try_wait().unwrap().is_none(), "no complete temporary folder");
        std::thread::sleep(Duration::from_millis(5));
    };
    let path = out.join("dataset.json");
    let mut m: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    m["configuration"]["seed"] = serde_json::json!(7);
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    drop(lock);
    let o = child.wait_with_output().unwrap();
    // The scene's JSON line on stdout says why it failed.
    let err = format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr));
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("another render-dataset run claimed this folder for another configuration") && err.contains("seed"), "{err}");
    assert!(!out.join("s00").exists(), "the scene was moved in under the other claim");
}

fn study_args(out: &Path, iterations: &str) -> Vec<String> {
    ["study", "--synthetic", "1", "--scene-size", "16", "--presets", "sp", "--operators", "shift", "--bands", "450:650:4", "--planes", "4", "--rays", "1", "--iterations", iterations, "--out", out.to_str().unwrap()].iter().map(|s| s.to_string()).collect()
}

fn run_study(out: &Path, iterations: &str) -> (Option<i32>, String) {
    let o = bin().args(study_args(out, iterations)).output().unwrap();
    (o.status.code(), format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr)))
}

/// A study holds its folder's lock for the whole run: a second study on the folder meanwhile is refused
/// (exit 1, naming the other study, nothing written); once the first ends (the lock is released, also when
/// killed) a study on the folder, with other settings or not, runs as before.
#[test]
fn a_study_is_refused_while_another_writes_its_folder() {
    let d = tempfile::tempdir().unwrap();
    let out = d.path().join("study");
    let lock = hold(&out);
    let (code, text) = run_study(&out, "2");
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("another study is writing this folder") && text.contains("nothing was written"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    assert_eq!(std::fs::read_dir(&out).unwrap().count(), 0, "nothing written");
    drop(lock);
    let (code, text) = run_study(&out, "2");
    assert_eq!(code, Some(0), "{text}");
    let csv = std::fs::read(out.join("study.csv")).unwrap();
    let marker = std::fs::read(out.join("study.json")).unwrap();
    // A finished study, resumed with other settings while another study holds the folder: refused, untouched.
    let lock = hold(&out);
    let (code, text) = run_study(&out, "1");
    assert_eq!(code, Some(1), "{text}");
    assert!(text.contains("another study is writing this folder"), "{text}");
    assert_eq!(std::fs::read(out.join("study.csv")).unwrap(), csv);
    assert_eq!(std::fs::read(out.join("study.json")).unwrap(), marker);
    drop(lock);
    let (code, text) = run_study(&out, "1");
    assert_eq!(code, Some(0), "{text}");
    let marker: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("study.json")).unwrap()).unwrap();
    assert_eq!(marker["configuration"]["iterations"], serde_json::json!(1));
}

/// Each Slurm message names the variable whose value is bad (exit 2, nothing written): a count of 0 was
/// reported under SLURM_ARRAY_TASK_ID, an empty count as "not set", an empty SLURM_ARRAY_TASK_MAX accepted.
#[test]
fn slurm_messages_name_the_bad_variable() {
    let d = tempfile::tempdir().unwrap();
    let (sc, out) = (d.path().join("sc"), d.path().join("out"));
    make_scenes(&sc, 1);
    let cases: [(&[(&str, &str)], &str, &str); 4] = [
        (&[("SLURM_ARRAY_TASK_ID", "1"), ("SLURM_ARRAY_TASK_COUNT", "0")], "SLURM_ARRAY_TASK_COUNT=0: the shard count N must be ≥ 1", "SLURM_ARRAY_TASK_ID=1:"),
        (&[("SLURM_ARRAY_TASK_ID", "1"), ("SLURM_ARRAY_TASK_COUNT", "")], "SLURM_ARRAY_TASK_COUNT is set but empty", "not set"),
        (&[("SLURM_ARRAY_TASK_ID", "0"), ("SLURM_ARRAY_TASK_COUNT", "2"), ("SLURM_ARRAY_TASK_MAX", "")], "SLURM_ARRAY_TASK_MAX is set but empty", "not set"),
        (&[("SLURM_ARRAY_TASK_ID", "2"), ("SLURM_ARRAY_TASK_COUNT", "2")], "SLURM_ARRAY_TASK_ID=2 with SLURM_ARRAY_TASK_COUNT=2: shard index 2 is out of range", "panicked"),
    ];
    for (vars, needle, absent) in cases {
        let mut c = bin();
        for (k, v) in vars {
            c.env(k, v);
        }
        let o = c.args(["render-dataset", "--scenes", sc.to_str().unwrap(), "--out", out.to_str().unwrap(), "--shard", "slurm"]).args(OPTS).output().unwrap();
        let e = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{vars:?}: {e}");
        assert!(e.contains(needle) && !e.contains(absent), "{vars:?}: {e}");
        assert!(!out.exists(), "nothing written");
    }
}
