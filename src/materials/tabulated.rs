//! A refractive index known only at tabulated wavelengths — a vendor datasheet's (λ, n) rows — and the
//! interpolant that evaluates it between them: a **monotone piecewise-cubic Hermite interpolant in λ**
//! (PCHIP: Fritsch & Carlson, SIAM J. Numer. Anal. 17, 238 (1980), with the slopes of Fritsch & Butland,
//! SIAM J. Sci. Stat. Comput. 5, 300 (1984) — the interpolant of MATLAB's `pchip` and SciPy's
//! `PchipInterpolator`).
//!
//! Some glasses are published with no dispersion formula, only n at a handful of spectral lines (SCHOTT's
//! B 270 datasheet of August 1993: eight lines from 0.43583 to 0.65627 µm, printed to 4 decimals). The
//! interpolant is chosen for what the tracer needs of an index and for what such a table is:
//!
//! * it passes through every tabulated point *exactly* (the Hermite basis below is exactly 1 and 0 at the
//!   ends of a segment, so at a tabulated λ the value is the tabulated f64 bit for bit): at a datasheet
//!   line the index is the datasheet's;
//! * it is C¹ in λ, so n and dn/dλ ([`TabulatedIndex::slope_um`], used by the wavelength derivatives of
//!   [`crate::diff::dispersion`]) are continuous; a piecewise-linear table would give a dn/dλ that jumps
//!   at every line;
//! * it is monotone between points and never overshoots them. That matters for a table printed to
//!   4 decimals (±0.5e-4) with lines 1.7 nm apart (d 587.56 and D 589.29 nm): the rounding makes the local
//!   slope between such close lines uncertain by ~100 %, and a C² spline (natural cubic) carries that error
//!   into the next interval — on B 270 it sags 1.2e-4 below the trend between 589 and 644 nm, more than the
//!   printed precision. PCHIP stays within 0.6e-4 of SCHOTT's own Schott-formula fit of B 270 (after
//!   removing that fit's constant 0.9e-4 offset from this datasheet, a different melt: its n_d is
//!   1.523080). With n decreasing through the table, n decreases everywhere (normal dispersion): the sign
//!   of dn/dλ is guaranteed, not a coincidence of the data;
//! * it has no parameter to tune and is local (a point moves only its two neighbouring intervals).
//!
//! What the table cannot give: dn/dλ between close lines is known only as well as the printed decimals
//! allow; the interpolant does not know better than the datasheet.
//!
//! Outside the table the index is not defined by the source: a [`super::Glass`] refuses such a wavelength
//! under the default strict policy (its valid range is the table's, see [`super::Glass::in_range`]). Asked
//! to extrapolate explicitly ([`super::WavelengthPolicy::AllowExtrapolation`]), the interpolant continues as
//! the straight line of its end slope (value and slope continuous), never NaN.
//!
//! On [λᵢ, λᵢ₊₁], h = λᵢ₊₁ − λᵢ, t = (λ − λᵢ)/h, s = 1 − t, with slopes dᵢ at the points:
//! n = (1 + 2t)s² nᵢ + t s² h dᵢ + t²(3 − 2t) nᵢ₊₁ − t² s h dᵢ₊₁. The slopes: at an interior point the
//! weighted harmonic mean of the neighbouring secants Δ (weights 2hᵢ + hᵢ₋₁, hᵢ + 2hᵢ₋₁), 0 where the
//! secants change sign or one is 0; at an end the three-point estimate, set to 0 if its sign differs from the
//! end secant's and limited to 3Δ where the secants change sign; two points give the straight line.
//!
//! ```
//! use diffcassi::materials::TabulatedIndex;
//! let t = TabulatedIndex::new(vec![(0.48613, 1.5292), (0.58756, 1.5230), (0.65627, 1.5203)]).unwrap();
//! assert_eq!(t.index_um(0.58756), 1.5230); // a tabulated point, exactly
//! let n = t.index_um(0.55);
//! assert!(n < 1.5292 && n > 1.5230);
//! assert!(t.slope_um(0.55) < 0.0);
//! assert!(TabulatedIndex::new(vec![(0.5, 1.5)]).is_err()); // one point has no dispersion
//! ```
use serde::{Deserialize, Serialize};

