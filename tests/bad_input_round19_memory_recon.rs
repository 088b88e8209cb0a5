//! Round 19 of the held-out battery (3 Dec 2026, prober A, findings 1–3): the memory budget (`--max-memory-gb`)
//! left out what `reconstruct` and `render-dataset` really hold. `reconstruct` with the exact operator checked
//! the render record alone (estimate/peak 0.12–0.31; 1.52 GB under a 0.5 GB budget): the operator's kept
//! transport and the planes in flight were not counted. `render-dataset` cached its transport beside the budget.
//! The PnP solvers checked the denoiser's activations against the whole budget while the solver's arrays and the
//! record were resident (0.92 GB under 0.5 GB). Now what the process holds is registered
//! ([`diffcassi::limits::hold`]) and every check counts it; the exact operator's estimate is the library's
//! ([`diffcassi::recon::exact::TransportMemory`]), used by the CLI, `render-dataset` and Python alike.
use crate::cli_run::{ok_cli as ok, run_cli};

/// The first "needs an estimated X GB of memory, over the budget of B GB (…)[ with the Y GB held already]" of a
/// refusal: (X, Y).
fn estimate(out: &str) -> (f64, f64) {
    let num = |s: &str| s.trim().trim_end_matches("GB").trim().parse::<f64>().unwrap_or_else(|_| panic!("`{s}` in {out}"));
    let rest = out.split("needs an estimated ").nth(1).unwrap_or_else(|| panic!("no estimate in: {out}"));
    let x = num(rest.split(" of memory").next().unwrap());
    let message = rest.split("; reduce").next().unwrap();
    let y = match message.split(" with the ").nth(1) {
        Some(b) if b.contains(" held already") => num(b.split(" held already").next().unwrap()),
        _ => 0.0,
    };
    (x, y)
}

fn render(dir: &std::path::Path, n: &str, planes: &str, rays: &str) {
    ok(dir, &["render", "--preset", "sp", "--scene-size", n, "--planes", planes, "--rays", rays, "--no-mapping", "--out", "r"]);
}

/// Raise the budget past each refusal that does not contain `stop` (every check the old code had too), from
/// 1e-9 GB: returns the budget (GB) at which the refusal names `stop`, and that refusal.
fn climb(run: &dyn Fn(f64) -> (Option<i32>, String), stop: &str) -> (f64, String) {
    let mut budget = 1e-9;
    for _ in 0..30 {
        let (code, out) = run(budget);
        assert_eq!(code, Some(1), "accepted at {budget} GB before any check named `{stop}`: {out}");
        assert!(!out.contains("panicked"), "{out}");
        if out.contains(stop) {
            return (budget, out);
        }
        let (x, y) = estimate(&out);
        budget = ((x + y) * 1.02).max(budget * 1.05);
    }
    panic!("no refusal named `{stop}`");
}

/// Finding 1: a budget every earlier check passes (the record, the renderer: all the old code checked) but
/// below the record plus the exact operator's transport is refused, naming the transport and its option;
/// `--transport-memory-gb 0` (no transport kept) lowers the estimate; a budget above the whole estimate runs.
#[test]
fn reconstruct_counts_the_exact_operators_transport() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    render(d, "48", "56", "2");
    let rec = |gb: f64, extra: &[&str]| {
        let g = format!("{gb:e}");
        let mut a = vec!["--max-memory-gb", g.as_str(), "reconstruct", "--from", "r", "--iterations", "1", "--out", "o"];
        a.extend_from_slice(extra);
        run_cli(d, &a)
    };
    let (budget, out) = climb(&|gb| rec(gb, &[]), "the exact operator of");
    assert!(out.contains("the exact operator of a 48×48 scene × 56 planes × 2 rays") && out.contains("light transport kept") && out.contains("--transport-memory-gb"), "{out}");
    assert!(out.contains("held already (the render record of"), "{out}");
    let (op, beside) = estimate(&out);
    assert!(op > 0.0 && beside > 0.0 && op + beside > budget, "{out}");
    // Nothing kept: a smaller estimate (the planes in flight only).
    let (_, out0) = rec(budget, &["--transport-memory-gb", "0"]);
    if out0.contains("the exact operator of") {
        let (op0, _) = estimate(&out0);
        assert!(out0.contains("re-traced at every apply and adjoint") && op0 < op, "{op0} vs {op}: {out0}");
    }
    // Above the whole estimate (operator, its twin, the record): runs.
    let (code, out) = rec(3.0 * (op + beside), &[]);
    assert_eq!(code, Some(0), "{out}");
}

