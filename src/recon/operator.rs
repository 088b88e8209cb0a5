//! The linear-operator interface of reconstruction: Φ maps a cube x (H×W×B, f32, C order
//! `[row][col][band]`, like [`crate::scene::SpectralCube::data`]) to a detector image y (h×w, f32,
//! row-major), and Φᵀ maps back. Implementations promise the adjoint identity
//! ⟨Φx, y⟩ = ⟨x, Φᵀy⟩ (to f32 rounding) and nothing else; solvers rely on nothing else.
use crate::error::{Error, Result};

/// Shape of an operator's domain: a cube of `height × width` pixels and `bands` bands.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct CubeShape {
    pub height: usize,
    pub width: usize,
    pub bands: usize,
}

impl CubeShape {
    pub fn len(&self) -> usize {
        self.height * self.width * self.bands
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Shape of an operator's range: a detector image of `height × width` pixels.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ImageShape {
    pub height: usize,
    pub width: usize,
}

impl ImageShape {
    pub fn len(&self) -> usize {
        self.height * self.width
    }
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A linear map from cubes to detector images, with its adjoint.
pub trait Operator: Send + Sync {
    /// Short name (`exact`, `mapping`, `shift`, …) for reports.
    fn name(&self) -> &str;
    fn cube_shape(&self) -> CubeShape;
    fn image_shape(&self) -> ImageShape;
    /// image ← Φ cube. Slices have exactly the shapes' lengths (checked by [`apply`](dyn Operator::apply)).
    fn apply_into(&self, cube: &[f32], image: &mut [f32]);
    /// cube ← Φᵀ image.
    fn adjoint_into(&self, image: &[f32], cube: &mut [f32]);
}

impl dyn Operator + '_ {
    /// Φ cube, with the cube's length checked.
    pub fn apply(&self, cube: &[f32]) -> Result<Vec<f32>> {
        let (c, i) = (self.cube_shape(), self.image_shape());
        if cube.len() != c.len() {
            return Err(Error::invalid(format!(
                "operator `{}`: the cube has {} values, expected {}×{}×{} = {}",
                self.name(), cube.len(), c.height, c.width, c.bands, c.len()
            )));
        }
        let mut image = vec![0.0f32; i.len()];
        self.apply_into(cube, &mut image);
        Ok(image)
    }

    /// Φᵀ image, with the image's length checked.
    pub fn adjoint(&self, image: &[f32]) -> Result<Vec<f32>> {
        let (c, i) = (self.cube_shape(), self.image_shape());
        if image.len() != i.len() {
            return Err(Error::invalid(format!(
                "operator `{}`: the image has {} values, expected {}×{} = {}",
                self.name(), image.len(), i.height, i.width, i.len()
            )));
        }
        let mut cube = vec![0.0f32; c.len()];
        self.adjoint_into(image, &mut cube);
        Ok(cube)
    }

    /// The bands (indices) no detector pixel sees: Φᵀ𝟙 has no positive voxel in the band (the operators are
    /// non-negative), so a reconstruction is 0 there whatever the data — too few render planes for the bands,
    /// or the mask closed or passed by where the band's light lands. One adjoint. The solvers record them
    /// ([`Reconstruction::dark_bands`](crate::recon::Reconstruction::dark_bands)); Python's operator builders
    /// warn of them.
    pub fn dark_bands(&self) -> Vec<usize> {
        let (c, i) = (self.cube_shape(), self.image_shape());
        let mut sens = vec![0.0f32; c.len()];
        self.adjoint_into(&vec![1.0f32; i.len()], &mut sens);
        (0..c.bands).filter(|&b| sens.iter().skip(b).step_by(c.bands).all(|&v| !(v > 0.0))).collect()
    }
}