/// What [`TabulatedIndex`] interpolates with (shown by `info`).
pub const INTERPOLANT: &str = "monotone cubic (PCHIP) in λ";

/// A tabulated relative index n(λ) and its monotone cubic interpolant.
///
/// Serialised as its points only (`wavelength_um`, `index`); the slopes are rebuilt (and the points
/// checked) on reading.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "TabulatedPoints", into = "TabulatedPoints")]
pub struct TabulatedIndex {
    /// λ of the points (µm), strictly increasing.
    wavelengths_um: Vec<f64>,
    /// n at each point.
    indices: Vec<f64>,
    /// dn/dλ of the interpolant at each point (µm⁻¹).
    slopes: Vec<f64>,
}

/// The serialised form of a [`TabulatedIndex`].
#[derive(Clone, Serialize, Deserialize)]
struct TabulatedPoints {
    wavelength_um: Vec<f64>,
    index: Vec<f64>,
}

impl TryFrom<TabulatedPoints> for TabulatedIndex {
    type Error = String;
    fn try_from(p: TabulatedPoints) -> Result<Self, String> {
        if p.wavelength_um.len() != p.index.len() {
            return Err(format!(
                "tabulated index: {} wavelengths but {} indices",
                p.wavelength_um.len(),
                p.index.len()
            ));
        }
        Self::new(p.wavelength_um.into_iter().zip(p.index).collect())
    }
}

impl From<TabulatedIndex> for TabulatedPoints {
    fn from(t: TabulatedIndex) -> Self {
        TabulatedPoints {
            wavelength_um: t.wavelengths_um,
            index: t.indices,
        }
    }
}

impl TabulatedIndex {
    /// The spline through `points` = (λ µm, n).
    ///
    /// # Errors
    /// A message naming the offending point (1-based) and value: fewer than 2 points, a non-finite or
    /// non-positive λ or n, or λ not strictly increasing.
    pub fn new(points: Vec<(f64, f64)>) -> Result<Self, String> {
        if points.len() < 2 {
            return Err(format!(
                "a tabulated index needs at least 2 points (λ, n) to interpolate, found {}",
                points.len()
            ));
        }
        for (i, &(w, n)) in points.iter().enumerate() {
            if !(w.is_finite() && w > 0.0) {
                return Err(format!(
                    "point {}: wavelength {w} µm is not a finite positive number",
                    i + 1
                ));
            }
            if !(n.is_finite() && n > 0.0) {
                return Err(format!(
                    "point {}: index {n} is not a finite positive number",
                    i + 1
                ));
            }
            if i > 0 && w <= points[i - 1].0 {
                return Err(format!(
                    "point {}: wavelength {w} µm does not increase (after {} µm)",
                    i + 1,
                    points[i - 1].0
                ));
            }
        }
        let (x, y): (Vec<f64>, Vec<f64>) = points.into_iter().unzip();
        let slopes = pchip_slopes(&x, &y);
        Ok(Self {
            wavelengths_um: x,
            indices: y,
            slopes,
        })
    }

    /// Number of tabulated points.
    pub fn len(&self) -> usize {
        self.wavelengths_um.len()
    }

    /// Always `false` (a table has at least 2 points).
    pub fn is_empty(&self) -> bool {
        self.wavelengths_um.is_empty()
    }

    /// The tabulated (λ µm, n), in increasing λ.
    pub fn points(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        self.wavelengths_um
            .iter()
            .copied()
            .zip(self.indices.iter().copied())
    }

    /// First and last tabulated λ (µm): the range where the index is defined.
    pub fn range_um(&self) -> (f64, f64) {
        (self.wavelengths_um[0], self.wavelengths_um[self.len() - 1])
    }

    /// The interval [λᵢ, λᵢ₊₁] holding `w` (inside the table): i = the last point ≤ w, at most n − 2.
    #[inline]
    fn interval(&self, w: f64) -> usize {
        let k = self.wavelengths_um.partition_point(|&x| x <= w);
        k.saturating_sub(1).min(self.len() - 2)
    }

