//! The dihedral group D4 acting on a cube's two spatial axes: the eight flips and quarter turns of an
//! `H × W × B` cube (`[row][col][band]`, the bands untouched), their exact inverses, and the seeded,
//! counter-based choice of one per plug-and-play call that **equivariant PnP** uses.
//!
//! Equivariant PnP (after Terris, Moreau, Pustelnik & Tachella, "Equivariant plug-and-play image
//! reconstruction", CVPR 2024): at the j-th network call the solver draws g from the group, denoises g·x and
//! applies g⁻¹ — θ = g⁻¹ D(g x, σ). A network that is not exactly equivariant then averages its orientation
//! biases over the iterations (a stochastic self-ensemble at the cost of one call), which regularises the
//! fixed point. The choice is `mix64(mix64(seed) ^ j)` reduced to the group's size, so it depends only on
//! (seed, call) — never on threads or timing. Quarter turns swap H and W; the solver draws them only for
//! square cubes ([`Dihedral::draw`] with `square = false` draws among the four flips).
//!
//! Every transform is a permutation of whole pixels: [`Dihedral::apply`] followed by [`Dihedral::invert`]
//! gives the input back bit for bit (tested).
//!
//! ```
//! use diffcassi::recon::prior::dihedral::Dihedral;
//! use diffcassi::recon::CubeShape;
//! let shape = CubeShape { height: 2, width: 3, bands: 1 };
//! let x = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]; // rows [1 2 3], [4 5 6]
//! let g = Dihedral { quarter_turns: 1, flip: false }; // torch.rot90(x, 1): counter-clockwise
//! let mut t = [0.0; 6];
//! assert_eq!(g.apply(&x, shape, &mut t), CubeShape { height: 3, width: 2, bands: 1 });
//! assert_eq!(t, [3.0, 6.0, 2.0, 5.0, 1.0, 4.0]);
//! let mut back = [0.0; 6];
//! g.invert(&t, shape, &mut back);
//! assert_eq!(back, x);
//! ```
use crate::recon::operator::CubeShape;
use crate::render::sampling::mix64;

/// One element of D4 on the spatial axes: a rotation by `quarter_turns`·90° as `torch.rot90(x, k, dims=(H,
/// W))` (k = 1 maps out\[r\]\[c\] = in\[c\]\[W−1−r\]), then, if `flip`, a reversal of the width axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Dihedral {
    /// Quarter turns k ∈ 0..4 (counter-clockwise, torch.rot90's sense).
    pub quarter_turns: u8,
    /// Reverse the width axis after the rotation.
    pub flip: bool,
}

impl Dihedral {
    /// The identity.
    pub const IDENTITY: Dihedral = Dihedral { quarter_turns: 0, flip: false };

    /// The eight elements, in the self-ensemble's order (quarter turns 0..4, each without then with the flip).
    pub const ALL: [Dihedral; 8] = [
        Dihedral { quarter_turns: 0, flip: false },
        Dihedral { quarter_turns: 0, flip: true },
        Dihedral { quarter_turns: 1, flip: false },
        Dihedral { quarter_turns: 1, flip: true },
        Dihedral { quarter_turns: 2, flip: false },
        Dihedral { quarter_turns: 2, flip: true },
        Dihedral { quarter_turns: 3, flip: false },
        Dihedral { quarter_turns: 3, flip: true },
    ];

    /// The four elements that keep H × W (no quarter turn, or a half turn; each without and with the flip):
    /// the identity, the width flip, the height flip (half turn + width flip) and the half turn.
    pub const FLIPS: [Dihedral; 4] = [
        Dihedral { quarter_turns: 0, flip: false },
        Dihedral { quarter_turns: 0, flip: true },
        Dihedral { quarter_turns: 2, flip: false },
        Dihedral { quarter_turns: 2, flip: true },
    ];

