//! `diffcassi ghosts` (issue 23): the CSV interface, the JSON and PNG, and bad input.
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_diffcassi")).args(args).output().expect("the binary runs")
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("diffcassi-ghosts-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

fn csv(path: &Path) -> (Vec<String>, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty());
    let header = lines.next().unwrap().split(',').map(String::from).collect();
    (header, lines.map(|l| l.split(',').map(String::from).collect()).collect())
}

#[test]
fn ghosts_interface_on_sp_and_ap() {
    for preset in ["sp", "ap"] {
        let (c, j, p) = (tmp(&format!("{preset}.csv")), tmp(&format!("{preset}.json")), tmp(&format!("{preset}.png")));
        let o = run(&["ghosts", "--preset", preset, "--order", "2", "--rings", "2", "--extended-grid", "2", "--csv", c.to_str().unwrap(), "--json", j.to_str().unwrap(), "--png", p.to_str().unwrap()]);
        assert!(o.status.success(), "{}", text(&o));
        let out = text(&o);
        assert!(out.contains("scalar model vs polarised"), "{out}");
        let (h, rows) = csv(&c);
        for col in ["path", "energy_fraction", "x_mm", "y_mm"] {
            assert!(h.iter().any(|x| x == col), "column {col} in {h:?}");
        }
        assert!(!rows.is_empty(), "{preset}: no ghost path");
        let ip = h.iter().position(|x| x == "path").unwrap();
        let ie = h.iter().position(|x| x == "energy_fraction").unwrap();
        let mut seen = std::collections::HashSet::new();
        for r in &rows {
            assert!(seen.insert(r[ip].clone()), "one row per path: {}", r[ip]);
            assert!(r[ip].split(' ').all(|s| s.ends_with('R') && s[..s.len() - 1].parse::<u32>().is_ok()), "path label {}", r[ip]);
            let e: f64 = r[ie].parse().unwrap();
            // Two Fresnel reflections of bare glass: well below 1 % of the main image each.
            assert!(e > 0.0 && e < 0.01, "{preset} {}: {e}", r[ip]);
        }
        let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&j).unwrap()).unwrap();
        assert!(v["ledger"]["launched"].as_f64().unwrap() > 0.0);
        assert!(v["scalar_max_relative_error"].as_f64().unwrap() >= 0.0);
        assert!(v["paths"].as_array().unwrap().iter().any(|p| p["source"] == "uniform"));
        assert!(std::fs::metadata(&p).unwrap().len() > 100);
    }
}

#[test]
fn bad_input_writes_nothing() {
    let c = tmp("bad.csv");
    let o = run(&["ghosts", "--preset", "sp", "--order", "5", "--csv", c.to_str().unwrap()]);
    // A usage error (exit 2), as `render --ghosts 5`.
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("--order") && text(&o).contains("ghost order 5") && text(&o).contains("at most 4"), "{}", text(&o));
    assert!(!c.exists());
    // A coating reflectance outside [0, 1] in the spec.
    let spec = tmp("coated.toml");
    let e = run(&["export-spec", "--preset", "sp", "--out", spec.to_str().unwrap()]);
    assert!(e.status.success());
    let t = std::fs::read_to_string(&spec).unwrap();
    // The first refracting surface after the object: add a coating line to the second [[surfaces]] table.
    let k = t.match_indices("[[surfaces]]").nth(1).unwrap().0 + "[[surfaces]]\n".len();
    let bad = format!("{}coating = {{ reflectance = -0.2 }}\n{}", &t[..k], &t[k..]);
    std::fs::write(&spec, bad).unwrap();
    let o = run(&["ghosts", "--system", spec.to_str().unwrap(), "--csv", c.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("coating") && text(&o).contains("-0.2") && text(&o).contains("[0, 1]"), "{}", text(&o));
    assert!(!c.exists());
}
