//! Reference values for the C++ bit-identity test (`cpp/tests/test_bitwise.cpp`), computed with the Rust
//! API only (`diffcassi`, not this bridge) in a separate process: for each preset, a ray batch (seeded
//! workload plus rays that fail in each way) and its trace, a 13×13 grid distortion, a mapping cube, a
//! spot diagram, the batch's Jacobians for five named parameters (analytic and Embree hits) and three small
//! renders (random mask from opening and seed, in f64 and in f32; an explicit mask). Every f64 is written as its IEEE-754
//! bit pattern in hex, so the C++ side compares bits.
//!
//! ```text
//! cargo run --release -p diffcassi-cpp --example cpp_reference -- target/cpp_reference.txt
//! ```
//! Format: whitespace-separated tokens, a keyword before each record (see `cpp/tests/reference.hpp`).
use diffcassi::analysis;
use diffcassi::diff::{preset_alias, Param, ParamSet};
use diffcassi::materials::GlassCatalog;
use diffcassi::render::{AiryConfig, Mask, RenderConfig, Renderer, Sampling, SpectralSampling};
use diffcassi::scene::SpectralCube;
use diffcassi::tracer::{BackendConfig, Precision};
use diffcassi::prelude::*;
use glam::DVec3;
use std::fmt::Write as _;

fn hex(v: f64) -> String {
    format!("{:016x}", v.to_bits())
}

/// The batch: a seeded workload over three wavelengths, rays aimed outside the pupil (vignetted or
/// missed), a ray pointing backwards, a non-finite origin and a zero direction.
fn batch(sys: &SequentialSystem) -> diffcassi::Result<RayBatch> {
    let mut b = RayBatch::seeded_workload(sys, 200, &[450.0, 520.0, 650.0], 11)?;
    b.extend(&RayBatch::for_field(sys, [2.5, 2.5], &[[3.0, 0.0], [0.0, -3.0], [-2.0, 2.0], [20.0, 0.0], [0.0, 40.0], [-60.0, 0.0], [200.0, 200.0], [1000.0, 0.0]], 520.0)?);
    let (o, d) = (b.origin(0), b.direction(0));
    b.push(o, -d, 520.0);
    b.push(DVec3::new(f64::NAN, 0.0, 0.0), d, 520.0);
    b.push(o, DVec3::ZERO, 650.0);
    Ok(b)
}

/// The free parameters of the Jacobian record (names as C++ passes them; `prism_tilt_x` is an alias).
pub fn jacobian_parameters(preset: &str) -> [&'static str; 5] {
    match preset {
        "sp" | "msp" => ["prism_tilt_x", "s0.thickness_mm", "glass_nd:N-BK7", "wavelength", "ray.dir_x"],
        _ => ["prism_tilt_x", "s0.thickness_mm", "glass_vd:N-SF10", "wavelength", "ray.origin_y"],
    }
}

/// Scene value at (row, col, band) of the render records (the C++ test fills its buffer the same way).
fn scene_value(r: usize, c: usize, b: usize) -> f32 {
    (0.25 + 0.05 * ((r * 7 + c * 3 + b * 5) % 11) as f64) as f32
}

/// Explicit mask transmission at (row, col).
fn mask_value(r: usize, c: usize) -> f32 {
    [0.0, 0.5, 1.0][(r + 2 * c) % 3]
}

fn jacobian_record(s: &mut String, sys: &SequentialSystem, preset: &str, backend: &str, rays: &RayBatch) -> diffcassi::Result<()> {
    let names = jacobian_parameters(preset);
    let params: Vec<Param> = names.iter().map(|n| preset_alias(preset, n).map_or_else(|| Param::parse(n), Ok)).collect::<diffcassi::Result<_>>()?;
    let ds = ParamSet::new(sys.spec.clone(), GlassCatalog::builtin(), params)?.build()?;
    let hj = ds.trace_with_backend(&backend.parse::<BackendConfig>()?, rays)?;
    let (n, kk) = (hj.batch.len(), hj.batch.k());
    writeln!(s, "jacobian {backend} {kk} {} {n}", names.join(" ")).unwrap();
    writeln!(s, "{}", hj.batch.params.join(" ")).unwrap();
    for i in 0..n {
        let t = &hj.batch.traced;
        writeln!(s, "{} {} {} {} {} {} {} {}", hex(t.x[i]), hex(t.y[i]), hex(t.z[i]), hex(t.dir_x[i]), hex(t.dir_y[i]), hex(t.dir_z[i]), t.status[i] as u8, hj.unavailable[i].is_none() as u8).unwrap();
    }
    for c in 0..6 {
        for k in 0..kk {
            writeln!(s, "{}", (0..n).map(|i| hex(hj.batch.row(i, c)[k])).collect::<Vec<_>>().join(" ")).unwrap();
        }
    }
    eprintln!("{preset} jacobian {backend}: {} of {n} rays available", hj.available_count());
    Ok(())
}

