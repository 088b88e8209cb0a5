//! `diffcassi bench nonsequential`: where each backend wins (issue 23's benchmark table).
//!
//! ```text
//! diffcassi bench nonsequential [--preset sp | --system SPEC] [--rays N] [--repeat R] [--quick] [--floor] [--csv OUT]
//! ```
//!
//! Rows: **(a)** the system traced sequentially by the analytic SIMD kernel, Embree over analytic user
//! geometry and Embree over meshes (f64 refinement), rays/s; **(b)** the system with ghosts K = 2: ray trees
//! per second through the brute-force kernel and Embree's two scene representations (the analytic kernel
//! has no ghosts); **(c)** mechanics queries (first hit of
//! seeded random rays — origins uniform in the parts' bounding box, directions uniform on the sphere:
//! what scattered stray light asks) at the generated mounts' three resolutions, brute force (every
//! triangle in f64) against Embree (f32 BVH + f64 re-solve of the hit triangle), one thread each; and
//! the **crossover**: the same on a triangle, a square, a cube and one lens tube from 4 to 256 segments, and the triangle count where
//! Embree's time per query falls below brute force's (log–log interpolation). Every Embree hit is compared
//! with brute force's (same part and point within 1e-6 mm) on the rays both ran. With `--floor`, row (a)
//! and then the floor of Embree as the sequential tracer (its own packet queries replayed with oracle
//! callbacks, with the real ones, and the full walk, beside the analytic kernel: `bench_floor`).
use super::args::BenchArgs;
use super::shared::{cpu_interval, cpu_seconds, MIN_CPU_INTERVAL_S};
use crate::analysis::linspace;
use crate::error::{Error, Result};
use crate::geometry::Frame;
use crate::mechanics::parts::{box_solid, ring_solid};
use crate::mechanics::{Mechanics, MechanicsScene, Part, PartKind, SurfaceModel, TriMesh};
use crate::rays::RayBatch;
use crate::spec::{MechanicsResolution, MechanicsSpec};
use crate::system::SequentialSystem;
use crate::tracer::{AnalyticTracer, Tracer};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use crate::io::{CsvValue, CsvWriter};
use std::time::Instant;

/// Seeded random query rays in the bounding box of `m` (enlarged by 20 %).
pub fn query_rays(m: &Mechanics, n: usize, seed: u64) -> Vec<(DVec3, DVec3)> {
    let (lo, hi) = m.parts.iter().map(|p| p.mesh.bounds()).fold((DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)), |(a, b), (l, h)| (a.min(l), b.max(h)));
    let (c, h) = (0.5 * (lo + hi), 0.6 * (hi - lo));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let o = c + h * DVec3::new(rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0));
            let z: f64 = rng.gen_range(-1.0..1.0);
            let a: f64 = rng.gen_range(0.0..std::f64::consts::TAU);
            let r = (1.0 - z * z).max(0.0).sqrt();
            (o, DVec3::new(r * a.cos(), r * a.sin(), z))
        })
        .collect()
}

/// Seconds per query (best of `repeat`) and the hits, brute force then Embree.
struct Timing {
    brute_s: f64,
    embree_s: f64,
    checked: usize,
    mismatches: usize,
}