    /// n at `w` µm: the interpolant inside the table (exactly the tabulated n at a tabulated λ), the straight
    /// line of the end slope outside it (explicit extrapolation only: [`super::Glass`] refuses it by
    /// default). NaN for a NaN `w`.
    pub fn index_um(&self, w: f64) -> f64 {
        let (x, y, d) = (&self.wavelengths_um, &self.indices, &self.slopes);
        let last = self.len() - 1;
        if w.is_nan() {
            return f64::NAN;
        }
        if w < x[0] {
            return y[0] + d[0] * (w - x[0]);
        }
        if w > x[last] {
            return y[last] + d[last] * (w - x[last]);
        }
        let i = self.interval(w);
        let h = x[i + 1] - x[i];
        let t = (w - x[i]) / h;
        let s = 1.0 - t;
        // At λᵢ: t = 0, s = 1; at λᵢ₊₁: t = h/h = 1, s = 0 — exactly, so the value is the tabulated n.
        (1.0 + 2.0 * t) * s * s * y[i] + t * s * s * h * d[i] + t * t * (3.0 - 2.0 * t) * y[i + 1]
            - t * t * s * h * d[i + 1]
    }

    /// dn/dλ (per µm) at `w` µm, the derivative of [`index_um`](Self::index_um) (the end slope outside the
    /// table). NaN for a NaN `w`.
    pub fn slope_um(&self, w: f64) -> f64 {
        let (x, y, d) = (&self.wavelengths_um, &self.indices, &self.slopes);
        let last = self.len() - 1;
        if w.is_nan() {
            return f64::NAN;
        }
        if w < x[0] {
            return d[0];
        }
        if w > x[last] {
            return d[last];
        }
        let i = self.interval(w);
        let h = x[i + 1] - x[i];
        let t = (w - x[i]) / h;
        let s = 1.0 - t;
        6.0 * t * s * (y[i + 1] - y[i]) / h
            + s * (1.0 - 3.0 * t) * d[i]
            + t * (3.0 * t - 2.0) * d[i + 1]
    }

    /// `tabulated (N points, monotone cubic (PCHIP) in λ)`.
    pub fn label(&self) -> String {
        format!("tabulated ({} points, {INTERPOLANT})", self.len())
    }
}

/// The slopes of the monotone cubic interpolant at the points (see the module documentation).
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let h: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    let delta: Vec<f64> = (0..n - 1).map(|i| (y[i + 1] - y[i]) / h[i]).collect();
    if n == 2 {
        return vec![delta[0]; 2];
    }
    let mut d = vec![0.0; n];
    for i in 1..n - 1 {
        let (a, b) = (delta[i - 1], delta[i]);
        if a * b > 0.0 {
            let (w1, w2) = (2.0 * h[i] + h[i - 1], h[i] + 2.0 * h[i - 1]);
            d[i] = (w1 + w2) / (w1 / a + w2 / b);
        }
    }
    // Ends: the three-point estimate, kept monotone.
    let end = |h0: f64, h1: f64, d0: f64, d1: f64| {
        let e = ((2.0 * h0 + h1) * d0 - h0 * d1) / (h0 + h1);
        if e.signum() != d0.signum() || d0 == 0.0 {
            0.0
        } else if d0.signum() != d1.signum() && e.abs() > 3.0 * d0.abs() {
            3.0 * d0
        } else {
            e
        }
    };
    d[0] = end(h[0], h[1], delta[0], delta[1]);
    d[n - 1] = end(h[n - 2], h[n - 3], delta[n - 2], delta[n - 3]);
    d
}

/// SCHOTT B 270 datasheet (August 1993), as on refractiveindex.info `specs/schott/misc/B270.yml`: the
/// tests' tabulated glass.
#[cfg(test)]
pub(crate) const B270: [(f64, f64); 8] = [
    (0.43583, 1.5341),
    (0.47999, 1.5297),
    (0.48613, 1.5292),
    (0.54607, 1.5251),
    (0.58756, 1.5230),
    (0.58929, 1.5229),
    (0.64385, 1.5207),
    (0.65627, 1.5203),
];

#[cfg(test)]
mod tests {
    use super::*;

    fn b270() -> TabulatedIndex {
        TabulatedIndex::new(B270.to_vec()).unwrap()
    }

