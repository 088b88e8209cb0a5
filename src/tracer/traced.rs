use super::RayStatus;

/// Rays at the image surface, struct-of-arrays, in the image surface's local frame (mm, unit directions).
/// For a ray whose status is not `Ok`, position and direction are 0 and `surface` names where it stopped.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TracedBatch {
    pub x: Vec<f64>,
    pub y: Vec<f64>,
    pub z: Vec<f64>,
    pub dir_x: Vec<f64>,
    pub dir_y: Vec<f64>,
    pub dir_z: Vec<f64>,
    pub status: Vec<RayStatus>,
    /// Surface index where a failed ray stopped (`u32::MAX` for `Ok`).
    pub surface: Vec<u32>,
}

impl TracedBatch {
    /// Reclassify arrived rays whose position or direction is non-finite or implausible (|x|, |y|, |z|
    /// beyond [`crate::limits::MAX_IMAGE_COORD_MM`]) as [`RayStatus::OutOfRange`] at `image_surface`, with
    /// zeroed position and direction (failed rays carry no position). Every tracer calls it last.
    pub fn classify_out_of_range(&mut self, image_surface: u32) {
        let lim = crate::limits::MAX_IMAGE_COORD_MM;
        for i in 0..self.status.len() {
            if self.status[i] != RayStatus::Ok {
                continue;
            }
            let p = [self.x[i], self.y[i], self.z[i]];
            let d = [self.dir_x[i], self.dir_y[i], self.dir_z[i]];
            if p.iter().all(|v| v.is_finite() && v.abs() <= lim) && d.iter().all(|v| v.is_finite()) {
                continue;
            }
            self.status[i] = RayStatus::OutOfRange;
            self.surface[i] = image_surface;
            (self.x[i], self.y[i], self.z[i], self.dir_x[i], self.dir_y[i], self.dir_z[i]) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        }
    }

    pub fn zeroed(n: usize) -> Self {
        TracedBatch {
            x: vec![0.0; n],
            y: vec![0.0; n],
            z: vec![0.0; n],
            dir_x: vec![0.0; n],
            dir_y: vec![0.0; n],
            dir_z: vec![0.0; n],
            status: vec![RayStatus::Ok; n],
            surface: vec![u32::MAX; n],
        }
    }
    pub fn len(&self) -> usize {
        self.x.len()
    }
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }
    pub fn ok_count(&self) -> usize {
        self.status.iter().filter(|s| **s == RayStatus::Ok).count()
    }
    /// Positions (x, y) of the rays that arrived.
    pub fn ok_positions(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        (0..self.len()).filter(move |&i| self.status[i] == RayStatus::Ok).map(move |i| (self.x[i], self.y[i]))
    }
}
