//! Glass catalogues: name → [`Glass`], case-insensitive like Zemax.
//!
//! Names are normalised to upper case (Zemax shows and matches glass names in upper case,
//! so `n-bk7`, `N-BK7` and SCHOTT's mixed-case `N-BK7HTi` all resolve). Iteration is in
//! upper-case name order, so it is deterministic.
//!
//! [`GlassCatalog::builtin`] holds N-BK7, N-SK2, N-SF10, N-BAF10, SF10 and SK10 with
//! their `NM`, `CD`, `TD`, `ED`, `LD` and `GC` data typed in from SCHOTT.AGF (December 2024
//! release), so the binary works with no catalogue file; the values are bit-identical to
//! the parsed file. `IT` transmission data are not included in the built-in table.
//!
//! # Example
//!
//! ```
//! use diffcassi::materials::{GlassCatalog, MaterialError, Medium};
//!
//! let mut catalog = GlassCatalog::builtin();
//! // A file catalogue can be merged on top; its entries replace same-named built-ins.
//! catalog.merge(GlassCatalog::from_agf_str(
//!     "NM MY-GLASS 2 0 1.5168 64.17\nCD 1.03961212 0.00600069867 0.231792344 0.0200179144 1.01046945 103.560653\nLD 0.3 2.5\n",
//!     "MINE.AGF",
//! )?);
//! assert_eq!(catalog.len(), 7);
//! assert_eq!(catalog.get("my-glass")?.catalog, "MINE");
//! assert!(matches!(catalog.medium("")?, Medium::Air));
//! match catalog.get("N-BK8") {
//!     Err(MaterialError::UnknownGlass { suggestions, .. }) => {
//!         assert!(suggestions.contains(&"N-BK7".to_string()))
//!     }
//!     other => panic!("{other:?}"),
//! }
//! # Ok::<(), MaterialError>(())
//! ```

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use super::agf::parse_agf_document;
use super::dispersion::DispersionFormula;
use super::glass::{ExtraData, Glass, GlassInfo, GlassStatus, ThermalData};
use super::medium::Medium;
use super::MaterialError;

/// Maximum number of suggestions in an [`MaterialError::UnknownGlass`] error.
const MAX_SUGGESTIONS: usize = 5;

/// A set of glasses addressed by case-insensitive name.
#[derive(Clone, Debug, Default)]
pub struct GlassCatalog {
    /// Upper-case name → glass (whose `name` is the same upper-case string).
    glasses: BTreeMap<String, Arc<Glass>>,
    comments: Vec<String>,
}

impl GlassCatalog {
    /// An empty catalogue.
    pub fn new() -> Self {
        Self::default()
    }

    /// The built-in SCHOTT subset: N-BK7, N-SK2, N-SF10, N-BAF10, SF10, SK10.
    pub fn builtin() -> Self {
        let mut catalog = Self::new();
        for glass in builtin_glasses() {
            catalog.insert(glass);
        }
        catalog.comments.push(BUILTIN_COMMENT.to_string());
        catalog
    }

    /// Reads an AGF file (any encoding accepted by [`decode_agf_bytes`](super::decode_agf_bytes)).
    /// The catalogue name of its glasses is the upper-case file stem.
    ///
    /// # Errors
    /// [`MaterialError::Io`] naming the path if it cannot be read; parse errors name the
    /// path and line.
    pub fn from_agf_file(path: impl AsRef<Path>) -> Result<Self, MaterialError> {
        let path = path.as_ref();
        let shown = path.display().to_string();
        let bytes = crate::io::input::read_input(path, crate::limits::MAX_TEXT_FILE_BYTES).map_err(|e| MaterialError::Io {
            path: shown.clone(),
            message: match e {
                crate::io::IoError::Io { source, .. } => source.to_string(),
                crate::io::IoError::Input { reason, .. } => reason,
                other => other.to_string(),
            },
        })?;
        Self::from_agf_bytes(&bytes, &shown)
    }

    /// One entry of a spec's `glass_catalogs`: `builtin:NAME` is a built-in vendor catalogue
    /// ([`super::builtin_catalogs`]), anything else the path of an AGF file ([`from_agf_file`](Self::from_agf_file)).
    ///
    /// # Errors
    /// [`MaterialError::Io`] naming the entry for an unknown built-in name (listing the built-in ones) or an
    /// unreadable file; parse errors as for a file.
    pub fn from_entry(entry: impl AsRef<Path>) -> Result<Self, MaterialError> {
        let entry = entry.as_ref();
        match entry.to_str().and_then(super::builtin_catalogs::entry_name) {
            Some(name) => super::builtin_catalogs::catalog(name).unwrap_or_else(|| {
                Err(MaterialError::Io {
                    path: entry.display().to_string(),
                    message: format!(
                        "no built-in glass catalogue `{name}` (built in: {})",
                        super::builtin_catalogs::names().collect::<Vec<_>>().join(", ")
                    ),
                })
            }),
            None => Self::from_agf_file(entry),
        }
    }