fn time_queries(m: &Mechanics, rays: &[(DVec3, DVec3)], brute_rays: usize, repeat: usize) -> Result<Timing> {
    let scene = MechanicsScene::new(m)?;
    let sub = &rays[..brute_rays.min(rays.len())];
    let (mut brute_s, mut embree_s) = (f64::INFINITY, f64::INFINITY);
    let mut brute = Vec::new();
    let mut emb = Vec::new();
    for _ in 0..repeat {
        let t = Instant::now();
        brute = sub.iter().map(|(o, d)| m.intersect_brute(*o, *d, 0.0, f64::INFINITY)).collect();
        brute_s = brute_s.min(t.elapsed().as_secs_f64() / sub.len() as f64);
        let t = Instant::now();
        emb = crate::tracer::embree::with_flush_denormals(|| rays.iter().map(|(o, d)| scene.intersect(*o, *d, 0.0, f64::INFINITY, u32::MAX)).collect::<Vec<_>>());
        embree_s = embree_s.min(t.elapsed().as_secs_f64() / rays.len() as f64);
    }
    let mismatches = brute
        .iter()
        .zip(&emb)
        .filter(|(b, e)| match (b, e) {
            (None, None) => false,
            (Some(b), Some(e)) => b.part != e.part || (b.point - e.point).length() > 1e-6,
            _ => true,
        })
        .count();
    Ok(Timing { brute_s, embree_s, checked: sub.len(), mismatches })
}

