//! The dual-disperser presets `ddsp` and `mddsp` (DD-CASSI, Gehm et al., Opt. Express 15, 14013, 2007): SP's
//! first arm disperses the scene onto a coded mask at its image plane; a second arm, SP's first arm mirrored
//! in the plane of the mask, undoes the dispersion onto the detector.
//!
//! **Construction.** Surfaces 0–18 are SP's, as the preset builds them (its chief-ray solve included). SP's
//! image surface (19) becomes the coded-mask surface: flat, in air, 10 µm pixels (the scene pitch of the
//! default render, so that one mask pixel is about the image of one scene pixel: the first arm images at
//! magnification ≈ −1). After it come SP's surfaces 18, 17, …, 1 mirrored in the mask plane, then the
//! detector where SP's object plane is mirrored. Mirroring (M = diag(1, 1, −1) about the mask's vertex) a
//! surface whose vertex frame is G gives the right-handed frame M·G·M′ (M′ = diag(1, 1, −1) in local
//! coordinates; its +z is the direction of travel away from the mask), in which the surface's local points are
//! (x, y, −z): **radii and asphere terms change sign; conics, apertures and x, y are kept**. The
//! frame steps follow from G_{i+1} = G_i·C_i·T_z(t_i) (C_i the Coordinate Break of surface i):
//! H_i = H_{i+1}·T_z(t_i)·(M′ C_i⁻¹ M′), so the mirrored surface i comes at the thickness t_i after mirrored
//! surface i + 1, carries the thickness t_{i−1}, and the medium after old surface i − 1; a Coordinate Break
//! (order 0: decenter, then tilts x, y, z) becomes M′ C⁻¹ M′ = tilt z by −c, y by b, x by a, then decenter
//! (−dx, −dy): the opposite order flag with (−dx, −dy, a, b, −c) — since M′ R_x(a) M′ = R_x(−a),
//! M′ R_y(b) M′ = R_y(−b) and M′ R_z(c) M′ = R_z(c). Every pickup and solve of the second arm is SP's resolved
//! value (fixed).
//!
//! Why it cancels: a ray leaving the mask point Q in the mirrored arm is the mirror image of a ray going back
//! from Q through the first arm, which reaches the object point P that the first arm images onto Q at that
//! wavelength (point-to-point imaging, whatever the direction within the aperture). So the second arm maps
//! Q_λ to the mirror image of P at every λ: registered images, the mask sheared by each band's dispersion.
//! Aberrations cancel only for rays whose direction at the mask is mirror-symmetric (SP's stop sits near the
//! doublet's front focus: nearly telecentric at the mask), so a small residual remains (docs/study.md).
//!
//! `mddsp`: the second arm's prism tilted 5° about x (mSP's misalignment: the breaks 4 and 14 of SP tilted
//! by +5° and −5° before mirroring), its doublet's alignment kept as in `ddsp` (no re-solve).
//!
//! ```
//! let s = diffcassi::presets::spec("ddsp").unwrap();
//! assert_eq!(s.surfaces.len(), 39);
//! assert!(s.surfaces[19].coded_mask.is_some());
//! ```
use crate::error::Result;
use crate::spec::{Cell, CodedMaskSpec, MaskSampling, SurfaceKind, SurfaceSpec, SystemSpec};
use crate::system::SequentialSystem;

/// The coded mask's pixel pitch on `ddsp`'s mask surface (µm).
pub const DD_MASK_PITCH_UM: f64 = 10.0;