    /// The content identity of one entry of a spec's `glass_catalogs`: `None` for a built-in catalogue
    /// (`builtin:NAME`, part of the program), else the file named by its content,
    /// `NAME (N bytes, crc32 X)` ([`crate::io::input::content_identity`]). A dataset's configuration names its
    /// catalogues so (the same glasses wherever the file lies); a copied `System` (Python's pickle and
    /// `copy`) carries the identities recorded when it was built, to refuse a file edited since
    /// ([`crate::system::SequentialSystem::check_catalog_identities`]).
    pub fn entry_identity(entry: &str) -> Option<std::io::Result<String>> {
        if super::builtin_catalogs::entry_name(entry).is_some() {
            return None;
        }
        Some(crate::io::input::content_identity(Path::new(entry)))
    }

    /// Parses AGF text; `source_name` is used in error messages and (file stem) as the
    /// catalogue name.
    pub fn from_agf_str(text: &str, source_name: &str) -> Result<Self, MaterialError> {
        Self::from_agf_bytes(text.as_bytes(), source_name)
    }

    /// Parses AGF bytes (UTF-8, Windows-1252 or UTF-16); see [`from_agf_str`](Self::from_agf_str).
    pub fn from_agf_bytes(bytes: &[u8], source_name: &str) -> Result<Self, MaterialError> {
        let doc = parse_agf_document(bytes, source_name)?;
        let mut catalog = Self {
            glasses: BTreeMap::new(),
            comments: doc.comments,
        };
        for glass in doc.glasses {
            catalog.insert(glass);
        }
        Ok(catalog)
    }

    /// Inserts a glass under its upper-cased name (the stored glass's `name` is upper-cased
    /// too), returning the glass it replaced, if any.
    pub fn insert(&mut self, mut glass: Glass) -> Option<Arc<Glass>> {
        let key = normalize(&glass.name);
        if glass.name != key {
            glass.name = key.clone();
        }
        self.glasses.insert(key, Arc::new(glass))
    }

    /// Adds all glasses of `other`. On a name clash the glass from `other` wins, so a file
    /// catalogue merged onto [`builtin`](Self::builtin) overrides it. (Zemax resolves a
    /// name in the first loaded catalogue that has it: to reproduce a Zemax catalogue
    /// order, merge the catalogues from last to first.) Comments are appended.
    pub fn merge(&mut self, other: GlassCatalog) {
        self.glasses.extend(other.glasses);
        self.comments.extend(other.comments);
    }

    /// The glass called `name` (case-insensitive, surrounding whitespace ignored).
    ///
    /// # Errors
    /// [`MaterialError::UnknownGlass`] with up to five close catalogue names.
    pub fn get(&self, name: &str) -> Result<Arc<Glass>, MaterialError> {
        self.find(name)
            .cloned()
            .ok_or_else(|| MaterialError::UnknownGlass {
                name: name.to_string(),
                suggestions: self.suggestions(name),
            })
    }

    /// The glass called `name` (case-insensitive), or `None`.
    pub fn find(&self, name: &str) -> Option<&Arc<Glass>> {
        self.glasses.get(&normalize(name))
    }

    /// `true` if a glass called `name` (case-insensitive) exists.
    pub fn contains(&self, name: &str) -> bool {
        self.find(name).is_some()
    }

    /// The medium for a Zemax material column entry: empty or `AIR` (any case) is
    /// [`Medium::Air`], anything else a catalogue glass.
    ///
    /// # Errors
    /// [`MaterialError::UnknownGlass`] if the glass is not in the catalogue.
    pub fn medium(&self, name: &str) -> Result<Medium, MaterialError> {
        let key = normalize(name);
        if key.is_empty() || key == "AIR" {
            Ok(Medium::Air)
        } else {
            self.get(name).map(Medium::Glass)
        }
    }