/// `diffcassi bench nonsequential`.
pub(super) fn bench_nonsequential(a: &BenchArgs) -> Result<()> {
    if a.png.is_some() {
        return Err(Error::invalid("--png belongs to `diffcassi bench tradeoff`"));
    }
    if let Some(b) = &a.backends {
        return Err(Error::invalid(format!(
            "--backends {b}: `bench nonsequential` measures its own rows (the analytic kernel, Embree over user geometry and meshes, brute force); --backends belongs to plain `diffcassi bench`"
        )));
    }
    if let (true, Some(r)) = (a.quick, a.rays) {
        return Err(Error::invalid(format!("--quick sets the workload itself (2000 rays per wavelength); it cannot be combined with --rays {r} (drop one or the other)")));
    }
    let (repeat, rays, wavelengths) = super::commands::bench_counts(a, if a.quick { 1 } else { 3 }, 100_000, 4)?;
    let (spec, base) = match &a.system {
        Some(p) => (crate::spec::load_spec_file(p)?, p.parent().map(|d| d.to_path_buf()).unwrap_or_default()),
        None => (crate::presets::spec(&a.preset)?, std::path::PathBuf::from(".")),
    };
    // The output policy before any work: --csv is a .csv file, never the spec (nor a mesh it names).
    let meshes: Vec<std::path::PathBuf> = spec.mechanics.iter().flat_map(|m| &m.meshes).map(|m| base.join(&m.path)).collect();
    let mut inputs: Vec<(&str, &std::path::Path)> = a.system.iter().map(|p| ("--system", p.as_path())).collect();
    inputs.extend(meshes.iter().map(|p| ("a mesh of --system", p.as_path())));
    super::commands::check_extension("--csv", &a.csv, &["csv"], &inputs)?;
    let system = SequentialSystem::build(&spec)?;
    // User meshes of the spec are loaded (and checked) before anything is measured or written.
    let user = Mechanics::build(&system, &MechanicsSpec { generate: false, ..spec.mechanics.clone().unwrap_or_default() }, &base).or_else(|e| {
        if spec.mechanics.as_ref().map_or(true, |m| m.meshes.is_empty()) {
            Ok(Mechanics::default())
        } else {
            Err(e)
        }
    })?;
    let (rays_a, queries, brute_queries) = if a.quick { (2_000, 2_000, 200) } else { (rays, 100_000, 2_000) };
    check_budget(&system, a, rays_a, wavelengths, repeat, queries, brute_queries)?;
    // "All threads": the pool `--threads` set (default: every core).
    let cores = rayon::current_num_threads();
    let mut csv = CsvWriter::new(a.csv.as_deref().unwrap_or(std::path::Path::new("bench.csv")), &CSV_COLUMNS)?;
    let t0 = Instant::now();
    println!("bench nonsequential: {}, {} mode, best of {repeat}", system.name(), if a.quick { "quick" } else { "full" });

    // (a) Sequential system, every backend, all cores.
    let ws = linspace(450.0, 650.0, wavelengths);
    let batch = RayBatch::seeded_workload(&system, rays_a, &ws, 1000)?;
    println!("\n(a) {} sequential: {} rays, {} threads", system.name(), batch.len(), cores);
    println!("| backend | M rays/s | × analytic time | CPU-s per M rays |");
    println!("|---|---|---|---|");
    let tracers: Vec<Box<dyn Tracer>> = vec![
        Box::new(AnalyticTracer::default()),
        "embree-user".parse::<crate::tracer::BackendConfig>()?.build()?,
        "embree-mesh".parse::<crate::tracer::BackendConfig>()?.build()?,
    ];
    let mut analytic_s = None;
    for t in &tracers {
        t.trace(&system, &batch)?; // scene construction and caches outside the timing
        let (mut best, mut cpu) = (f64::INFINITY, f64::INFINITY);
        for _ in 0..repeat {
            let c = cpu_seconds();
            let s = Instant::now();
            std::hint::black_box(t.trace(&system, &batch)?);
            best = best.min(s.elapsed().as_secs_f64());
            if let Some(d) = cpu_interval(c, cpu_seconds()) {
                cpu = cpu.min(d);
            }
        }
        let base = *analytic_s.get_or_insert(best);
        let n = batch.len() as f64;
        println!("| {} | {:.2} | {:.1}× | {} |", t.name(), n / best / 1e6, best / base, per_m_cpu(cpu, n, 2));
        row(&mut csv, "a", &format!("{} sequential", system.name()), &t.name(), None, cores, Some((best / n, n / best)), Some(best / base))?;
    }
    if a.floor {
        bench_floor(&system, &batch, repeat, cores, &mut csv)?;
        write_csv(a, csv)?;
        println!("bench nonsequential --floor finished in {:.1} s", t0.elapsed().as_secs_f64());
        return Ok(());
    }
    // (b) Ghosts K = 2: each ray's tree (polarised Fresnel, roulette below 1e-7) through each kernel.
    bench_ghosts(&system, &batch, a.quick, repeat, cores, &mut csv)?;

    // (c) Mechanics at the three resolutions.
    println!("\n(c) mechanics queries on {}: first hit of {queries} seeded random rays (brute force: {brute_queries}), 1 thread", system.name());
    println!("| resolution | triangles | brute force µs/query | Embree µs/query | Embree speed-up | hits checked (mismatches) |");
    println!("|---|---|---|---|---|---|");
    for res in [MechanicsResolution::Coarse, MechanicsResolution::Medium, MechanicsResolution::Fine] {
        let mspec = MechanicsSpec { generate: true, resolution: res, meshes: Vec::new(), ..Default::default() };
        let mut m = Mechanics::build(&system, &mspec, &base)?;
        m.parts.extend(user.parts.iter().cloned());
        let rays = query_rays(&m, queries, 23);
        let t = time_queries(&m, &rays, brute_queries, repeat)?;
        let tri = m.triangle_count();
        println!("| {res:?} | {tri} | {:.2} | {:.3} | {:.1}× | {} ({}) |", t.brute_s * 1e6, t.embree_s * 1e6, t.brute_s / t.embree_s, t.checked, t.mismatches);
        row(&mut csv, "c", &format!("mechanics {res:?}"), "brute-f64", Some(tri), 1, Some((t.brute_s, 1.0 / t.brute_s)), None)?;
        row(&mut csv, "c", &format!("mechanics {res:?}"), "embree-f64", Some(tri), 1, Some((t.embree_s, 1.0 / t.embree_s)), Some(t.brute_s / t.embree_s))?;
    }

    // Crossover: one triangle, a square (2), a cube (12), then one lens tube, growing.
    println!("\ncrossover: a triangle, a square, a cube (10 mm), then one lens tube (r 10 mm, 30 mm long); {} queries (brute force: {})", queries / 10, brute_queries);
    println!("| mesh | triangles | brute force µs/query | Embree µs/query | Embree speed-up |");
    println!("|---|---|---|---|---|");
    let mut meshes: Vec<(String, TriMesh)> = vec![
        ("triangle".into(), TriMesh::new(vec![DVec3::ZERO, DVec3::new(10.0, 0.0, 0.0), DVec3::new(0.0, 10.0, 0.0)], vec![[0, 1, 2]])),
        ("square".into(), TriMesh::new(vec![DVec3::ZERO, DVec3::new(10.0, 0.0, 0.0), DVec3::new(10.0, 10.0, 0.0), DVec3::new(0.0, 10.0, 0.0)], vec![[0, 1, 2], [0, 2, 3]])),
        ("cube".into(), box_solid(&Frame::IDENTITY, DVec3::ZERO, DVec3::splat(10.0), 1)),
    ];
    for seg in [4usize, 8, 16, 32, 64, 128, 256] {
        let circle = |r: f64| (0..seg).map(|k| (std::f64::consts::TAU * k as f64 / seg as f64).sin_cos()).map(|(s, c)| (r * c, r * s)).collect::<Vec<_>>();
        meshes.push((format!("tube, {seg} segments"), ring_solid(&Frame::IDENTITY, &circle(10.0), &circle(11.0), 0.0, 30.0, (seg / 4).max(1))));
    }
    let mut curve: Vec<(f64, f64)> = Vec::new();
    for (label, mesh) in meshes {
        let m = Mechanics { parts: vec![Part { name: label.clone(), kind: PartKind::UserMesh, surface: SurfaceModel::Absorbing, mesh }] };
        let rays = query_rays(&m, queries / 10, 29);
        let t = time_queries(&m, &rays, brute_queries, repeat)?;
        let tri = m.triangle_count();
        println!("| {label} | {tri} | {:.3} | {:.3} | {:.2}× |", t.brute_s * 1e6, t.embree_s * 1e6, t.brute_s / t.embree_s);
        row(&mut csv, "crossover", &label, "brute-f64", Some(tri), 1, Some((t.brute_s, 1.0 / t.brute_s)), None)?;
        row(&mut csv, "crossover", &label, "embree-f64", Some(tri), 1, Some((t.embree_s, 1.0 / t.embree_s)), Some(t.brute_s / t.embree_s))?;
        if t.mismatches > 0 {
            println!("  ({} of {} hits differ from brute force)", t.mismatches, t.checked);
        }
        curve.push((tri as f64, t.brute_s / t.embree_s));
    }
    match crossover(&curve) {
        Some(n) => println!("crossover: Embree is faster than brute force from ≈ {n:.0} triangles on"),
        None if curve[0].1 >= 1.0 => println!("crossover: Embree is already faster at {:.0} triangle(s), the smallest mesh measured", curve[0].0),
        None => println!("crossover: Embree is not faster anywhere in the measured range ({:.0}–{:.0} triangles)", curve[0].0, curve[curve.len() - 1].0),
    }
    write_csv(a, csv)?;
    println!("bench nonsequential finished in {:.1} s", t0.elapsed().as_secs_f64());
    Ok(())
}

