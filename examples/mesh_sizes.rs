//! Mesh size vs chord-sag tolerance on the AC254-050-A front surface (R = 33.34 mm, 12.7 mm semi-diameter):
//! `cargo run --release --example mesh_sizes`.
use diffcassi::surfaces::{tessellate, Aperture, MeshResolution, SurfaceShape};
fn main() {
    let s = SurfaceShape::Conic { curvature: 1.0 / 33.34, conic: 0.0 };
    println!("| tolerance (µm) | segments | triangles | measured chord sag (µm) | boundary (µm) |");
    println!("|---|---|---|---|---|");
    for tol in [10.0, 1.0, 0.1, 0.01] {
        let m = tessellate(&s, &Aperture::circular(12.7), MeshResolution::MaxSagErrorUm(tol)).unwrap();
        println!("| {tol} | {} | {} | {:.4} | {:.4} |", m.segments, m.triangles.len(), m.max_sag_error_um, m.boundary_error_um);
    }
}
