//! Natural test scenes: hyperspectral reflectance cubes from ordinary RGB photographs (Smits' RGB → spectrum
//! uplift), and a measured-spectra colour chart (the 24-patch ColorChecker, reflectances measured by Ohta).
//!
//! **RGB → spectrum (Smits 1999).** B. Smits, "An RGB-to-Spectrum Conversion for Reflectances", Journal of
//! Graphics Tools 4(4):11–22, 1999. Seven smooth basis reflectances — white, cyan, magenta, yellow, red, green,
//! blue — are combined so the result is as smooth as possible: with m = the smallest of the linear (r, g, b), the
//! spectrum is m·white + (mid − m)·(the secondary of the two larger channels) + (max − mid)·(the primary of the
//! largest), e.g. for r ≤ g ≤ b: r·white + (g − r)·cyan + (b − g)·blue. The basis numbers are pbrt-v3's
//! 32-sample tables of Smits' spectra (380–720 nm; M. Pharr, W. Jakob, G. Humphreys, *Physically Based
//! Rendering*, 3rd ed., §5.2.2, `src/core/spectrum.cpp`, `RGBRefl2Spect*`, BSD-2 licence), evaluated at any
//! wavelength by linear interpolation (held constant beyond the table). As pbrt does, the sum is scaled by
//! 0.94 (the basis white is ≈ 1.062, so a white pixel stays a physical reflectance) and clamped to [0, 1]. The
//! photograph's 8/16-bit values are sRGB-encoded: they are linearised (IEC 61966-2-1) first. Measured round
//! trip on the 23 in-gamut ColorChecker patches (sRGB → spectrum → XYZ under D65): ΔE*ab mean 1.2, max 5.1
//! over 380–780 nm; mean 1.4, max 6.8 seen through 28 bands 450–650 nm (test `chart_round_trip_delta_e`).
//! The spectra are plausible (smooth, non-negative, bounded, metameric to the pixel's colour up to the clamp) but
//! not the true spectra of the photographed objects; real spectral data (KAIST, CAVE) stays the reference.
//!
//! **Colour chart.** The X-Rite/Macbeth ColorChecker Classic (4 rows × 6 patches on a black frame) with the
//! reflectances measured by N. Ohta (1997), *The basis of color reproduction engineering*, 380–780 nm by 5 nm
//! (via colour-science's dataset, see `scripts/make_color_tables.py`).
//!
//! ```
//! use diffcassi::scene::natural::{rgb_to_reflectance, colour_checker_scene};
//! let ws: Vec<f64> = (0..28).map(|k| 450.0 + 200.0 * k as f64 / 27.0).collect();
//! let white = rgb_to_reflectance([1.0, 1.0, 1.0], &ws);
//! assert!(white.iter().all(|&v| v > 0.99 && v <= 1.0));
//! let chart = colour_checker_scene(96, &ws);
//! assert!(chart.data.iter().all(|v| (0.0..=1.0).contains(v)));
//! ```
pub use super::color_tables::COLORCHECKER_NAMES;
use super::color_tables::{COLORCHECKER_OHTA, TABLE_LEN, TABLE_START_NM, TABLE_STEP_NM};
use super::colorimetry::srgb_decode;
use super::SpectralCube;
use crate::error::{Error, Result};
use std::path::Path;

/// Wavelengths (nm) of Smits' basis spectra as tabulated by pbrt-v3 (`RGB2SpectLambda`): 32 samples, 380–720 nm.
pub const SMITS_LAMBDA_NM: [f64; 32] = [
    380.000000, 390.967743, 401.935486, 412.903229, 423.870972, 434.838715, 445.806458, 456.774200, 467.741943, 478.709686, 489.677429, 500.645172,
    511.612915, 522.580627, 533.548340, 544.516052, 555.483765, 566.451477, 577.419189, 588.386902, 599.354614, 610.322327, 621.290039, 632.257751,
    643.225464, 654.193176, 665.160889, 676.128601, 687.096313, 698.064026, 709.031738, 720.000000,
];