/// `--floor`: how fast can Embree trace the sequential system at best (docs/nonsequential.md, "Fourth
/// pass"). Embree over analytic user geometry traces (a)'s batch once recording every packet query of its
/// walk; the queries are then replayed, the same packets, by a walk that only advances each lane to its
/// recorded next query, through (i) oracle callbacks that report the recorded hit (no surface solve:
/// Embree's traversal and dispatch, the floor) and (ii) the real callbacks; (iii) is the full tracer, and
/// (0) the replay without any query (its own packet building, part of (i) and (ii)).
/// The rows are measured interleaved (each repeat runs them all in turn), best of `repeat`, beside the
/// analytic SIMD kernel.
fn bench_floor(system: &SequentialSystem, batch: &RayBatch, repeat: usize, cores: usize, csv: &mut CsvWriter) -> Result<()> {
    use crate::tracer::embree::{EmbreeOptions, EmbreeTracer, FloorCallbacks, FloorScenes, Refinement, SceneOptions};
    let n = batch.len();
    // A recorded query is 64 B, and ≈ 1.5 kB per packet query once laid out by packets; SP's rays make 7
    // queries each: ≈ 1.1 kB per ray (4 kB allowed).
    crate::limits::check_memory(&format!("--floor: the recorded queries of {n} rays"), n as f64 * 4096.0)?;
    let tracer = EmbreeTracer::new(EmbreeOptions::user(Refinement::F64));
    let analytic = AnalyticTracer::default();
    let (recorded, log) = tracer.record_queries(system, batch)?;
    let plain = tracer.trace(system, batch)?;
    if recorded != plain {
        return Err(Error::invalid("--floor: the trace that records its queries differs from the plain trace (a bug)"));
    }
    let floor = FloorScenes::new(system, &SceneOptions::default())?;
    let lanes = log.lane_queries();
    let log = log.packets();
    let packets = floor.replay(&log, FloorCallbacks::NoQuery).packet_queries;
    let rows: [(&str, &str, &str); 5] = [
        ("analytic-f64", "SIMD kernel (surface order known)", "-"),
        ("(0) replay only", "replay: read the recorded packets", "none: no Embree query"),
        ("(i) floor", "replay: advance to the recorded next query", "oracle: report the recorded hit, no solve"),
        ("(ii)", "replay: advance to the recorded next query", "real: f64 lane solve + answer"),
        ("(iii) today", "full walk (embree-user,refine=f64)", "real"),
    ];
    let run = |row: usize| -> Result<usize> {
        Ok(match row {
            0 => {
                std::hint::black_box(analytic.trace(system, batch)?);
                0
            }
            1 => floor.replay(&log, FloorCallbacks::NoQuery).differing,
            2 => floor.replay(&log, FloorCallbacks::Oracle).differing,
            3 => floor.replay(&log, FloorCallbacks::Exact).differing,
            _ => {
                std::hint::black_box(tracer.trace(system, batch)?);
                0
            }
        })
    };
    let (mut wall, mut cpu, mut differing) = ([f64::INFINITY; 5], [f64::INFINITY; 5], [0usize; 5]);
    for row in 0..5 {
        run(row)?; // warm-up: scenes, caches
    }
    for _ in 0..repeat {
        for row in 0..5 {
            // A row shorter than the CPU time the kernel's accounting resolves ([`MIN_CPU_INTERVAL_S`]) runs
            // again until it is measured; its figures are the mean per run.
            let (c, s) = (cpu_seconds(), Instant::now());
            let mut runs = 0u32;
            let measured = loop {
                differing[row] = differing[row].max(run(row)?);
                runs += 1;
                let now = cpu_seconds();
                if let Some(d) = cpu_interval(c, now) {
                    break Some(d);
                }
                if now.is_none() || runs >= 100_000 {
                    break None;
                }
            };
            wall[row] = wall[row].min(s.elapsed().as_secs_f64() / runs as f64);
            if let Some(d) = measured {
                cpu[row] = cpu[row].min(d / runs as f64);
            }
        }
    }
    if cpu.iter().any(|c| !c.is_finite()) {
        return Err(Error::invalid("--floor: the process CPU clock (/proc/self/task/*/schedstat) could not be read; the floor is a CPU-time split"));
    }
    println!(
        "\nfloor of Embree as the sequential tracer on {}: {n} rays, the walk's {lanes} lane queries in {packets} rtcIntersect16 packets ({:.1} per ray) replayed; {cores} threads, rows interleaved, best of {repeat} (a row under {MIN_CPU_INTERVAL_S} CPU-s is run again until measured: the mean per run)",
        system.name(),
        lanes as f64 / n as f64
    );
    println!("| row | walk | callbacks | M rays/s | CPU-s per M rays | × analytic CPU time | lanes differing from the walk's record |");
    println!("|---|---|---|---|---|---|---|");
    let per_m = |x: f64| x / n as f64 * 1e6;
    for (row, (name, walk, callbacks)) in rows.iter().enumerate() {
        let check = if row == 2 || row == 3 { differing[row].to_string() } else { "-".into() };
        println!("| {name} | {walk} | {callbacks} | {:.2} | {:.3} | {:.1}× | {check} |", n as f64 / wall[row] / 1e6, per_m(cpu[row]), cpu[row] / cpu[0]);
        let backend = ["analytic-f64", "embree-user-floor-no-query", "embree-user-floor-oracle", "embree-user-floor-replay", "embree-user,refine=f64"][row];
        self::row(csv, "floor", &format!("{} sequential", system.name()), backend, None, cores, Some((wall[row] / n as f64, n as f64 / wall[row])), Some(cpu[row] / cpu[0]))?;
    }
    println!(
        "shares (CPU-s per M rays): the floor (i) {:.3}, of which reading the recorded packets (0) {:.3} and Embree's traversal + dispatch (i) − (0) {:.3}; the callbacks' surface solve (ii) − (i) {:.3}; our walk (iii) − (ii) {:.3}; 5× the analytic kernel is {:.3}",
        per_m(cpu[2]),
        per_m(cpu[1]),
        per_m(cpu[2] - cpu[1]),
        per_m(cpu[3] - cpu[2]),
        per_m(cpu[4] - cpu[3]),
        5.0 * per_m(cpu[0])
    );
    if cpu[2] >= 5.0 * cpu[0] {
        println!("the floor (i) alone is {:.1}× the analytic kernel: within 5× is out of reach for Embree as the sequential tracer on this workload", cpu[2] / cpu[0]);
    }
    if differing[2] + differing[3] > 0 {
        return Err(Error::invalid(format!("--floor: the replays answered {} and {} lanes differently from the walk's record (a bug)", differing[2], differing[3])));
    }
    Ok(())
}