/// `ddsp` (`misaligned` false) or `mddsp` (true).
pub fn dd_spec(misaligned: bool) -> Result<SystemSpec> {
    let sp = super::spec("sp")?;
    let resolved = SequentialSystem::build(&sp)?.spec;
    let mut second = resolved.clone();
    if misaligned {
        // mSP's prism misalignment (its Lens Data Editor): break 4 tilted +5° about x, break 14 −5°.
        second.surfaces[4].tilt_x_deg = Some(Cell::fixed(5.0));
        second.surfaces[14].tilt_x_deg = Some(Cell::fixed(-5.0));
    }
    let last = sp.surfaces.len() - 1; // SP's image surface: the mask
    let mut surfaces: Vec<SurfaceSpec> = sp.surfaces[..last].to_vec();
    // Its thickness is SP's last gap (surface 18 → image): the mirrored doublet sits there.
    let mut mask = SurfaceSpec::standard(None, resolved.surfaces[last - 1].thickness_mm.value, None);
    mask.comment = "coded mask (SP's image plane)".into();
    mask.semi_diameter_mm = resolved.surfaces[last].semi_diameter_mm;
    mask.coded_mask = Some(CodedMaskSpec { pitch_um: DD_MASK_PITCH_UM, sampling: MaskSampling::Nearest });
    surfaces.push(mask);
    surfaces.extend(mirrored_arm(&second.surfaces[..last]));
    let mut image = SurfaceSpec::standard(None, 0.0, None);
    image.comment = "detector (SP's object plane, mirrored)".into();
    image.semi_diameter_mm = resolved.surfaces[0].semi_diameter_mm;
    surfaces.push(image);
    let mut s = sp;
    s.name = if misaligned { "mddsp" } else { "ddsp" }.into();
    s.description = if misaligned {
        "mDDSP: DDSP with its second prism tilted 5° about x".into()
    } else {
        "DDSP: dual-disperser CASSI — SP's arm onto a coded mask, then SP's arm mirrored onto the detector".into()
    };
    s.surfaces = surfaces;
    Ok(s)
}

/// Surfaces 1..n of `arm` (resolved values; surface 0 is the object) mirrored in the plane of the surface
/// after them, in the order a ray meets them going on: n − 1, …, 1 (see the module docs).
pub(crate) fn mirrored_arm(arm: &[SurfaceSpec]) -> Vec<SurfaceSpec> {
    // The medium after each surface (a Coordinate Break keeps the one before it).
    let mut medium: Vec<Option<String>> = Vec::with_capacity(arm.len());
    for s in arm {
        let m = if s.kind == SurfaceKind::CoordinateBreak { medium.last().cloned().flatten() } else { s.material.clone() };
        medium.push(m);
    }
    let fixed = |c: &Option<Cell>| c.as_ref().map(|c| Cell::fixed(c.value));
    let neg = |c: &Option<Cell>| c.as_ref().map(|c| Cell::fixed(-c.value));
    (1..arm.len())
        .rev()
        .map(|i| {
            let o = &arm[i];
            let mut s = SurfaceSpec::new(o.kind);
            s.comment = if o.comment.is_empty() { format!("mirror of surface {i}") } else { format!("mirror of surface {i}: {}", o.comment) };
            s.thickness_mm = Cell::fixed(arm[i - 1].thickness_mm.value);
            s.semi_diameter_mm = o.semi_diameter_mm;
            if o.kind == SurfaceKind::CoordinateBreak {
                s.decenter_x_mm = neg(&o.decenter_x_mm);
                s.decenter_y_mm = neg(&o.decenter_y_mm);
                s.tilt_x_deg = fixed(&o.tilt_x_deg);
                s.tilt_y_deg = fixed(&o.tilt_y_deg);
                s.tilt_z_deg = neg(&o.tilt_z_deg);
                s.order = 1 - o.order.min(1);
            } else {
                s.material = medium[i - 1].clone();
                s.radius_mm = neg(&o.radius_mm);
                s.conic = fixed(&o.conic);
                s.asphere_coefficients = o.asphere_coefficients.iter().map(|c| Cell::fixed(-c.value)).collect();
                s.focal_length_mm = fixed(&o.focal_length_mm);
                s.aperture = o.aperture.clone();
            }
            s
        })
        .collect()
}