/// pbrt-v3 `RGBRefl2SpectWhite`.
pub const SMITS_WHITE: [f64; 32] = [
    1.0618958571272863e+00, 1.0615019980348779e+00, 1.0614335379927147e+00, 1.0622711654692485e+00, 1.0622036218416742e+00, 1.0625059965187085e+00,
    1.0623938486985884e+00, 1.0624706448043137e+00, 1.0625048144827762e+00, 1.0624366131308856e+00, 1.0620694238892607e+00, 1.0613167586932164e+00,
    1.0610334029377020e+00, 1.0613868564828413e+00, 1.0614215366116762e+00, 1.0620336151299086e+00, 1.0625497454805051e+00, 1.0624317487992085e+00,
    1.0625249140554480e+00, 1.0624277664486914e+00, 1.0624749854090769e+00, 1.0625538581025402e+00, 1.0625326910104864e+00, 1.0623922312225325e+00,
    1.0623650980354129e+00, 1.0625256476715284e+00, 1.0612277619533155e+00, 1.0594262608698046e+00, 1.0599810758292072e+00, 1.0602547314449409e+00,
    1.0601263046243634e+00, 1.0606565756823634e+00,
];
/// pbrt-v3 `RGBRefl2SpectCyan`.
pub const SMITS_CYAN: [f64; 32] = [
    1.0414628021426751e+00, 1.0328661533771188e+00, 1.0126146228964314e+00, 1.0350460524836209e+00, 1.0078661447098567e+00, 1.0422280385081280e+00,
    1.0442596738499825e+00, 1.0535238290294409e+00, 1.0180776226938120e+00, 1.0442729908727713e+00, 1.0529362541920750e+00, 1.0537034271160244e+00,
    1.0533901869215969e+00, 1.0537782700979574e+00, 1.0527093770467102e+00, 1.0530449040446797e+00, 1.0550554640191208e+00, 1.0553673610724821e+00,
    1.0454306634683976e+00, 6.2348950639230805e-01, 1.8038071613188977e-01, -7.6303759201984539e-03, -1.5217847035781367e-04, -7.5102257347258311e-03,
    -2.1708639328491472e-03, 6.5919466602369636e-04, 1.2278815318539780e-02, -4.4669775637208031e-03, 1.7119799082865147e-02, 4.9211089759759801e-03,
    5.8762925143334985e-03, 2.5259399415550079e-02,
];
/// pbrt-v3 `RGBRefl2SpectMagenta`.
pub const SMITS_MAGENTA: [f64; 32] = [
    9.9422138151236850e-01, 9.8986937122975682e-01, 9.8293658286116958e-01, 9.9627868399859310e-01, 1.0198955019000133e+00, 1.0166395501210359e+00,
    1.0220913178757398e+00, 9.9651666040682441e-01, 1.0097766178917882e+00, 1.0215422470827016e+00, 6.4031953387790963e-01, 2.5012379477078184e-03,
    6.5339939555769944e-03, 2.8334080462675826e-03, -5.1209675389074505e-11, -9.0592291646646381e-03, 3.3936718323331200e-03, -3.0638741121828406e-03,
    2.2203936168286292e-01, 6.3141140024811970e-01, 9.7480985576500956e-01, 9.7209562333590571e-01, 1.0173770302868150e+00, 9.9875194322734129e-01,
    9.4701725739602238e-01, 8.5258623154354796e-01, 9.4897798581660842e-01, 9.4751876096521492e-01, 9.9598944191059791e-01, 8.6301351503809076e-01,
    8.9150987853523145e-01, 8.4866492652845082e-01,
];
/// pbrt-v3 `RGBRefl2SpectYellow`.
pub const SMITS_YELLOW: [f64; 32] = [
    5.5740622924920873e-03, -4.7982831631446787e-03, -5.2536564298613798e-03, -6.4571480044499710e-03, -5.9693514658007013e-03, -2.1836716037686721e-03,
    1.6781120601055327e-02, 9.6096355429062641e-02, 2.1217357081986446e-01, 3.6169133290685068e-01, 5.3961011543232529e-01, 7.4408810492171507e-01,
    9.2209571148394054e-01, 1.0460304298411225e+00, 1.0513824989063714e+00, 1.0511991822135085e+00, 1.0510530911991052e+00, 1.0517397230360510e+00,
    1.0516043086790485e+00, 1.0511944032061460e+00, 1.0511590325868068e+00, 1.0516612465483031e+00, 1.0514038526836869e+00, 1.0515941029228475e+00,
    1.0511460436960840e+00, 1.0515123758830476e+00, 1.0508871369510702e+00, 1.0508923708102380e+00, 1.0477492815668303e+00, 1.0493272144017338e+00,
    1.0435963333422726e+00, 1.0392280772051465e+00,
];
/// pbrt-v3 `RGBRefl2SpectRed`.
pub const SMITS_RED: [f64; 32] = [
    1.6575604867086180e-01, 1.1846442802747797e-01, 1.2408293329637447e-01, 1.1371272058349924e-01, 7.8992434518899132e-02, 3.2205603593106549e-02,
    -1.0798365407877875e-02, 1.8051975516730392e-02, 5.3407196598730527e-03, 1.3654918729501336e-02, -5.9564213545642841e-03, -1.8444365067353252e-03,
    -1.0571884361529504e-02, -2.9375521078000011e-03, -1.0790476271835936e-02, -8.0224306697503633e-03, -2.2669167702495940e-03, 7.0200240494706634e-03,
    -8.1528469000299308e-03, 6.0772866969252792e-01, 9.8831560865432400e-01, 9.9391691044078823e-01, 1.0039338994753197e+00, 9.9234499861167125e-01,
    9.9926530858855522e-01, 1.0084621557617270e+00, 9.8358296827441216e-01, 1.0085023660099048e+00, 9.7451138326568698e-01, 9.8543269570059944e-01,
    9.3495763980962043e-01, 9.8713907792319400e-01,
];
/// pbrt-v3 `RGBRefl2SpectGreen`.
pub const SMITS_GREEN: [f64; 32] = [
    2.6494153587602255e-03, -5.0175013429732242e-03, -1.2547236272489583e-02, -9.4554964308388671e-03, -1.2526086181600525e-02, -7.9170697760437767e-03,
    -7.9955735204175690e-03, -9.3559433444469070e-03, 6.5468611982999303e-02, 3.9572875517634137e-01, 7.5244022299886659e-01, 9.6376478690218559e-01,
    9.9854433855162328e-01, 9.9992977025287921e-01, 9.9939086751140449e-01, 9.9994372267071396e-01, 9.9939121813418674e-01, 9.9911237310424483e-01,
    9.6019584878271580e-01, 6.3186279338432438e-01, 2.5797401028763473e-01, 9.4014888527335638e-03, -3.0798345608649747e-03, -4.5230367033685034e-03,
    -6.8933410388274038e-03, -9.0352195539015398e-03, -8.5913667165340209e-03, -8.3690869120289398e-03, -7.8685832338754313e-03, -8.3657578711085132e-06,
    5.4301225442817177e-03, -2.7745589759259194e-03,
];
/// pbrt-v3 `RGBRefl2SpectBlue`.
pub const SMITS_BLUE: [f64; 32] = [
    9.9209771469720676e-01, 9.8876426059369127e-01, 9.9539040744505636e-01, 9.9529317353008218e-01, 9.9181447411633950e-01, 1.0002584039673432e+00,
    9.9968478437342512e-01, 9.9988120766657174e-01, 9.8504012146370434e-01, 7.9029849053031276e-01, 5.6082198617463974e-01, 3.3133458513996528e-01,
    1.3692410840839175e-01, 1.8914906559664151e-02, -5.1129770932550889e-06, -4.2395493167891873e-04, -4.1934593101534273e-04, 1.7473028136486615e-03,
    3.7999160177631316e-03, -5.5101474906588642e-04, -4.3716662898480967e-05, 7.5874501748732798e-03, 2.5795650780554021e-02, 3.8168376532500548e-02,
    4.9489586408030833e-02, 4.9595992290102905e-02, 4.9814819505812249e-02, 3.9840911064978023e-02, 3.0501024937233868e-02, 2.1243054765241080e-02,
    6.9596532104356399e-03, 4.1733649330980525e-03,
];