    /// Glasses in upper-case name order.
    pub fn iter(&self) -> impl Iterator<Item = &Arc<Glass>> + '_ {
        self.glasses.values()
    }

    /// Upper-case glass names in order.
    pub fn names(&self) -> impl Iterator<Item = &str> + '_ {
        self.glasses.keys().map(String::as_str)
    }

    /// Number of glasses.
    pub fn len(&self) -> usize {
        self.glasses.len()
    }

    /// `true` if the catalogue has no glass.
    pub fn is_empty(&self) -> bool {
        self.glasses.is_empty()
    }

    /// Appends catalogue comment lines (the `CC` lines of a built-in catalogue's tabulated glasses).
    pub fn extend_comments(&mut self, lines: impl IntoIterator<Item = String>) {
        self.comments.extend(lines);
    }

    /// `CC` comment lines of the merged catalogues.
    pub fn comments(&self) -> &[String] {
        &self.comments
    }

    /// Up to [`MAX_SUGGESTIONS`] names close to `name`: small edit distance, or one name
    /// containing the other.
    fn suggestions(&self, name: &str) -> Vec<String> {
        let query = normalize(name);
        if query.is_empty() {
            return Vec::new();
        }
        let q: Vec<char> = query.chars().collect();
        let max_distance = (q.len() / 3).max(2);
        let mut scored: Vec<(usize, &str)> = self
            .glasses
            .keys()
            .filter_map(|key| {
                let k: Vec<char> = key.chars().collect();
                let d = levenshtein(&q, &k);
                let related =
                    q.len() >= 3 && (key.contains(&query) || query.contains(key.as_str()));
                (d <= max_distance || related).then_some((d, key.as_str()))
            })
            .collect();
        scored.sort();
        scored
            .into_iter()
            .take(MAX_SUGGESTIONS)
            .map(|(_, k)| k.to_string())
            .collect()
    }
}

impl<'a> IntoIterator for &'a GlassCatalog {
    type Item = &'a Arc<Glass>;
    type IntoIter = std::collections::btree_map::Values<'a, String, Arc<Glass>>;
    fn into_iter(self) -> Self::IntoIter {
        self.glasses.values()
    }
}

/// Upper case, trimmed: the catalogue key of a glass name.
fn normalize(name: &str) -> String {
    name.trim().to_uppercase()
}

/// Edit distance (insert/delete/substitute), O(|a|·|b|).
fn levenshtein(a: &[char], b: &[char]) -> usize {
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    let mut cur = vec![0; b.len() + 1];
    for (i, ca) in a.iter().enumerate() {
        cur[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let sub = prev[j] + usize::from(ca != cb);
            cur[j + 1] = sub.min(prev[j + 1] + 1).min(cur[j] + 1);
        }
        std::mem::swap(&mut prev, &mut cur);
    }
    prev[b.len()]
}

// ---------------------------------------------------------------------------------------
// Built-in table, typed in from /work/shared/reference/glass/SCHOTT.AGF
// ("CC SCHOTT December 2024 preferred, inquiry, AR glasses (revC)").
// Literal spellings are kept identical to the file so that the f64 values are identical
// to what the parser reads.
// ---------------------------------------------------------------------------------------

const BUILTIN_COMMENT: &str =
    "built-in subset of SCHOTT December 2024 preferred, inquiry, AR glasses (revC)";

/// Typed-in AGF records of one built-in glass.
struct BuiltinGlass {
    /// NM: name, MIL code, nd, vd, exclude, status, melt frequency.
    name: &'static str,
    mil: &'static str,
    nd: f64,
    vd: f64,
    status: i64,
    melt: Option<i64>,
    /// GC
    comment: &'static str,
    /// ED: TCE(−30..70), TCE(100..300), density, ΔPgF, ignore-thermal-expansion.
    ed: [f64; 5],
    /// CD (Sellmeier 1): K1 L1 K2 L2 K3 L3.
    cd: [f64; 6],
    /// TD: D0 D1 D2 E0 E1 λtk Tref.
    td: [f64; 7],
    /// LD in µm.
    ld_um: [f64; 2],
}

