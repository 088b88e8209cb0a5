//! dn/dλ of the 13 AGF dispersion formulas, exact (differentiated by hand; checked against the value
//! formula of [`crate::materials::DispersionFormula`] and against finite differences), of a tabulated
//! index (the derivative of its monotone cubic, [`crate::materials::TabulatedIndex::slope_um`]) and of
//! Buchdahl's model ((ν1 + 2ν2 ω) dω/dλ, dω/dλ = 1/(1 + 2.5 Δλ)²).
//!
//! All but Conrady are functions of x = λ² (µm²): for n² = G(x), dn/dλ = G′(x)·λ/n; for n = H(x),
//! dn/dλ = 2λ H′(x).
//!
//! ```
//! use diffcassi::materials::GlassCatalog;
//! let bk7 = GlassCatalog::builtin().get("N-BK7").unwrap();
//! let (n, dn) = diffcassi::diff::dispersion::index_and_slope(&bk7.formula, 520.0);
//! assert!(dn < 0.0 && (n - bk7.refractive_index(520.0).unwrap()).abs() < 1e-15);
//! ```
use crate::materials::DispersionFormula;

/// Σ a_p x^p and its derivative for (coefficient, power) pairs.
fn poly(x: f64, terms: &[(f64, i32)]) -> (f64, f64) {
    terms.iter().fold((0.0, 0.0), |(v, d), &(a, p)| (v + a * x.powi(p), d + a * p as f64 * x.powi(p - 1)))
}

/// Σ K x/(x − L) and its x-derivative Σ −K L/(x − L)² over (K, L) pairs.
fn sellmeier(x: f64, c: &[f64]) -> (f64, f64) {
    c.chunks_exact(2).fold((0.0, 0.0), |(v, d), kl| {
        let (k, l) = (kl[0], kl[1]);
        let q = x - l;
        (v + k * x / q, d - k * l / (q * q))
    })
}