/// pbrt's scale of the reflectance sum (keeps a white pixel ≤ 1).
pub const SMITS_SCALE: f64 = 0.94;

/// Linear interpolation of a table at `w` (nm), constant beyond its ends.
fn interp(xs: &[f64], ys: &[f64], w: f64) -> f64 {
    if w <= xs[0] {
        return ys[0];
    }
    if w >= xs[xs.len() - 1] {
        return ys[ys.len() - 1];
    }
    let k = xs.partition_point(|&x| x <= w) - 1;
    let t = (w - xs[k]) / (xs[k + 1] - xs[k]);
    (1.0 - t) * ys[k] + t * ys[k + 1]
}

/// Smits' seven basis spectra evaluated at the given wavelengths, for uplifting many pixels.
#[derive(Clone, Debug)]
pub struct SmitsBasis {
    /// white, cyan, magenta, yellow, red, green, blue; each one value per wavelength.
    spectra: [Vec<f64>; 7],
    pub wavelengths_nm: Vec<f64>,
}

impl SmitsBasis {
    pub fn new(wavelengths_nm: &[f64]) -> Self {
        let tables = [&SMITS_WHITE, &SMITS_CYAN, &SMITS_MAGENTA, &SMITS_YELLOW, &SMITS_RED, &SMITS_GREEN, &SMITS_BLUE];
        let spectra = tables.map(|t| wavelengths_nm.iter().map(|&w| interp(&SMITS_LAMBDA_NM, t, w)).collect());
        SmitsBasis { spectra, wavelengths_nm: wavelengths_nm.to_vec() }
    }