    #[test]
    fn passes_through_every_point_bit_for_bit() {
        let t = b270();
        for (w, n) in B270 {
            assert_eq!(t.index_um(w).to_bits(), n.to_bits(), "{w}");
        }
        assert_eq!(t.points().collect::<Vec<_>>(), B270.to_vec());
        assert_eq!(t.range_um(), (0.43583, 0.65627));
        assert_eq!(
            t.label(),
            "tabulated (8 points, monotone cubic (PCHIP) in λ)"
        );
    }

    /// Values of SciPy 1.x `PchipInterpolator` on the same points (independent implementation), and
    /// continuity of value and slope across every interior point.
    #[test]
    fn matches_scipy_pchip_and_is_c1() {
        let t = b270();
        for (w, n) in [
            (0.55, 1.5248799127),
            (0.5875618, 1.5229999008),
            (0.4861327, 1.5291997944),
        ] {
            assert!(
                (t.index_um(w) - n).abs() < 1e-10,
                "{w}: {} vs {n}",
                t.index_um(w)
            );
        }
        for &(w, _) in &B270[1..7] {
            let (l, r) = (w - 1e-10, w + 1e-10);
            assert!((t.index_um(l) - t.index_um(r)).abs() < 1e-10, "{w}");
            assert!(
                (t.slope_um(l) - t.slope_um(r)).abs() < 1e-6,
                "{w}: {} {}",
                t.slope_um(l),
                t.slope_um(r)
            );
        }
    }

    #[test]
    fn slope_is_the_derivative_of_the_value_and_dispersion_is_normal() {
        let t = b270();
        for k in 0..=200 {
            let w = 0.43583 + (0.65627 - 0.43583) * k as f64 / 200.0;
            let d = |h: f64| (t.index_um(w + h) - t.index_um(w - h)) / (2.0 * h);
            let rich = (4.0 * d(1e-6) - d(2e-6)) / 3.0;
            assert!(
                (t.slope_um(w) - rich).abs() < 1e-5,
                "{w}: {} vs {rich}",
                t.slope_um(w)
            );
            assert!(t.slope_um(w) < 0.0, "{w}: {}", t.slope_um(w));
        }
    }

    /// Outside the table (explicit extrapolation only): the straight line of the end slope, continuous in value
    /// and slope with the interpolant, never NaN.
    #[test]
    fn extension_is_the_end_tangent() {
        let t = b270();
        for (w, dir) in [(0.43583, -1.0), (0.65627, 1.0)] {
            let s = t.slope_um(w);
            let out = w + dir * 0.1;
            assert!((t.index_um(out) - (t.index_um(w) + s * dir * 0.1)).abs() < 1e-15);
            assert_eq!(t.slope_um(out), s);
            assert!((t.slope_um(w - dir * 1e-12) - s).abs() < 1e-9);
        }
        assert!(t.index_um(5.0).is_finite());
        assert!(t.index_um(f64::NAN).is_nan());
    }

    #[test]
    fn two_points_are_a_line_and_bad_tables_are_refused_by_point() {
        let t = TabulatedIndex::new(vec![(0.5, 1.5), (0.6, 1.4)]).unwrap();
        assert!((t.index_um(0.55) - 1.45).abs() < 1e-15);
        for (pts, needle) in [
            (vec![(0.5, 1.5)], "at least 2 points"),
            (
                vec![(0.5, 1.5), (0.5, 1.4)],
                "point 2: wavelength 0.5 µm does not increase",
            ),
            (vec![(0.5, 1.5), (0.6, f64::NAN)], "point 2: index NaN"),
            (vec![(-0.5, 1.5), (0.6, 1.4)], "point 1: wavelength -0.5"),
        ] {
            let e = TabulatedIndex::new(pts).unwrap_err();
            assert!(e.contains(needle), "{e}");
        }
    }

    #[test]
    fn serde_keeps_the_points_and_rebuilds_the_slopes() {
        let t = b270();
        let s = serde_json::to_string(&t).unwrap();
        assert!(s.contains("wavelength_um") && !s.contains("slopes"), "{s}");
        let u: TabulatedIndex = serde_json::from_str(&s).unwrap();
        assert_eq!(t, u);
        assert!(serde_json::from_str::<TabulatedIndex>(
            r#"{"wavelength_um":[0.6,0.5],"index":[1.5,1.4]}"#
        )
        .is_err());
    }
}