const BUILTIN: [BuiltinGlass; 6] = [
    BuiltinGlass {
        name: "N-BK7",
        mil: "517642.251",
        nd: 1.5168,
        vd: 64.17,
        status: 1,
        melt: None,
        comment: "step 0.5 available",
        ed: [7.100000, 8.300000, 2.510000, -0.000900, 0.0],
        cd: super::dispersion::N_BK7_SELLMEIER1,
        td: [
            1.860000E-06,
            1.310000E-08,
            -1.370000E-11,
            4.340000E-07,
            6.270000E-10,
            1.700000E-01,
            2.000000E+01,
        ],
        ld_um: [3.00000E-01, 2.50000E+00],
    },
    BuiltinGlass {
        name: "N-SK2",
        mil: "607567.355",
        nd: 1.60738,
        vd: 56.65,
        status: 1,
        melt: None,
        comment: "step 0.5 available",
        ed: [6.000000, 7.100000, 3.550000, -0.000800, 0.0],
        cd: [
            1.281890120E+00,
            7.271916400E-03,
            2.577382580E-01,
            2.428235270E-02,
            9.681860400E-01,
            1.103777730E+02,
        ],
        td: [
            3.800000E-06,
            1.410000E-08,
            2.280000E-11,
            6.440000E-07,
            8.030000E-11,
            1.080000E-01,
            2.000000E+01,
        ],
        ld_um: [3.10000E-01, 2.50000E+00],
    },
    BuiltinGlass {
        name: "N-SF10",
        mil: "728285.305",
        nd: 1.72828,
        vd: 28.53,
        status: 1,
        melt: None,
        comment: "",
        ed: [9.400000, 10.800000, 3.050000, 0.010800, 0.0],
        cd: [
            1.621539020E+00,
            1.222414570E-02,
            2.562878420E-01,
            5.957367750E-02,
            1.644475520E+00,
            1.474687930E+02,
        ],
        td: [
            -4.680000E-06,
            7.410000E-09,
            -1.890000E-11,
            9.490000E-07,
            1.420000E-09,
            2.790000E-01,
            2.000000E+01,
        ],
        ld_um: [3.80000E-01, 2.50000E+00],
    },
    BuiltinGlass {
        name: "N-BAF10",
        mil: "670471.375",
        nd: 1.67003,
        vd: 47.11,
        status: 1,
        melt: None,
        comment: "",
        ed: [6.180000, 7.040000, 3.745000, -0.001600, 0.0],
        cd: [
            1.585149500E+00,
            9.266812820E-03,
            1.435593850E-01,
            4.244898050E-02,
            1.085212690E+00,
            1.056135730E+02,
        ],
        td: [
            3.790000E-06,
            1.280000E-08,
            -1.420000E-11,
            5.840000E-07,
            7.600000E-10,
            2.200000E-01,
            2.000000E+01,
        ],
        ld_um: [3.50000E-01, 2.50000E+00],
    },
    BuiltinGlass {
        name: "SF10",
        mil: "728284.428",
        nd: 1.72825,
        vd: 28.41,
        status: 1,
        melt: None,
        comment: "lead containing glass type",
        ed: [7.500000, 8.400000, 4.280000, 0.008500, 0.0],
        cd: [
            1.616259770E+00,
            1.275345590E-02,
            2.592293340E-01,
            5.819839540E-02,
            1.077623170E+00,
            1.166076800E+02,
        ],
        td: [
            5.310000E-06,
            1.590000E-08,
            -4.070000E-11,
            1.280000E-06,
            1.320000E-09,
            2.700000E-01,
            2.000000E+01,
        ],
        ld_um: [3.80000E-01, 2.50000E+00],
    },
    BuiltinGlass {
        name: "SK10",
        mil: "623569",
        nd: 1.622801,
        vd: 56.903777,
        status: 2,
        melt: Some(0),
        comment: "old",
        ed: [
            7.000000000E+000,
            8.000000000E+000,
            3.660000000E+000,
            -3.000000000E-004,
            0.0,
        ],
        cd: [
            1.316587400E+000,
            7.122292320E-003,
            2.716559490E-001,
            2.444170040E-002,
            9.686875430E-001,
            1.050815660E+002,
        ],
        td: [
            2.690000000E-007,
            1.110000000E-008,
            -8.910000000E-012,
            4.890000000E-007,
            6.130000000E-010,
            1.820000000E-001,
            2.000000000E+001,
        ],
        ld_um: [3.34000000E-001, 2.32500000E+000],
    },
];