    /// Reflectance (one value per wavelength, in [0, 1]) of a **linear** RGB triple, written into `out`.
    pub fn reflectance_into(&self, rgb: [f64; 3], out: &mut [f32]) {
        const WHITE: usize = 0;
        const CYAN: usize = 1;
        const MAGENTA: usize = 2;
        const YELLOW: usize = 3;
        const RED: usize = 4;
        const GREEN: usize = 5;
        const BLUE: usize = 6;
        let [r, g, b] = rgb.map(|c| c.clamp(0.0, 1.0));
        // (weight, basis) pairs following Smits' case analysis on the smallest channel.
        let terms: [(f64, usize); 3] = if r <= g && r <= b {
            if g <= b { [(r, WHITE), (g - r, CYAN), (b - g, BLUE)] } else { [(r, WHITE), (b - r, CYAN), (g - b, GREEN)] }
        } else if g <= r && g <= b {
            if r <= b { [(g, WHITE), (r - g, MAGENTA), (b - r, BLUE)] } else { [(g, WHITE), (b - g, MAGENTA), (r - b, RED)] }
        } else if r <= g {
            [(b, WHITE), (r - b, YELLOW), (g - r, GREEN)]
        } else {
            [(b, WHITE), (g - b, YELLOW), (r - g, RED)]
        };
        for (k, o) in out.iter_mut().enumerate() {
            let v: f64 = terms.iter().map(|&(w, s)| w * self.spectra[s][k]).sum();
            *o = (SMITS_SCALE * v).clamp(0.0, 1.0) as f32;
        }
    }
}

/// Reflectance at `wavelengths_nm` of a linear RGB triple (components in [0, 1]; clamped).
pub fn rgb_to_reflectance(linear_rgb: [f64; 3], wavelengths_nm: &[f64]) -> Vec<f32> {
    let mut out = vec![0.0f32; wavelengths_nm.len()];
    SmitsBasis::new(wavelengths_nm).reflectance_into(linear_rgb, &mut out);
    out
}

/// An RGB photograph as encoded sRGB values in [0, 1], row-major `[row][col][channel]`.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub height: usize,
    pub width: usize,
    pub srgb: Vec<f32>,
}

/// Whether a path names an RGB photograph this module reads (`.png`, `.jpg`, `.jpeg`).
pub fn is_rgb_image(path: &Path) -> bool {
    matches!(path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase()).as_deref(), Some("png"))
}

/// Read an 8- or 16-bit PNG (RGB, RGBA — alpha ignored — or greyscale, replicated) as encoded sRGB in [0, 1].
/// The header is read first: an image whose decoding would exceed the memory budget is refused before it is
/// decoded ([`crate::limits::bytes_rgb_decode`]).
pub fn load_rgb_png(path: &Path) -> Result<RgbImage> {
    load_rgb_png_within(path, 0)
}