/// A render record: `explicit` selects the explicit mask, else the random one from (opening, seed);
/// `precision` the ray kernel's (C++'s `RenderOptions::precision`).
fn render_record(s: &mut String, sys: &SequentialSystem, backend: &str, precision: Precision, explicit: bool) -> diffcassi::Result<()> {
    let (h, w, wl) = (6usize, 5usize, vec![500.0, 520.0, 540.0]);
    let (planes, rays, seed, opening, mask_seed) = (6usize, 3usize, 5u64, 0.6, 2u64);
    let data = (0..h * w * wl.len()).map(|q| scene_value(q / wl.len() / w, (q / wl.len()) % w, q % wl.len())).collect();
    let scene = SpectralCube::new(h, w, wl.clone(), data, "reference scene")?;
    let mask = if explicit {
        Mask { height: h, width: w, values: (0..h * w).map(|q| mask_value(q / w, q % w)).collect(), description: "explicit".into() }.at_png_steps()
    } else {
        Mask::random(h, w, opening, mask_seed)?
    };
    // The bridge's options → RenderConfig mapping (cpp/bridge/src/render.rs), spelled out.
    let mut cfg = RenderConfig::paper(h);
    (cfg.scene_height, cfg.scene_width, cfg.scene_pitch_mm, cfg.detector_pitch_mm) = (h, w, 0.01, 0.01);
    cfg.spectral = SpectralSampling::with_planes(wl.clone(), planes)?;
    (cfg.rays_per_pixel, cfg.sampling, cfg.seed) = (rays, Sampling::Stratified, seed);
    cfg.airy = Some(AiryConfig { diameter_px: 2.5, ..AiryConfig::default() });
    cfg.precision = precision;
    let tracer = backend.parse::<BackendConfig>()?.build()?;
    let r = Renderer::new(sys, tracer.as_ref(), cfg, mask)?;
    let acq = r.render(&scene, false, &|_| {})?;
    let d = r.detector;
    writeln!(s, "render {backend} {precision} {h} {w} {} {planes} {rays} {seed} {} {} {mask_seed}", wl.len(), explicit as u8, hex(opening)).unwrap();
    writeln!(s, "{}", wl.iter().map(|v| hex(*v)).collect::<Vec<_>>().join(" ")).unwrap();
    writeln!(s, "{} {} {} {} {} {} {}", d.height, d.width, hex(d.pitch_mm), hex(d.x_left_mm), hex(d.y_top_mm), acq.stats.traced, acq.stats.arrived).unwrap();
    for row in acq.image.chunks(d.width) {
        writeln!(s, "{}", row.iter().map(|v| hex(*v)).collect::<Vec<_>>().join(" ")).unwrap();
    }
    Ok(())
}