    /// The element of the `call`-th draw of stream `seed`: uniform over [`Dihedral::ALL`] when `square`, else
    /// over [`Dihedral::FLIPS`] (a quarter turn would swap H and W). Counter-based: the same (seed, call) give
    /// the same element, whatever else ran before.
    pub fn draw(seed: u64, call: u64, square: bool) -> Dihedral {
        let z = mix64(mix64(seed) ^ call);
        // The top bits: SplitMix64's best mixed (and n divides 2⁶⁴, so the choice is exactly uniform).
        if square {
            Self::ALL[(z >> 61) as usize]
        } else {
            Self::FLIPS[(z >> 62) as usize]
        }
    }

    /// The shape of the transformed cube (H and W swapped by an odd number of quarter turns).
    pub fn output_shape(&self, shape: CubeShape) -> CubeShape {
        if self.quarter_turns % 2 == 1 {
            CubeShape { height: shape.width, width: shape.height, bands: shape.bands }
        } else {
            shape
        }
    }

    /// Source (row, col) in an `h`×`w` image of output pixel (r, c) of the transform (the output is `w`×`h`
    /// for odd quarter turns). The same map serves both ways: [`Dihedral::apply`] gathers from it,
    /// [`Dihedral::invert`] scatters back to it.
    pub fn source(&self, h: usize, w: usize, r: usize, c: usize) -> (usize, usize) {
        let ow = if self.quarter_turns % 2 == 1 { h } else { w };
        let c = if self.flip { ow - 1 - c } else { c };
        // torch.rot90(x, 1, dims=(H, W)): out[r][c] = in[c][W−1−r]; k = 2: in[H−1−r][W−1−c]; k = 3: in[H−1−c][r].
        match self.quarter_turns % 4 {
            0 => (r, c),
            1 => (c, w - 1 - r),
            2 => (h - 1 - r, w - 1 - c),
            _ => (h - 1 - c, r),
        }
    }

    /// The group inverse g⁻¹ (g⁻¹·g = identity): a flip is its own inverse, a rotation by k quarter turns
    /// is undone by 4 − k.
    pub fn inverse(&self) -> Dihedral {
        if self.flip {
            *self
        } else {
            Dihedral { quarter_turns: (4 - self.quarter_turns % 4) % 4, flip: false }
        }
    }

    /// A short name for records: `r0`, `r1`, `r2`, `r3` (quarter turns), `+flip` when the width is reversed.
    pub fn name(&self) -> String {
        format!("r{}{}", self.quarter_turns % 4, if self.flip { "+flip" } else { "" })
    }

    /// `out` ← g·x for a cube `x` of `shape`; returns the output's shape ([`Dihedral::output_shape`]). Both
    /// slices hold `shape.len()` values (panics otherwise: callers size them).
    pub fn apply(&self, x: &[f32], shape: CubeShape, out: &mut [f32]) -> CubeShape {
        let (h, w, b) = (shape.height, shape.width, shape.bands);
        assert!(x.len() == shape.len() && out.len() == shape.len(), "dihedral transform: buffer sizes");
        let o = self.output_shape(shape);
        for r in 0..o.height {
            for c in 0..o.width {
                let (sr, sc) = self.source(h, w, r, c);
                out[(r * o.width + c) * b..][..b].copy_from_slice(&x[(sr * w + sc) * b..][..b]);
            }
        }
        o
    }