fn builtin_glasses() -> impl Iterator<Item = Glass> {
    BUILTIN.iter().map(|b| Glass {
        name: b.name.to_string(),
        formula: DispersionFormula::Sellmeier1(b.cd),
        nd: b.nd,
        vd: b.vd,
        // Same expression as the AGF parser, so the bounds are bit-identical.
        min_wavelength_nm: b.ld_um[0] * 1000.0,
        max_wavelength_nm: b.ld_um[1] * 1000.0,
        catalog: "SCHOTT".to_string(),
        thermal: Some(ThermalData {
            d0: b.td[0],
            d1: b.td[1],
            d2: b.td[2],
            e0: b.td[3],
            e1: b.td[4],
            lambda_tk_um: b.td[5],
            reference_temperature_c: b.td[6],
        }),
        info: GlassInfo {
            mil_code: b.mil.to_string(),
            exclude_substitution: false,
            status: GlassStatus::from_code(b.status),
            melt_frequency: b.melt,
            comment: b.comment.to_string(),
            extra: Some(ExtraData {
                tce_minus30_70: Some(b.ed[0]),
                tce_100_300: Some(b.ed[1]),
                density_g_cm3: Some(b.ed[2]),
                delta_pg_f: Some(b.ed[3]),
                ignore_thermal_expansion: Some(b.ed[4] != 0.0),
            }),
            transmission: Vec::new(),
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builtin_has_six_glasses_matching_nd() {
        let c = GlassCatalog::builtin();
        assert_eq!(c.len(), 6);
        assert_eq!(
            c.names().collect::<Vec<_>>(),
            ["N-BAF10", "N-BK7", "N-SF10", "N-SK2", "SF10", "SK10"]
        );
        for g in c.iter() {
            let n = g.refractive_index(587.5618).unwrap();
            assert!((n - g.nd).abs() < 1e-4, "{}: {n} vs {}", g.name, g.nd);
            assert!((g.abbe_number().unwrap() - g.vd).abs() < 0.05, "{}", g.name);
            assert_eq!(g.catalog, "SCHOTT");
        }
    }

    #[test]
    fn lookup_is_case_insensitive() {
        let c = GlassCatalog::builtin();
        let a = c.get("n-bk7").unwrap();
        let b = c.get(" N-Bk7 ").unwrap();
        assert!(Arc::ptr_eq(&a, &b));
        assert_eq!(a.name, "N-BK7");
        assert!(c.contains("sf10"));
    }

    #[test]
    fn unknown_glass_error_lists_close_names() {
        let c = GlassCatalog::builtin();
        let e = c.get("NBK7").unwrap_err();
        let msg = e.to_string();
        assert!(msg.contains("NBK7") && msg.contains("N-BK7"), "{msg}");
        match c.get("completely-different").unwrap_err() {
            MaterialError::UnknownGlass { name, suggestions } => {
                assert_eq!(name, "completely-different");
                assert!(suggestions.is_empty());
            }
            e => panic!("{e:?}"),
        }
        // Substring relation: "SF1" is contained in SF10 and N-SF10.
        match c.get("sf1").unwrap_err() {
            MaterialError::UnknownGlass { suggestions, .. } => {
                assert!(suggestions.contains(&"SF10".to_string()), "{suggestions:?}");
            }
            e => panic!("{e:?}"),
        }
    }

    #[test]
    fn insert_normalises_and_merge_overrides() {
        let mut c = GlassCatalog::builtin();
        let mut g = (*c.get("N-BK7").unwrap()).clone();
        g.name = "n-bk7hti".into();
        g.nd = 1.0;
        assert!(c.insert(g).is_none());
        assert_eq!(c.get("N-BK7HTi").unwrap().name, "N-BK7HTI");

        let mut other = GlassCatalog::new();
        let mut g2 = (*c.get("SF10").unwrap()).clone();
        g2.catalog = "OTHER".into();
        other.insert(g2);
        c.merge(other);
        assert_eq!(c.len(), 7);
        assert_eq!(c.get("sf10").unwrap().catalog, "OTHER");
        assert_eq!((&c).into_iter().count(), 7);
    }

    #[test]
    fn medium_lookup() {
        let c = GlassCatalog::builtin();
        assert!(matches!(c.medium("").unwrap(), Medium::Air));
        assert!(matches!(c.medium("air").unwrap(), Medium::Air));
        assert!(matches!(c.medium("n-sk2").unwrap(), Medium::Glass(g) if g.name == "N-SK2"));
        assert!(matches!(
            c.medium("nope"),
            Err(MaterialError::UnknownGlass { .. })
        ));
    }

    #[test]
    fn missing_file_error_names_path() {
        let e = GlassCatalog::from_agf_file("/nonexistent/dir/FOO.AGF").unwrap_err();
        assert!(matches!(e, MaterialError::Io { .. }));
        assert!(e.to_string().contains("/nonexistent/dir/FOO.AGF"), "{e}");
    }

    #[test]
    fn levenshtein_basics() {
        let c = |s: &str| s.chars().collect::<Vec<_>>();
        assert_eq!(levenshtein(&c("NBK7"), &c("N-BK7")), 1);
        assert_eq!(levenshtein(&c(""), &c("ABC")), 3);
        assert_eq!(levenshtein(&c("SF10"), &c("SF10")), 0);
    }
}