/// Row (b): ray trees to ghost order 2 of the first `rays / 10` rays of (a)'s workload (the sequential
/// analytic kernel has no ghosts: its row is the main image only, from (a)), brute force against Embree's
/// two scene representations; the Embree trees are checked against brute force's (same paths, detector
/// power within 1e-9 per tree).
fn bench_ghosts(system: &SequentialSystem, batch: &RayBatch, quick: bool, repeat: usize, cores: usize, csv: &mut CsvWriter) -> Result<()> {
    use crate::tracer::embree::{EmbreeNextHit, SceneOptions, SurfaceRepresentation};
    use crate::tracer::nonseq::{trace_trees, BruteForce, NextHit, RayTree, SolidsOptions, TreeOptions};
    let n = if quick { batch.len().min(500) } else { (batch.len() / 10).max(1) };
    let mut rays = RayBatch::with_capacity(n);
    for i in 0..n {
        rays.push(batch.origin(i), batch.direction(i), batch.wavelength_nm[i]);
    }
    let opts = TreeOptions { order: 2, ..TreeOptions::default() };
    println!("\n(b) {} with ghosts K = 2 (polarised, roulette below 1e-7): {} ray trees, {} threads", system.name(), n, cores);
    println!("| backend | M trees/s | × brute-force time | CPU-s per M trees | paths per tree | trees differing from brute force |");
    println!("|---|---|---|---|---|---|");
    println!("| analytic-f64 (sequential) | n/a: no ghosts (main image only, row (a)) | | | | |");
    csv.row(&[CsvValue::Str("b"), CsvValue::Str(&format!("{} ghosts K=2", system.name())), CsvValue::Str("analytic-f64"), CsvValue::Str(""), CsvValue::from(cores), CsvValue::Str(""), CsvValue::Str(""), CsvValue::Str("n/a")])?;
    let mesh = SceneOptions { representation: SurfaceRepresentation::Mesh(crate::surfaces::MeshResolution::MaxSagErrorUm(1.0)), ..SceneOptions::default() };
    let mut reference: Option<(Vec<RayTree>, f64)> = None;
    let mut run = |name: &str, kernel: &dyn Fn(&RayBatch) -> Result<Vec<RayTree>>| -> Result<()> {
        let (mut best, mut cpu, mut trees) = (f64::INFINITY, f64::INFINITY, Vec::new());
        for _ in 0..repeat {
            let c = cpu_seconds();
            let s = Instant::now();
            trees = kernel(&rays)?;
            best = best.min(s.elapsed().as_secs_f64());
            if let Some(d) = cpu_interval(c, cpu_seconds()) {
                cpu = cpu.min(d);
            }
        }
        let paths = trees.iter().map(|t| t.arrivals.len()).sum::<usize>() as f64 / n as f64;
        let (base, differ) = match &reference {
            None => (best, "(reference)".to_string()),
            Some((r, b)) => {
                let d = r.iter().zip(&trees).filter(|(a, b)| a.arrivals.iter().map(|x| &x.path).ne(b.arrivals.iter().map(|x| &x.path)) || (a.ledger.detector - b.ledger.detector).abs() > 1e-9).count();
                (*b, d.to_string())
            }
        };
        println!("| {name} | {:.4} | {:.2}× | {} | {paths:.1} | {differ} |", n as f64 / best / 1e6, best / base, per_m_cpu(cpu, n as f64, 1));
        row(csv, "b", &format!("{} ghosts K=2", system.name()), name, None, cores, Some((best / n as f64, n as f64 / best)), Some(best / base))?;
        if reference.is_none() {
            reference = Some((trees, best));
        }
        Ok(())
    };
    fn walk<H: NextHit>(k: &H, system: &SequentialSystem, rays: &RayBatch, opts: &TreeOptions) -> Result<Vec<RayTree>> {
        trace_trees(k, system, rays, opts)
    }
    let brute = BruteForce::new(system, &SolidsOptions::default())?;
    run("brute-f64", &|r| walk(&brute, system, r, &opts))?;
    let user = EmbreeNextHit::new(system, &SceneOptions::default())?;
    run("embree-user (refine f64)", &|r| walk(&user, system, r, &opts))?;
    let meshes = EmbreeNextHit::new(system, &mesh)?;
    run("embree-mesh 1um (refine f64)", &|r| walk(&meshes, system, r, &opts))?;
    Ok(())
}

