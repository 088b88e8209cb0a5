//! Normalised pupil sampling patterns and their text form (`chief`, `hexapolar:12`, …: [`PupilPattern::parse_for`],
//! `str::parse`), shared by the command line and the bindings.
use crate::error::{Error, Result};
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

impl PupilPattern {
    /// `chief`, `marginal`, `hexapolar:R`, `grid:N`, `grid-step:S`, `random:N:SEED`; errors name `option`
    /// (the command line's `--pupil`, a binding's keyword) and the text. The pattern's point count is
    /// checked against the memory budget before any point is generated.
    pub fn parse_for(option: &str, text: &str) -> Result<PupilPattern> {
        let bad = |why: &str| Error::invalid(format!("{option} `{text}`: {why} (chief, marginal, hexapolar:RINGS, grid:N, grid-step:STEP, random:N:SEED)"));
        let parts: Vec<&str> = text.split(':').collect();
        let int = |k: usize| -> Result<usize> { parts.get(k).ok_or_else(|| bad("missing number"))?.parse().map_err(|_| bad("not a whole number")) };
        let p = match parts[0] {
            "chief" => PupilPattern::Chief,
            "marginal" => PupilPattern::Marginal,
            "hexapolar" => PupilPattern::Hexapolar { rings: int(1)? },
            "grid" => {
                let n = int(1)?;
                if n == 0 {
                    return Err(bad("grid:N needs N ≥ 1 (grid:1 is the chief ray)"));
                }
                if n == 2 {
                    // Its four points (±1, ±1) lie outside the unit pupil: no ray would be traced (a spot of 0/0).
                    return Err(bad("grid:2 has no point inside the pupil (its points are the corners (±1, ±1)); use grid:1 (the chief ray) or grid:3 and up"));
                }
                PupilPattern::Grid { n }
            }
            "grid-step" => {
                let step: f64 = parts.get(1).ok_or_else(|| bad("missing step"))?.parse().map_err(|_| bad("step is not a number"))?;
                if !(step > 0.0 && step <= 1.0) {
                    return Err(bad("step must be in (0, 1]"));
                }
                PupilPattern::GridStep { step }
            }
            "random" => {
                let n = int(1)?;
                if n == 0 {
                    return Err(bad("random:N:SEED needs N ≥ 1"));
                }
                let seed: u64 = parts.get(2).ok_or_else(|| bad("missing seed"))?.parse().map_err(|_| bad("seed is not a whole number ≥ 0"))?;
                PupilPattern::Random { n, seed }
            }
            _ => return Err(bad("unknown pattern")),
        };
        if parts.len() > match p { PupilPattern::Chief | PupilPattern::Marginal => 1, PupilPattern::Random { .. } => 3, _ => 2 } {
            return Err(bad("too many `:` parts"));
        }
        let count = p.count_bound();
        crate::limits::check_memory(&format!("{option} {text} ({count:.3e} points)"), count * crate::limits::BYTES_PER_RAY)?;
        Ok(p)
    }

    /// Upper bound on the number of points, computed without generating them.
    pub fn count_bound(&self) -> f64 {
        match *self {
            PupilPattern::Chief => 1.0,
            PupilPattern::Marginal => 4.0,
            PupilPattern::Hexapolar { rings } => 1.0 + 3.0 * rings as f64 * (rings as f64 + 1.0),
            PupilPattern::Grid { n } => (n as f64).powi(2),
            PupilPattern::GridStep { step } => (2.0 / step + 1.0).powi(2),
            PupilPattern::Random { n, .. } => n as f64,
        }
    }
}

impl std::str::FromStr for PupilPattern {
    type Err = Error;
    /// [`PupilPattern::parse_for`] naming the argument `pupil`.
    fn from_str(text: &str) -> Result<Self> {
        PupilPattern::parse_for("pupil", text)
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

    #[test]
    fn text_forms() {
        assert_eq!("hexapolar:12".parse::<PupilPattern>().unwrap(), PupilPattern::Hexapolar { rings: 12 });
        assert_eq!("random:5:9".parse::<PupilPattern>().unwrap(), PupilPattern::Random { n: 5, seed: 9 });
        assert!("grid:0".parse::<PupilPattern>().unwrap_err().to_string().starts_with("pupil `grid:0`: grid:N needs N"));
        assert!(PupilPattern::parse_for("--pupil", "chief:2").unwrap_err().to_string().contains("--pupil `chief:2`: too many"));
    }
}
