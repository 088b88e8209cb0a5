use glam::{DMat3, DVec3};

/// A right-handed orthonormal frame: `origin` is the local origin in global millimetres, the columns of
/// `rotation` are the local x, y, z axes in global coordinates (Zemax's "rotation matrix" R of the
/// Global Vertex report: global = origin + R · local).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Frame {
    pub origin: DVec3,
    pub rotation: DMat3,
}

impl Default for Frame {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Frame {
    pub const IDENTITY: Frame = Frame { origin: DVec3::ZERO, rotation: DMat3::IDENTITY };

    pub fn new(origin: DVec3, rotation: DMat3) -> Self {
        Self { origin, rotation }
    }
    /// Global point → local coordinates.
    #[inline]
    pub fn point_to_local(&self, p: DVec3) -> DVec3 {
        self.rotation.transpose() * (p - self.origin)
    }
    /// Local point → global coordinates.
    #[inline]
    pub fn point_to_global(&self, p: DVec3) -> DVec3 {
        self.origin + self.rotation * p
    }
    /// Global direction → local direction.
    #[inline]
    pub fn dir_to_local(&self, d: DVec3) -> DVec3 {
        self.rotation.transpose() * d
    }
    /// Local direction → global direction.
    #[inline]
    pub fn dir_to_global(&self, d: DVec3) -> DVec3 {
        self.rotation * d
    }
    /// The frame moved by `distance_mm` along its own local z axis (a surface thickness).
    pub fn advanced(&self, distance_mm: f64) -> Frame {
        Frame { origin: self.origin + self.rotation.z_axis * distance_mm, rotation: self.rotation }
    }
    /// `other` expressed in this frame: the (translation, rotation) with other = self ∘ (t, r).
    pub fn relative(&self, other: &Frame) -> (DVec3, DMat3) {
        (self.point_to_local(other.origin), self.rotation.transpose() * other.rotation)
    }
}

/// Right-handed rotation about x by `a` radians (positive tilts y toward z).
pub fn rot_x(a: f64) -> DMat3 {
    let (s, c) = a.sin_cos();
    DMat3::from_cols(DVec3::X, DVec3::new(0.0, c, s), DVec3::new(0.0, -s, c))
}
/// Right-handed rotation about y by `b` radians (positive tilts z toward x).
pub fn rot_y(b: f64) -> DMat3 {
    let (s, c) = b.sin_cos();
    DMat3::from_cols(DVec3::new(c, 0.0, -s), DVec3::Y, DVec3::new(s, 0.0, c))
}
/// Right-handed rotation about z by `c` radians (positive tilts x toward y).
pub fn rot_z(c: f64) -> DMat3 {
    let (s, co) = c.sin_cos();
    DMat3::from_cols(DVec3::new(co, s, 0.0), DVec3::new(-s, co, 0.0), DVec3::Z)
}

/// Zemax "Tilt About X, then Y, then Z" (moving axes): R = Rx(a)·Ry(b)·Rz(c), angles in radians.
/// This is the local-to-global rotation OpticStudio reports for a surface tilted by (a, b, c).
pub fn rotation_xyz(a: f64, b: f64, c: f64) -> DMat3 {
    rot_x(a) * rot_y(b) * rot_z(c)
}

/// Decompose R = Rx(a)·Ry(b)·Rz(c) into (a, b, c) radians, b ∈ [-π/2, π/2].
/// Used to express arbitrary relative orientations (YAML import) as Coordinate Breaks.
pub fn decompose_xyz(r: DMat3) -> (f64, f64, f64) {
    // R = Rx Ry Rz: R[2][0] (row 0, col 2) = sin b; row0: (cb cc, -cb sc, sb)
    // row1 col2 = -sa cb ; row2 col2 = ca cb
    let m = r.to_cols_array_2d(); // m[col][row]
    let sb = m[2][0].clamp(-1.0, 1.0);
    let b = sb.asin();
    if sb.abs() < 1.0 - 1e-12 {
        let a = (-m[2][1]).atan2(m[2][2]);
        let c = (-m[1][0]).atan2(m[0][0]);
        (a, b, c)
    } else {
        // gimbal lock: put all the x/z freedom in a
        let a = m[1][2].atan2(m[1][1]);
        (a, b, 0.0)
    }
}

/// Decenter order of a Zemax Coordinate Break (the "Order" column).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum BreakOrder {
    /// Order 0: decenter in x and y, then tilt about x, then y, then z (Zemax default).
    #[default]
    DecenterThenTilt,
    /// Order ≠ 0: tilt about z, then y, then x, then decenter along the tilted axes.
    /// The exact inverse of an order-0 break with all parameters negated.
    TiltThenDecenter,
}

/// The frame after a Zemax Coordinate Break placed at `frame` (lengths mm, angles radians).
pub fn coordinate_break_frame(
    frame: &Frame,
    decenter_x: f64,
    decenter_y: f64,
    tilt_x: f64,
    tilt_y: f64,
    tilt_z: f64,
    order: BreakOrder,
) -> Frame {
    let dec = DVec3::new(decenter_x, decenter_y, 0.0);
    match order {
        BreakOrder::DecenterThenTilt => {
            let origin = frame.point_to_global(dec);
            Frame { origin, rotation: frame.rotation * rotation_xyz(tilt_x, tilt_y, tilt_z) }
        }
        BreakOrder::TiltThenDecenter => {
            let rotation = frame.rotation * rot_z(tilt_z) * rot_y(tilt_y) * rot_x(tilt_x);
            Frame { origin: frame.origin + rotation * dec, rotation }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn order_one_inverts_order_zero() {
        let f0 = Frame::new(DVec3::new(1.0, -2.0, 3.0), rotation_xyz(0.1, -0.2, 0.3));
        let (dx, dy, a, b, c) = (0.7, -1.3, 0.21, -0.43, 0.11);
        let f1 = coordinate_break_frame(&f0, dx, dy, a, b, c, BreakOrder::DecenterThenTilt);
        let f2 = coordinate_break_frame(&f1, -dx, -dy, -a, -b, -c, BreakOrder::TiltThenDecenter);
        assert!((f2.origin - f0.origin).length() < 1e-13);
        assert!((f2.rotation - f0.rotation).to_cols_array().iter().all(|v| v.abs() < 1e-13));
    }

    #[test]
    fn decompose_roundtrip() {
        for &(a, b, c) in &[(0.1, 0.2, 0.3), (-1.0, 0.5, 2.0), (0.0, -0.0873, 0.0), (3.0, -1.2, -2.5)] {
            let (a2, b2, c2) = decompose_xyz(rotation_xyz(a, b, c));
            let r1 = rotation_xyz(a, b, c);
            let r2 = rotation_xyz(a2, b2, c2);
            assert!((r1 - r2).to_cols_array().iter().all(|v| v.abs() < 1e-12), "{a} {b} {c}");
        }
    }

    #[test]
    fn positive_tilt_y_turns_z_toward_x() {
        let r = rotation_xyz(0.0, 0.3, 0.0);
        assert!(r.z_axis.x > 0.0);
        let r = rotation_xyz(0.3, 0.0, 0.0);
        assert!(r.z_axis.y < 0.0, "right-handed rotation about x turns z toward -y");
    }
}