/// The columns of `--csv` (one row per table line; `vs`: the speed-up or time ratio its table prints).
const CSV_COLUMNS: [&str; 8] = ["row", "case", "backend", "triangles", "threads", "seconds_per_ray", "rays_per_second", "vs"];

/// One CSV row through the project's writer (fields holding commas, such as `embree-user,refine=f64` or
/// `tube, 4 segments`, are quoted); `None` leaves a cell empty.
#[allow(clippy::too_many_arguments)]
/// CPU-s per million rays (or trees) for a table cell, `decimals` after the point; `n/a` when the timed
/// interval was too short to measure ([`cpu_interval`]).
fn per_m_cpu(cpu_s: f64, n: f64, decimals: usize) -> String {
    if cpu_s.is_finite() {
        format!("{:.*}", decimals, cpu_s / n * 1e6)
    } else {
        format!("n/a (< {MIN_CPU_INTERVAL_S} s of CPU: more --rays)")
    }
}

fn row(csv: &mut CsvWriter, table: &str, case: &str, backend: &str, triangles: Option<usize>, threads: usize, timing: Option<(f64, f64)>, vs: Option<f64>) -> Result<()> {
    let empty = CsvValue::Str("");
    let (s, r) = timing.map_or((empty, empty), |(s, r)| (CsvValue::F64(s), CsvValue::F64(r)));
    csv.row(&[CsvValue::Str(table), CsvValue::Str(case), CsvValue::Str(backend), triangles.map_or(empty, CsvValue::from), CsvValue::from(threads), s, r, vs.map_or(empty, CsvValue::F64)])?;
    Ok(())
}

