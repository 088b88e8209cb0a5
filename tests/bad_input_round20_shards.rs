//! Round 20 of the held-out battery, prober C: a scene added to `--scenes` in the middle of a Slurm array.
//! Each task partitioned its own fresh, sorted folder listing: `a04.npy`, sorting first, shifted every index,
//! so shard 1/2 held s00 and s02 (shard 0's), skipped them as done and exited 0, and its own s01 and s03 were
//! never rendered. Shards now index the list `dataset.json` recorded, new scenes appended
//! (`render::dataset::SceneOrder`), and a recorded scene gone from the folder keeps its place.
use crate::cli_run::{ok_cli as ok, run_cli as run};
use diffcassi::render::dataset::{DatasetScene, SceneOrder, Shard};
use diffcassi::scene;
use std::path::Path;

const ARGS: [&str; 14] = ["render-dataset", "--preset", "sp", "--scenes", "sc", "--scene-size", "16", "--planes", "8", "--rays", "2", "--threads", "1", "--out"];

fn dataset(dir: &Path, extra: &[&str]) -> (Option<i32>, String) {
    let mut v: Vec<&str> = ARGS.to_vec();
    v.push("ds");
    v.extend_from_slice(extra);
    run(dir, &v)
}

fn add_scene(dir: &Path, name: &str, seed: u64) {
    let ws = scene::synthetic_wavelengths();
    scene::save_npy(&scene::synthetic_scene(16, 16, &ws, seed), &dir.join("sc").join(format!("{name}.npy"))).unwrap();
}

/// (scene, status) of each JSON line of a run's output.
fn lines(out: &str) -> Vec<(String, String)> {
    out.lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("not JSON: {l}: {e}"));
            (v["scene"].as_str().unwrap().to_string(), v["status"].as_str().unwrap().to_string())
        })
        .collect()
}

fn pairs(v: &[(&str, &str)]) -> Vec<(String, String)> {
    v.iter().map(|(a, b)| (a.to_string(), b.to_string())).collect()
}

fn recorded_list(dir: &Path) -> Vec<String> {
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(dir.join("ds/dataset.json")).unwrap()).unwrap();
    v["scenes"].as_array().unwrap().iter().map(|s| s.as_str().unwrap().to_string()).collect()
}

fn four_scenes() -> tempfile::TempDir {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("sc")).unwrap();
    for i in 0..4 {
        add_scene(d.path(), &format!("s{i:02}"), i);
    }
    d
}

