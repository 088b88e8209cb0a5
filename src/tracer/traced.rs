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