/// `--csv` (the writer was made on its path), written atomically, then announced.
fn write_csv(a: &BenchArgs, csv: CsvWriter) -> Result<()> {
    if let Some(path) = &a.csv {
        csv.finish()?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// The budgets, before anything is traced: every ray (a)–(c) and the crossover trace, and the largest
/// buffers (row (a)'s batch and its traced copy, row (b)'s trees, the query rays).
fn check_budget(system: &SequentialSystem, a: &BenchArgs, rays_a: usize, wavelengths: usize, repeat: usize, queries: usize, brute_queries: usize) -> Result<()> {
    use crate::limits::{check_memory, check_rays, BYTES_PER_RAY};
    let batch = rays_a as f64 * wavelengths as f64;
    let r = repeat as f64;
    let rows_ab = if a.quick { format!("--quick × --wavelengths {wavelengths} × --repeat {repeat}") } else { format!("--rays {rays_a} × --wavelengths {wavelengths} × --repeat {repeat}") };
    // Row (c)'s mechanics queries are fixed in number (--repeat times): named apart, since --rays does not set them.
    let what = if a.floor { rows_ab } else { format!("{rows_ab} (rows a, b) and row (c)'s {} mechanics queries × --repeat {repeat}", queries + brute_queries) };
    let (traced, bytes) = if a.floor {
        // Row (a) (3 tracers) and the floor's 5 rows, each warmed up once; the recorded queries (4 kB a ray).
        (batch * (3.0 * (r + 1.0) + 5.0 * (r + 1.0) + 2.0), batch * (2.0 * BYTES_PER_RAY + 4096.0))
    } else {
        let trees = if a.quick { batch.min(500.0) } else { (batch / 10.0).floor().max(1.0) };
        // Row (b)'s detector paths per tree, from the ghost analysis' pilot at K = 2.
        let pilot = crate::analysis::ghosts::GhostOptions { order: 2, rings: 1, extended_grid: 1, ..Default::default() };
        let paths = 1.0 + crate::analysis::ghosts::ghost_estimate(system, &pilot)?.paths_per_tree;
        let traced_a = batch * 3.0 * (r + 1.0);
        let traced_b = trees * paths * 3.0 * r;
        let traced_c = 3.0 * (queries + brute_queries) as f64 * r + 10.0 * (queries / 10 + brute_queries) as f64 * r;
        let bytes = batch * 2.0 * BYTES_PER_RAY + 2.0 * trees * paths * BENCH_BYTES_PER_PATH + queries as f64 * 96.0;
        (traced_a + traced_b + traced_c, bytes)
    };
    check_memory(&what, bytes)?;
    check_rays(&what, traced)
}

/// The triangle count where the speed-up (brute / Embree) crosses 1, interpolated in log–log between the
/// last measured point below 1 and the next (None if it never crosses).
pub fn crossover(curve: &[(f64, f64)]) -> Option<f64> {
    curve.windows(2).rev().find(|w| w[0].1 < 1.0 && w[1].1 >= 1.0).map(|w| {
        let (x0, y0, x1, y1) = (w[0].0.ln(), w[0].1.ln(), w[1].0.ln(), w[1].1.ln());
        (x0 + (x1 - x0) * (0.0 - y0) / (y1 - y0)).exp()
    })
}

/// Bytes one detector path of a held ray tree costs in row (b) (an arrival slot with its share of the
/// arrivals `Vec`'s growth, and its heap label): docs/robustness.md's 160 B.
const BENCH_BYTES_PER_PATH: f64 = 160.0;