    /// `out` ← g⁻¹·y for `y` the transform of a cube of shape `shape` (so `y` has [`Dihedral::output_shape`]
    /// of it and `out` has `shape`): every pixel goes back where [`Dihedral::apply`] took it from.
    pub fn invert(&self, y: &[f32], shape: CubeShape, out: &mut [f32]) {
        let (h, w, b) = (shape.height, shape.width, shape.bands);
        assert!(y.len() == shape.len() && out.len() == shape.len(), "dihedral transform: buffer sizes");
        let o = self.output_shape(shape);
        for r in 0..o.height {
            for c in 0..o.width {
                let (sr, sc) = self.source(h, w, r, c);
                out[(sr * w + sc) * b..][..b].copy_from_slice(&y[(r * o.width + c) * b..][..b]);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cube(shape: CubeShape) -> Vec<f32> {
        // Distinct values, some not exactly representable sums (bit patterns matter, not only order).
        (0..shape.len()).map(|i| (i as f32 * 0.1).sin() * 1e3 + i as f32 * 1e-7).collect()
    }

    #[test]
    fn apply_then_invert_is_the_identity_bit_for_bit() {
        for shape in [CubeShape { height: 5, width: 7, bands: 3 }, CubeShape { height: 6, width: 6, bands: 2 }, CubeShape { height: 1, width: 4, bands: 1 }] {
            let x = cube(shape);
            for g in Dihedral::ALL {
                let mut t = vec![0.0; shape.len()];
                let mut back = vec![f32::NAN; shape.len()];
                let ts = g.apply(&x, shape, &mut t);
                assert_eq!(ts, g.output_shape(shape));
                if g != Dihedral::IDENTITY && shape.height > 1 {
                    assert_ne!(t, x, "{} moved nothing on {shape:?}", g.name());
                }
                g.invert(&t, shape, &mut back);
                assert!(back.iter().zip(&x).all(|(a, b)| a.to_bits() == b.to_bits()), "{} on {shape:?}", g.name());
                // The group inverse applied to g·x is the same map as `invert`.
                let mut via_inverse = vec![f32::NAN; shape.len()];
                assert_eq!(g.inverse().apply(&t, ts, &mut via_inverse), shape);
                assert!(via_inverse.iter().zip(&x).all(|(a, b)| a.to_bits() == b.to_bits()), "{}⁻¹ = {}", g.name(), g.inverse().name());
            }
        }
    }

    #[test]
    fn the_eight_transforms_are_distinct_and_match_torch_conventions() {
        // 2×2 single band [[a b] [c d]]: rot90 (counter-clockwise) → [[b d] [a c]].
        let shape = CubeShape { height: 2, width: 2, bands: 1 };
        let x = [1.0, 2.0, 3.0, 4.0];
        let mut seen = Vec::new();
        for g in Dihedral::ALL {
            let mut t = [0.0; 4];
            g.apply(&x, shape, &mut t);
            assert!(!seen.contains(&t), "{} repeats another transform", g.name());
            seen.push(t);
        }
        assert_eq!(seen[2], [2.0, 4.0, 1.0, 3.0]); // r1
        assert_eq!(seen[1], [2.0, 1.0, 4.0, 3.0]); // width flip
        assert_eq!(seen[4], [4.0, 3.0, 2.0, 1.0]); // r2
        assert_eq!(seen[5], [3.0, 4.0, 1.0, 2.0]); // r2 + width flip = height flip
    }

    #[test]
    fn the_draw_is_deterministic_uniform_and_keeps_non_square_shapes() {
        for call in 0..50 {
            assert_eq!(Dihedral::draw(7, call, true), Dihedral::draw(7, call, true));
        }
        let a: Vec<_> = (0..32).map(|j| Dihedral::draw(1, j, true)).collect();
        let b: Vec<_> = (0..32).map(|j| Dihedral::draw(2, j, true)).collect();
        assert_ne!(a, b, "two seeds gave the same 32 draws");
        let mut count = [0usize; 8];
        for j in 0..8000 {
            let g = Dihedral::draw(3, j, true);
            count[Dihedral::ALL.iter().position(|e| *e == g).unwrap()] += 1;
        }
        // Binomial(8000, 1/8): mean 1000, sd 29.6; ±150 is 5 sd.
        assert!(count.iter().all(|&n| (850..=1150).contains(&n)), "{count:?}");
        let mut flips = [0usize; 4];
        for j in 0..4000 {
            let g = Dihedral::draw(3, j, false);
            assert_eq!(g.quarter_turns % 2, 0, "a quarter turn drawn for a non-square cube");
            flips[Dihedral::FLIPS.iter().position(|e| *e == g).unwrap()] += 1;
        }
        assert!(flips.iter().all(|&n| (850..=1150).contains(&n)), "{flips:?}");
    }
}