fn main() -> diffcassi::Result<()> {
    let path = std::env::args().nth(1).unwrap_or_else(|| "cpp_reference.txt".into());
    let tracer = AnalyticTracer::default();
    let mut s = String::from("diffcassi-cpp-reference 1\n");
    for preset in diffcassi::presets::NAMES {
        let sys = SequentialSystem::build(&diffcassi::presets::spec(preset)?)?;
        writeln!(s, "case {preset}").unwrap();

        let rays = batch(&sys)?;
        let out = tracer.trace(&sys, &rays)?;
        writeln!(s, "rays {}", rays.len()).unwrap();
        for i in 0..rays.len() {
            let (o, d) = (rays.origin(i), rays.direction(i));
            writeln!(s, "{} {} {} {} {} {} {}", hex(o.x), hex(o.y), hex(o.z), hex(d.x), hex(d.y), hex(d.z), hex(rays.wavelength_nm[i])).unwrap();
        }
        writeln!(s, "traced {} ok {}", out.len(), out.ok_count()).unwrap();
        for i in 0..out.len() {
            writeln!(s, "{} {} {} {} {} {} {} {}", hex(out.x[i]), hex(out.y[i]), hex(out.z[i]), hex(out.dir_x[i]), hex(out.dir_y[i]), hex(out.dir_z[i]), out.status[i] as u8, out.surface[i]).unwrap();
        }

        let (w, n, half) = (450.0, 13, 2.5);
        let g = analysis::grid_distortion(&sys, &tracer, w, n, half)?;
        writeln!(s, "distortion {} {n} {}", hex(w), hex(half)).unwrap();
        writeln!(s, "{} {} {} {} {} {} {}", hex(g.reference_mm[0]), hex(g.reference_mm[1]), hex(g.abcd[0]), hex(g.abcd[1]), hex(g.abcd[2]), hex(g.abcd[3]), hex(g.max_distortion_pct)).unwrap();
        for p in &g.points {
            writeln!(
                s,
                "{} {} {} {} {} {} {} {} {} {}",
                p.i, p.j, hex(p.x_field_mm), hex(p.y_field_mm), hex(p.real_x_mm), hex(p.real_y_mm), hex(p.pred_x_mm), hex(p.pred_y_mm), hex(p.distortion_pct), p.status as u8
            )
            .unwrap();
        }

        let (h, wd, pitch) = (9, 11, 0.25);
        let wl = analysis::linspace(450.0, 650.0, 4);
        let m = analysis::mapping_cube(&sys, &tracer, h, wd, pitch, &wl)?;
        writeln!(s, "mapping {h} {wd} {} {}", hex(pitch), wl.len()).unwrap();
        writeln!(s, "{}", wl.iter().map(|v| hex(*v)).collect::<Vec<_>>().join(" ")).unwrap();
        for k in 0..m.valid.len() {
            writeln!(s, "{} {} {}", hex(m.positions_mm[2 * k]), hex(m.positions_mm[2 * k + 1]), m.valid[k]).unwrap();
        }

        let pupil = PupilPattern::Hexapolar { rings: 6 }.points();
        let sp = analysis::spot_diagram(&sys, &tracer, [2.5, 0.0], 450.0, &pupil)?;
        let st = sp.stats.expect("the reference spot has arrived rays");
        writeln!(s, "spot {} {} {} {}", hex(sp.field_mm[0]), hex(sp.field_mm[1]), hex(sp.wavelength_nm), pupil.len()).unwrap();
        for (k, p) in pupil.iter().enumerate() {
            writeln!(s, "{} {} {} {} {}", hex(p[0]), hex(p[1]), hex(sp.x_mm[k]), hex(sp.y_mm[k]), sp.status[k] as u8).unwrap();
        }
        let chief = sp.chief_mm.expect("the reference spot's chief ray arrives");
        writeln!(s, "{} {} {} {} {} {} {} {}", st.count, hex(st.centroid_mm[0]), hex(st.centroid_mm[1]), hex(st.rms_radius_um), hex(st.geo_radius_um), hex(chief[0]), hex(chief[1]), hex(sp.rms_radius_chief_um.unwrap_or(0.0))).unwrap();

        for backend in ["analytic", "embree-user"] {
            jacobian_record(&mut s, &sys, preset, backend, &rays)?;
        }
        render_record(&mut s, &sys, "analytic", Precision::F64, false)?;
        render_record(&mut s, &sys, "analytic", Precision::F32, false)?;
        render_record(&mut s, &sys, if preset == "ap" { "embree-user" } else { "analytic" }, Precision::F64, true)?;
    }
    s.push_str("end\n");
    diffcassi::io::write_atomic(std::path::Path::new(&path), s.as_bytes())?;
    eprintln!("wrote {path}");
    Ok(())
}