/// The repro: shard 0/2 over s00…s03, then `a04` (sorting first) added, then shard 1/2. Shard 1/2 must render
/// its own s01 and s03 (it skipped shard 0's s00 and s02, exit 0), say what it did with a04, and record it
/// at the end of the list; a04 falls to shard 0 (index 4), which renders it next; dataset-status agrees.
#[test]
fn a_scene_added_mid_array_keeps_every_recorded_scene_on_its_shard() {
    let d = four_scenes();
    let dir = d.path();
    let (code, out) = dataset(dir, &["--shard", "0/2"]);
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(lines(&out), pairs(&[("s00", "rendered"), ("s02", "rendered")]));
    add_scene(dir, "a04", 4);
    let (code, out) = dataset(dir, &["--shard", "1/2"]);
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(lines(&out), pairs(&[("s01", "rendered"), ("s03", "rendered")]), "{out}");
    assert!(out.contains("1 scene(s) in sc are new since dataset.json recorded its list (a04): appended as scene 4 of the list"), "{out}");
    assert_eq!(recorded_list(dir), ["s00", "s01", "s02", "s03", "a04"]);
    // dataset-status --scenes checks the same list: a04 missing, listed last.
    let (code, out) = run(dir, &["dataset-status", "ds", "--scenes", "sc"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("missing  a04") && out.contains("5 scenes: 4 done, 1 missing"), "{out}");
    assert!(out.find("s03").unwrap() < out.find("a04").unwrap(), "{out}");
    let (code, out) = dataset(dir, &["--shard", "0/2"]);
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(lines(&out), pairs(&[("s00", "skipped"), ("s02", "skipped"), ("a04", "rendered")]), "{out}");
    ok(dir, &["dataset-status", "ds", "--scenes", "sc"]);
    // A second resubmission renders nothing.
    let (code, out) = dataset(dir, &["--shard", "1/2"]);
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(lines(&out), pairs(&[("s01", "skipped"), ("s03", "skipped")]), "{out}");
}

/// A recorded scene removed from the folder keeps its place (s03 stays on shard 1, not moved to shard 0):
/// its shard reports it failed (it cannot render it), renders its other scenes and exits 1; dataset-status
/// --scenes reports it missing with a note. One already rendered stays done and is skipped.
#[test]
fn a_recorded_scene_gone_from_the_folder_keeps_its_place_and_fails_its_shard() {
    let d = four_scenes();
    let dir = d.path();
    let (code, out) = dataset(dir, &["--shard", "0/2"]);
    assert_eq!(code, Some(0), "{out}");
    std::fs::remove_file(dir.join("sc/s01.npy")).unwrap();
    std::fs::remove_file(dir.join("sc/s00.npy")).unwrap();
    let (code, out) = dataset(dir, &["--shard", "1/2"]);
    assert_eq!(code, Some(1), "{out}");
    assert_eq!(lines(&out), pairs(&[("s01", "failed"), ("s03", "rendered")]), "{out}");
    assert!(out.contains("dataset.json lists the scene but sc no longer holds it"), "{out}");
    assert!(out.contains("1 of 2 scenes failed") && out.contains("s01"), "{out}");
    assert_eq!(recorded_list(dir), ["s00", "s01", "s02", "s03"]);
    // s00 was rendered before its file went: done, skipped with a message.
    let (code, out) = dataset(dir, &["--shard", "0/2"]);
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(lines(&out), pairs(&[("s00", "skipped"), ("s02", "skipped")]), "{out}");
    assert!(out.contains("s00: no longer in sc, kept as rendered"), "{out}");
    let (code, out) = run(dir, &["dataset-status", "ds", "--scenes", "sc"]);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("missing  s01: listed in dataset.json but no longer in the --scenes folder"), "{out}");
    assert!(out.contains("done     s00: listed in dataset.json"), "{out}");
    assert!(out.contains("4 scenes: 3 done, 1 missing"), "{out}");
}

/// The order itself: appending keeps every recorded scene's round-robin shard for any shard count, a
/// recorded scene gone keeps its index, duplicates in a damaged list count once, and without a recorded list
/// the order is the folder's sorted one.
#[test]
fn scene_order_appends_new_scenes_after_the_recorded_list() {
    let found = |names: &[&str]| -> Vec<DatasetScene> {
        let mut v: Vec<DatasetScene> = names.iter().map(|n| DatasetScene { name: n.to_string(), path: format!("/x/{n}.npy").into() }).collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    };
    let recorded: Vec<String> = ["s00", "s01", "s02", "s03", "s04"].iter().map(|s| s.to_string()).collect();
    let now = found(&["a05", "s00", "s01", "s03", "s04", "z06", "b07"]);
    let o = SceneOrder::new(Some(&recorded), &now);
    assert_eq!(o.names, ["s00", "s01", "s02", "s03", "s04", "a05", "b07", "z06"]);
    assert_eq!(o.added, ["a05", "b07", "z06"]);
    assert_eq!(o.gone, ["s02"]);
    assert!(o.is_gone("s02") && !o.is_gone("s03"));
    let before = SceneOrder::new(None, &found(&["s00", "s01", "s02", "s03", "s04"]));
    assert_eq!(before.names, recorded);
    assert!(before.added.is_empty() && before.gone.is_empty());
    for n in 1..=6 {
        for k in 0..n {
            let shard = Shard::new(k, n).unwrap();
            let old = before.select(shard);
            let new = o.select(shard);
            assert_eq!(&new[..old.len()], &old[..], "shard {k}/{n}");
        }
    }
    let dup: Vec<String> = ["s01", "s00", "s01"].iter().map(|s| s.to_string()).collect();
    assert_eq!(SceneOrder::new(Some(&dup), &found(&["s00", "s01"])).names, ["s01", "s00"]);
    assert_eq!(SceneOrder::new(None, &now).names, ["a05", "b07", "s00", "s01", "s03", "s04", "z06"]);
}