/// [`load_rgb_png`], refusing (before decoding) an image whose decoding plus a cube of `bands` bands at its
/// size would exceed the memory budget.
fn load_rgb_png_within(path: &Path, bands: usize) -> Result<RgbImage> {
    let ferr = |m: String| Error::File { path: path.display().to_string(), message: m };
    let bytes = crate::io::input::read_input(path, crate::io::input::binary_limit())?;
    crate::io::png16::png_dimensions_within_budget(path, &bytes, crate::limits::bytes_rgb_decode(1, 1) + crate::limits::bytes_cube(1, 1, bands))?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png).map_err(|e| ferr(format!("not a readable PNG: {e}")))?;
    let (width, height) = (img.width() as usize, img.height() as usize);
    if width == 0 || height == 0 {
        return Err(ferr("the image is empty".into()));
    }
    let srgb: Vec<f32> = img.to_rgb32f().into_raw();
    Ok(RgbImage { height, width, srgb })
}

/// Wavelength range (nm) of the Smits RGB → spectrum uplift: its basis tables (pbrt-v3), beyond which the
/// reflectances would be extrapolated (held constant).
pub const SMITS_RANGE_NM: (f64, f64) = (380.0, 720.0);
/// Wavelength range (nm) of the measured ColorChecker reflectances (Ohta 1997, 380–780 nm by 5 nm).
pub const COLORCHECKER_RANGE_NM: (f64, f64) = (TABLE_START_NM, TABLE_START_NM + TABLE_STEP_NM * (TABLE_LEN - 1) as f64);

/// Every wavelength inside `range` (nm), the tabulated range of `method`: outside it the reflectances would
/// be extrapolated, a silently wrong spectrum. The error names the first band outside, the method and range.
pub fn check_uplift_range(method: &str, range: (f64, f64), wavelengths_nm: &[f64]) -> Result<()> {
    if let Some((k, w)) = wavelengths_nm.iter().enumerate().find(|(_, w)| !(range.0..=range.1).contains(*w)) {
        return Err(Error::invalid(format!(
            "band {k} = {} nm is outside the {}–{} nm range of {method} (its reflectances would be extrapolated); choose bands within it",
            crate::limits::fmt_num(*w),
            range.0,
            range.1
        )));
    }
    Ok(())
}

/// Uplift an RGB photograph to a reflectance cube at `wavelengths_nm` (Smits 1999; see the module docs),
/// which must lie within [`SMITS_RANGE_NM`].
pub fn rgb_scene(image: &RgbImage, wavelengths_nm: &[f64]) -> Result<SpectralCube> {
    if wavelengths_nm.is_empty() {
        return Err(Error::invalid("an RGB scene needs at least one wavelength"));
    }
    check_uplift_range("the Smits RGB → spectrum uplift", SMITS_RANGE_NM, wavelengths_nm)?;
    crate::limits::check_memory(&format!("the {}×{} photograph uplifted to {} bands", image.height, image.width, wavelengths_nm.len()), crate::limits::bytes_cube(image.height, image.width, wavelengths_nm.len()))?;
    let basis = SmitsBasis::new(wavelengths_nm);
    let nb = wavelengths_nm.len();
    let mut data = vec![0.0f32; image.height * image.width * nb];
    // Linearise through a 16-bit lookup (exact for 8- and 16-bit sources).
    let lut: Vec<f64> = (0..=65535).map(|i| srgb_decode(i as f64 / 65535.0)).collect();
    let lin = |v: f32| lut[(v.clamp(0.0, 1.0) as f64 * 65535.0).round() as usize];
    for (px, out) in image.srgb.chunks_exact(3).zip(data.chunks_exact_mut(nb)) {
        basis.reflectance_into([lin(px[0]), lin(px[1]), lin(px[2])], out);
    }
    SpectralCube::new(image.height, image.width, wavelengths_nm.to_vec(), data, "RGB scene")
}

/// Read an RGB PNG and uplift it (default wavelengths: 28 bands 450–650 nm).
pub fn load_rgb_scene(path: &Path, wavelengths_nm: Option<&[f64]>) -> Result<SpectralCube> {
    let default = crate::analysis::linspace(450.0, 650.0, 28);
    let ws = wavelengths_nm.unwrap_or(&default);
    check_uplift_range("the Smits RGB → spectrum uplift", SMITS_RANGE_NM, ws).map_err(|e| Error::File { path: path.display().to_string(), message: e.to_string() })?;
    let img = load_rgb_png_within(path, ws.len())?;
    rgb_scene(&img, ws).map_err(|e| Error::File { path: path.display().to_string(), message: e.to_string() })
}

