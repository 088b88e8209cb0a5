//! Diagnosis behind the open SP off-axis spot finding (docs/accuracy.md): for every field
//! and wavelength of a Zemax spot export, fit the affine map (shift ox, oy; scale 1+sx, 1+sy) of Zemax's
//! normalised pupil coordinates onto ours that best reproduces Zemax's image points (Gauss–Newton on every
//! 7th ray). A correct pupil model gives ox = oy = sx = sy = 0 at the export's quantisation (0.029 µm RMS).
//!
//! `cargo run --release --example zemax_pupil_fit -- sp` (or `ap`); needs `../shared/reference`.
use diffcassi::prelude::*;
use diffcassi::rays::object_ray;
use diffcassi::tracer::trace_single;
fn land(sys: &SequentialSystem, f: [f64; 2], a: f64, b: f64, w: f64) -> (f64, f64) {
    let (o, d) = object_ray(sys, f, a, b);
    let (p, _) = trace_single(sys, o, d, w).unwrap().unwrap();
    (p.x, p.y)
}
fn main() {
    let name = std::env::args().nth(1).unwrap_or_else(|| "sp".into());
    let dir = if name == "sp" { "SP_single_prism_aligned" } else { "AP_amici_prism_aligned" };
    let sys = SequentialSystem::build(&presets::spec(&name).unwrap()).unwrap();
    for wi in 1..=3 {
        for fi in 1..=4 {
            let w = [450.0, 520.0, 650.0][wi - 1];
            let f = [[0.0, 0.0], [2.5, 0.0], [0.0, 2.5], [2.5, 2.5]][fi - 1];
            let text = std::fs::read_to_string(format!("../shared/reference/zemax/{dir}/ray_positions_wavelength_W{wi}_field_F{fi}.csv")).unwrap();
            let rows: Vec<Vec<f64>> = text.lines().filter(|l| !l.starts_with('#') && !l.starts_with("px")).map(|l| l.split(',').map(|v| v.parse().unwrap()).collect()).collect();
            let rows: Vec<&Vec<f64>> = rows.iter().step_by(7).collect();
            // params: ox, oy, sx, sy
            let mut q = [0.0f64; 4];
            let resid = |q: &[f64; 4]| -> Vec<f64> {
                let mut r = Vec::new();
                for row in &rows {
                    let (x, y) = land(&sys, f, q[0] + (1.0 + q[2]) * row[0], q[1] + (1.0 + q[3]) * row[1], w);
                    r.push(x - row[2]);
                    r.push(y - row[3]);
                }
                r
            };
            for _ in 0..6 {
                let r0 = resid(&q);
                let mut jac = vec![vec![0.0; 4]; r0.len()];
                for k in 0..4 {
                    let mut qq = q;
                    qq[k] += 1e-6;
                    let r1 = resid(&qq);
                    for i in 0..r0.len() {
                        jac[i][k] = (r1[i] - r0[i]) / 1e-6;
                    }
                }
                // normal equations
                let mut a = [[0.0; 4]; 4];
                let mut g = [0.0; 4];
                for i in 0..r0.len() {
                    for k in 0..4 {
                        g[k] += jac[i][k] * r0[i];
                        for l in 0..4 {
                            a[k][l] += jac[i][k] * jac[i][l];
                        }
                    }
                }
                // solve 4x4 by Gaussian elimination
                let mut m = a;
                let mut v = g;
                for c in 0..4 {
                    let p = (c..4).max_by(|&x, &y| m[x][c].abs().partial_cmp(&m[y][c].abs()).unwrap()).unwrap();
                    m.swap(c, p);
                    v.swap(c, p);
                    for r in 0..4 {
                        if r != c {
                            let fct = m[r][c] / m[c][c];
                            for k in 0..4 {
                                m[r][k] -= fct * m[c][k];
                            }
                            v[r] -= fct * v[c];
                        }
                    }
                }
                for k in 0..4 {
                    q[k] -= v[k] / m[k][k];
                }
            }
            let r = resid(&q);
            let rms = (r.iter().map(|v| v * v).sum::<f64>() / r.len() as f64).sqrt() * 1e3;
            println!("W{wi} F{fi}: ox {:+.5} oy {:+.5} sx {:+.5} sy {:+.5}  rms resid {rms:.3} um", q[0], q[1], q[2], q[3]);
        }
    }
}