/// (n, dn/dλ per nm) of `formula` at `wavelength_nm`. The value equals
/// [`DispersionFormula::refractive_index`] up to rounding (the slope is what matters here).
pub fn index_and_slope(formula: &DispersionFormula, wavelength_nm: f64) -> (f64, f64) {
    use DispersionFormula as F;
    let l = wavelength_nm / 1000.0;
    let x = l * l;
    let n = formula.refractive_index(wavelength_nm);
    // dn/dλ in µm⁻¹
    let slope_um = match formula {
        F::Schott(a) => {
            let (_, g) = poly(x, &[(a[0], 0), (a[1], 1), (a[2], -1), (a[3], -2), (a[4], -3), (a[5], -4)]);
            g * l / n
        }
        F::Extended(a) => {
            let (_, g) = poly(x, &[(a[0], 0), (a[1], 1), (a[2], -1), (a[3], -2), (a[4], -3), (a[5], -4), (a[6], -5), (a[7], -6)]);
            g * l / n
        }
        F::Extended2(a) => {
            let (_, g) = poly(x, &[(a[0], 0), (a[1], 1), (a[2], -1), (a[3], -2), (a[4], -3), (a[5], -4), (a[6], 2), (a[7], 3)]);
            g * l / n
        }
        F::Extended3(a) => {
            let (_, g) =
                poly(x, &[(a[0], 0), (a[1], 1), (a[2], 2), (a[3], -1), (a[4], -2), (a[5], -3), (a[6], -4), (a[7], -5), (a[8], -6)]);
            g * l / n
        }
        F::Sellmeier1(c) => sellmeier(x, c).1 * l / n,
        F::Sellmeier3(c) => sellmeier(x, c).1 * l / n,
        F::Sellmeier5(c) => sellmeier(x, c).1 * l / n,
        F::Herzberger(c) => {
            let ll = 1.0 / (x - 0.028);
            let h = (c[1] + 2.0 * c[2] * ll) * (-ll * ll) + c[3] + 2.0 * c[4] * x + 3.0 * c[5] * x * x;
            2.0 * l * h
        }
        F::Sellmeier2(c) => {
            let (l1, l2) = (c[2] * c[2], c[4] * c[4]);
            let g = -c[1] * l1 / ((x - l1) * (x - l1)) - c[3] / ((x - l2) * (x - l2));
            g * l / n
        }
        F::Conrady(c) => -c[1] / (l * l) - 3.5 * c[2] / l.powf(4.5),
        F::HandbookOfOptics1(c) => {
            let g = -c[1] / ((x - c[2]) * (x - c[2])) - c[3];
            g * l / n
        }
        F::HandbookOfOptics2(c) => {
            let g = -c[1] * c[2] / ((x - c[2]) * (x - c[2])) - c[3];
            g * l / n
        }
        F::Sellmeier4(c) => {
            let g = -c[1] * c[2] / ((x - c[2]) * (x - c[2])) - c[3] * c[4] / ((x - c[4]) * (x - c[4]));
            g * l / n
        }
        F::Tabulated(t) => t.slope_um(l),
        F::Buchdahl(c) => {
            let (o, dodl) = crate::materials::dispersion::buchdahl_omega(l, c[0]);
            (c[2] + 2.0 * c[3] * o) * dodl
        }
    };
    (n, slope_um / 1000.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_formula_slope_matches_richardson_difference() {
        use DispersionFormula as F;
        let formulas = vec![
            F::Schott([2.27, -0.01, 0.0108, 1.2e-4, -3e-6, 2e-7]),
            F::Sellmeier1([1.0396, 0.0060007, 0.23179, 0.020018, 1.01047, 103.56]),
            F::Herzberger([1.5, 0.004, 1e-4, -0.002, 1e-5, -1e-7]),
            F::Sellmeier2([0.3, 1.0, 0.1, 0.001, 0.09]),
            F::Conrady([1.5, 0.005, 1e-4]),
            F::Sellmeier3([0.7, 0.004, 0.3, 0.02, 0.8, 100.0, 0.01, 50.0]),
            F::HandbookOfOptics1([2.3, 0.01, 0.02, 0.01]),
            F::HandbookOfOptics2([1.3, 1.0, 0.01, 0.01]),
            F::Sellmeier4([1.3, 1.0, 0.01, 0.5, 90.0]),
            F::Extended([2.27, -0.01, 0.0108, 1.2e-4, -3e-6, 2e-7, 1e-8, -1e-9]),
            F::Sellmeier5([0.7, 0.004, 0.3, 0.02, 0.8, 100.0, 0.01, 50.0, 0.001, 30.0]),
            F::Extended2([2.27, -0.01, 0.0108, 1.2e-4, -3e-6, 2e-7, 1e-4, -1e-5]),
            F::Extended3([2.27, -0.01, 1e-4, 0.0108, 1.2e-4, -3e-6, 2e-7, 1e-8, -1e-9]),
            // SCHOTT B 270's datasheet table (no point within 0.1 nm of 450, 520, 650 nm).
            F::Tabulated(crate::materials::TabulatedIndex::new(crate::materials::tabulated::B270.to_vec()).unwrap()),
            // Robb & Mercado's (1983) SCHOTT SF5 row, about 0.574 µm.
            F::Buchdahl([0.574, 1.674185, -0.11374, 0.036167]),
        ];
        for f in &formulas {
            for w in [450.0, 520.0, 650.0] {
                let (n, s) = index_and_slope(f, w);
                assert_eq!(n, f.refractive_index(w));
                let d = |h: f64| (f.refractive_index(w + h) - f.refractive_index(w - h)) / (2.0 * h);
                let rich = (4.0 * d(0.05) - d(0.1)) / 3.0;
                assert!((s - rich).abs() <= 1e-7 * s.abs().max(1e-9), "{} at {w}: {s} vs {rich}", f.name());
            }
        }
    }
}
