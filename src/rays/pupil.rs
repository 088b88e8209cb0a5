use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Normalised pupil sampling patterns (points in the unit disk, Zemax px, py).
#[derive(Clone, Debug, PartialEq)]
pub enum PupilPattern {
    /// (0, 0).
    Chief,
    /// The four marginal rays (±1, 0), (0, ±1).
    Marginal,
    /// Centre plus `rings` rings, ring k holding 6k points at radius k / rings (Zemax's hexapolar).
    Hexapolar { rings: usize },
    /// Square grid of `n × n` points spanning [−1, 1] (step 2/(n−1)), keeping px² + py² ≤ 1.
    Grid { n: usize },
    /// Zemax's square pupil grid: points (i·step, j·step) strictly inside the unit circle (Zemax leaves
    /// out the points exactly on it; step 0.025 gives the 5013 rays of the reference spot exports).
    GridStep { step: f64 },
    /// `n` points uniform in the disk, from a ChaCha8 stream seeded with `seed`.
    Random { n: usize, seed: u64 },
}

impl PupilPattern {
    pub fn points(&self) -> Vec<[f64; 2]> {
        match *self {
            PupilPattern::Chief => vec![[0.0, 0.0]],
            PupilPattern::Marginal => vec![[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]],
            PupilPattern::Hexapolar { rings } => {
                let mut v = vec![[0.0, 0.0]];
                for k in 1..=rings {
                    let r = k as f64 / rings as f64;
                    let m = 6 * k;
                    for j in 0..m {
                        let a = 2.0 * std::f64::consts::PI * j as f64 / m as f64;
                        v.push([r * a.cos(), r * a.sin()]);
                    }
                }
                v
            }
            PupilPattern::Grid { n } => {
                if n < 2 {
                    return vec![[0.0, 0.0]];
                }
                let step = 2.0 / (n - 1) as f64;
                let mut v = Vec::new();
                for i in 0..n {
                    for j in 0..n {
                        let (px, py) = (-1.0 + i as f64 * step, -1.0 + j as f64 * step);
                        if px * px + py * py <= 1.0 + 1e-12 {
                            v.push([px, py]);
                        }
                    }
                }
                v
            }
            PupilPattern::GridStep { step } => {
                let k = (1.0 / step).floor() as i64;
                let mut v = Vec::new();
                for i in -k..=k {
                    for j in -k..=k {
                        let (px, py) = (i as f64 * step, j as f64 * step);
                        if px * px + py * py < 1.0 - 1e-12 {
                            v.push([px, py]);
                        }
                    }
                }
                v
            }
            PupilPattern::Random { n, seed } => {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                (0..n)
                    .map(|_| {
                        let r = rng.gen::<f64>().sqrt();
                        let a = rng.gen::<f64>() * 2.0 * std::f64::consts::PI;
                        [r * a.cos(), r * a.sin()]
                    })
                    .collect()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    #[test]
    fn counts() {
        assert_eq!(PupilPattern::Hexapolar { rings: 3 }.points().len(), 1 + 6 + 12 + 18);
        // The Zemax spot export: step 0.025 grid in the unit disk holds 5013 points.
        assert_eq!(PupilPattern::GridStep { step: 0.025 }.points().len(), 5013);
        let a = PupilPattern::Random { n: 100, seed: 7 }.points();
        assert_eq!(a, PupilPattern::Random { n: 100, seed: 7 }.points());
        assert!(a.iter().all(|p| p[0] * p[0] + p[1] * p[1] <= 1.0));
    }
}