/// The reflectance of ColorChecker patch `k` (chart order, 0 = dark skin) at `w` nm (Ohta 1997 data).
pub fn colour_checker_reflectance(k: usize, w: f64) -> f64 {
    let xs: Vec<f64> = (0..TABLE_LEN).map(|i| TABLE_START_NM + TABLE_STEP_NM * i as f64).collect();
    interp(&xs, &COLORCHECKER_OHTA[k], w)
}

/// A `size × size` scene of the 24-patch ColorChecker (4 rows × 6 columns, centred, patch gaps 1/6 of the
/// pitch) on a frame of the chart's black (patch 24) reflectance.
pub fn colour_checker_scene(size: usize, wavelengths_nm: &[f64]) -> SpectralCube {
    let nb = wavelengths_nm.len();
    let spectra: Vec<Vec<f32>> = (0..24).map(|k| wavelengths_nm.iter().map(|&w| colour_checker_reflectance(k, w) as f32).collect()).collect();
    let pitch = size as f64 / 6.25; // 6 patch pitches plus a quarter-pitch margin
    let gap = pitch / 6.0;
    let (x0, y0) = ((size as f64 - 6.0 * pitch) / 2.0, (size as f64 - 4.0 * pitch) / 2.0);
    let mut data = vec![0.0f32; size * size * nb];
    for r in 0..size {
        for c in 0..size {
            let (y, x) = (r as f64 + 0.5 - y0, c as f64 + 0.5 - x0);
            let (i, j) = ((y / pitch).floor(), (x / pitch).floor());
            let inside = (0.0..4.0).contains(&i) && (0.0..6.0).contains(&j) && y - i * pitch >= gap / 2.0 && y - i * pitch < pitch - gap / 2.0 && x - j * pitch >= gap / 2.0 && x - j * pitch < pitch - gap / 2.0;
            let k = if inside { i as usize * 6 + j as usize } else { 23 };
            data[(r * size + c) * nb..(r * size + c + 1) * nb].copy_from_slice(&spectra[k]);
        }
    }
    SpectralCube { height: size, width: size, wavelengths_nm: wavelengths_nm.to_vec(), data }
}

#[cfg(test)]
mod tests {
    use super::super::color_tables::COLORCHECKER_SRGB_FIXTURE;
    use super::super::colorimetry::{delta_e76, linear_srgb_to_xyz, XyzWeights};
    use super::*;

    fn bands28() -> Vec<f64> {
        crate::analysis::linspace(450.0, 650.0, 28)
    }

    #[test]
    fn white_is_flat_black_is_zero_and_values_are_reflectances() {
        let ws = bands28();
        let white = rgb_to_reflectance([1.0; 3], &ws);
        let (lo, hi) = white.iter().fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
        assert!(hi <= 1.0 && lo > 0.99 && hi - lo < 0.005, "white spans {lo}..{hi}");
        assert!(rgb_to_reflectance([0.0; 3], &ws).iter().all(|&v| v == 0.0));
        let basis = SmitsBasis::new(&ws);
        let mut out = vec![0.0f32; ws.len()];
        for i in 0..=10 {
            for j in 0..=10 {
                for k in 0..=10 {
                    basis.reflectance_into([i as f64 / 10.0, j as f64 / 10.0, k as f64 / 10.0], &mut out);
                    assert!(out.iter().all(|v| (0.0..=1.0).contains(v)));
                }
            }
        }
        // A grey is a scaled white.
        let grey = rgb_to_reflectance([0.5; 3], &ws);
        assert!(grey.iter().zip(&white).all(|(g, w)| (g - 0.5 * w).abs() < 1e-6));
    }

    #[test]
    fn primaries_put_energy_where_they_should() {
        let ws = bands28();
        let red = rgb_to_reflectance([1.0, 0.0, 0.0], &ws);
        let blue = rgb_to_reflectance([0.0, 0.0, 1.0], &ws);
        assert!(red[27] > 0.85 && red[0] < 0.05, "{red:?}");
        assert!(blue[0] > 0.85 && blue[27] < 0.1, "{blue:?}");
    }