/// Finding 3: the denoiser's activations are checked beside the solver's arrays and the record; a budget every
/// other check passes and above the activations alone (what the old code compared) but below their sum is
/// refused, naming the denoiser and what is held; a budget above the sum runs.
#[test]
fn the_denoiser_is_checked_beside_the_solvers_arrays() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    render(d, "64", "28", "1");
    let pnp = |gb: f64| {
        let g = format!("{gb:e}");
        run_cli(d, &["--max-memory-gb", &g, "reconstruct", "--from", "r", "--operator", "shift", "--solver", "pnp-gap", "--iterations", "2", "--tv-warmup", "1", "--out", "o"])
    };
    let (budget, out) = climb(&pnp, "denoiser on a 64×64×28 cube (activations)");
    assert!(out.contains("solver's arrays") && out.contains("the render record of") && out.contains("held already"), "{out}");
    let (activations, held) = estimate(&out);
    // What the old code accepted: every other check passed (at `budget`) and the activations alone fit.
    let old_ok = budget.max(activations * 1.02);
    assert!(old_ok < activations + held, "{old_ok} {activations} {held}");
    let (code, out) = pnp(old_ok);
    assert_eq!(code, Some(1), "{out}");
    assert!(out.contains("denoiser on a 64×64×28 cube") && out.contains("held already"), "{out}");
    let (code, out) = pnp(1.5 * (activations + held));
    assert_eq!(code, Some(0), "{out}");
}

/// Finding 2: `render-dataset`'s transport cache counts against `--max-memory-gb`: under a budget that holds
/// each scene's render but not the cache beside it, the scenes are traced one by one (the same numbers), and
/// the record says so; under a larger budget the cache is kept.
#[test]
fn render_dataset_keeps_its_cache_within_the_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    std::fs::create_dir(d.join("scenes")).unwrap();
    crate::common::two_small_scenes(&d.join("scenes"));
    let ds = |gb: Option<f64>, out: &str| {
        let g = gb.map(|g| format!("{g:e}"));
        let mut a: Vec<&str> = Vec::new();
        if let Some(g) = &g {
            a.extend(["--max-memory-gb", g.as_str()]);
        }
        a.extend(["render-dataset", "--preset", "sp", "--scenes", "scenes", "--scene-size", "32", "--fit", "resize", "--planes", "112", "--rays", "4", "--no-mapping", "--out", out]);
        run_cli(d, &a)
    };
    // The smallest budget the render's own checks pass (each refusal's estimate, raised past in turn).
    let mut budget = 1e-9;
    let (code, out) = loop {
        let _ = std::fs::remove_dir_all(d.join("tight"));
        let (code, out) = ds(Some(budget), "tight");
        if code == Some(0) {
            break (code, out);
        }
        assert_eq!(code, Some(1), "{out}");
        let (x, y) = estimate(&out);
        assert!((x + y) * 1.02 > budget, "{out}");
        budget = (x + y) * 1.02;
    };
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("light transport would need") && out.contains("over the memory budget") && out.contains("tracing each scene"), "{out}");
    let cached = |dir: &str| -> bool {
        let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join(dir).join("s0").join("render.json")).unwrap()).unwrap();
        j["transport_cached"].as_bool().unwrap()
    };
    assert!(!cached("tight"));
    let (code, out) = ds(None, "roomy");
    assert_eq!(code, Some(0), "{out}");
    assert!(cached("roomy"), "{out}");
    // The same acquisitions either way.
    let sha = |dir: &str, s: &str| -> String {
        let j: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(d.join(dir).join(s).join("render.json")).unwrap()).unwrap();
        j["acquisition_f32le_sha256"].as_str().unwrap().to_string()
    };
    for s in ["s0", "s1"] {
        assert_eq!(sha("tight", s), sha("roomy", s), "{s}: the acquisition differs with the cache");
    }
}

/// The ledger itself: what is held counts in every check and is released when dropped.
#[test]
fn held_memory_counts_until_released() {
    let name = "round 19's test buffer";
    let h = diffcassi::limits::hold(name, 5e8);
    let (now, terms) = diffcassi::limits::held_now();
    assert!(now >= 5e8 && terms.iter().any(|t| t == &format!("{name} 0.50 GB")), "{terms:?}");
    drop(h);
    let (_, terms) = diffcassi::limits::held_now();
    assert!(!terms.iter().any(|t| t.starts_with(name)), "{terms:?}");
}