    /// Round trip of the chart: colour-science's sRGB of every measured patch → Smits spectrum → our
    /// colorimetry (full 380–780 nm, and as the pipeline sees it, 28 bands 450–650 nm held constant beyond) →
    /// ΔE*ab against the patch's own XYZ. In-gamut patches only (cyan is outside sRGB).
    #[test]
    fn chart_round_trip_delta_e() {
        let full: Vec<f64> = (0..81).map(|i| 380.0 + 5.0 * i as f64).collect();
        let mut worst = [0.0f64; 2];
        let mut mean = [0.0f64; 2];
        let mut n = 0;
        for s in COLORCHECKER_SRGB_FIXTURE.iter() {
            if s.iter().any(|&c| !(0.0..=1.0).contains(&c)) {
                continue;
            }
            let lin = s.map(srgb_decode);
            let target = linear_srgb_to_xyz(lin);
            for (m, ws) in [full.clone(), bands28()].iter().enumerate() {
                let refl = rgb_to_reflectance(lin, ws);
                let xyz = XyzWeights::new(ws).xyz(&refl);
                let de = delta_e76(target, xyz);
                worst[m] = worst[m].max(de);
                mean[m] += de;
            }
            n += 1;
        }
        mean.iter_mut().for_each(|m| *m /= n as f64);
        eprintln!("Smits round trip on {n} ColorChecker patches: ΔE*ab mean {:.2} / max {:.2} (380–780 nm), mean {:.2} / max {:.2} (28 bands 450–650 nm)", mean[0], worst[0], mean[1], worst[1]);
        // Measured: mean 1.20 / max 5.09 (full), mean 1.42 / max 6.83 (28 bands).
        assert!(mean[0] < 1.5 && worst[0] < 5.5, "full range ΔE mean {} max {}", mean[0], worst[0]);
        assert!(mean[1] < 1.7 && worst[1] < 7.5, "28-band ΔE mean {} max {}", mean[1], worst[1]);
    }

    #[test]
    fn chart_scene_has_24_patches_and_is_deterministic() {
        let ws = bands28();
        let a = colour_checker_scene(120, &ws);
        assert_eq!(a, colour_checker_scene(120, &ws));
        let mut distinct: Vec<Vec<u32>> = a.data.chunks_exact(ws.len()).map(|p| p.iter().map(|v| v.to_bits()).collect()).collect();
        distinct.sort();
        distinct.dedup();
        assert_eq!(distinct.len(), 24);
        // Patch 19 (white 9.5) at the bottom-left cell centre.
        let pitch = 120.0 / 6.25;
        let (r, c) = (((120.0 - 4.0 * pitch) / 2.0 + 3.5 * pitch) as usize, ((120.0 - 6.0 * pitch) / 2.0 + 0.5 * pitch) as usize);
        assert!((a.at(r, c, 10) as f64 - colour_checker_reflectance(18, ws[10])).abs() < 1e-6);
    }

    #[test]
    fn rgb_scene_is_deterministic_and_reads_png() {
        let dir = std::env::temp_dir().join(format!("diffcassi_natural_{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("t.png");
        let img = image::RgbImage::from_fn(5, 3, |x, y| image::Rgb([(x * 50) as u8, (y * 100) as u8, 200]));
        img.save(&p).unwrap();
        let a = load_rgb_scene(&p, None).unwrap();
        assert_eq!((a.height, a.width, a.bands()), (3, 5, 28));
        assert_eq!(a, load_rgb_scene(&p, None).unwrap());
        let direct = rgb_to_reflectance([srgb_decode(100.0 / 255.0), srgb_decode(200.0 / 255.0), srgb_decode(200.0 / 255.0)], &bands28());
        let px = &a.data[(2 * 5 + 2) * 28..(2 * 5 + 3) * 28];
        assert!(px.iter().zip(&direct).all(|(x, y)| (x - y).abs() < 1e-6));
        std::fs::write(dir.join("bad.png"), b"not a png").unwrap();
        assert!(load_rgb_scene(&dir.join("bad.png"), None).unwrap_err().to_string().contains("bad.png"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
