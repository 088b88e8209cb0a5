use serde::{Deserialize, Serialize};

/// A numeric cell of the Lens Data Editor: its value and what drives it.
///
/// In a file a fixed cell is a bare number (`tilt_y_deg = -30.0`); otherwise a table:
/// `{ value = 30.0, pickup = { surface = 7, scale = 1.0 } }`, `{ solve = "chief_ray" }`,
/// `{ value = 50.0, variable = true }`, `{ value = 30.0, unknown_pickup = true }`.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(into = "CellRepr")]
pub struct Cell {
    /// The value (for pickups and solves: the last resolved value, informative only).
    pub value: f64,
    /// Marked variable ("V"): free for optimisation; otherwise treated as a fixed value.
    pub variable: bool,
    pub driver: Driver,
}

/// What determines a cell's value.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
pub enum Driver {
    #[default]
    Fixed,
    /// value = scale · source + offset, read from `surface` (same column unless `column` is set). ("P")
    Pickup(Pickup),
    /// Coordinate Break decenter/tilt solved so the primary-wavelength chief ray follows the new axis. ("C")
    ChiefRay,
    /// A pickup ("P") whose source the file does not say (a Lens Data Editor transcription,
    /// `spec::zemax_csv`): traced at its shown value, like a fixed cell, but it would not follow its source
    /// when that changes, so no cell of its column (a pickup reads its own column unless it says otherwise)
    /// may be freed for a fit or a design ([`crate::diff::ParamSet`] refuses, naming the cells). Written `{ value = 30.0, unknown_pickup = true }`;
    /// replace it by `{ value = 30.0, pickup = { surface = 7, scale = -1.0 } }` once the source is known.
    UnknownPickup,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Pickup {
    pub surface: usize,
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub scale: f64,
    #[serde(default, skip_serializing_if = "is_zero")]
    pub offset: f64,
    /// Source column name (e.g. "tilt_x_deg"); defaults to the same column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub column: Option<String>,
}

fn one() -> f64 {
    1.0
}
fn is_one(v: &f64) -> bool {
    *v == 1.0
}
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

impl Cell {
    pub fn fixed(value: f64) -> Self {
        Cell { value, variable: false, driver: Driver::Fixed }
    }
    pub fn variable(value: f64) -> Self {
        Cell { value, variable: true, driver: Driver::Fixed }
    }
    pub fn pickup(value: f64, surface: usize, scale: f64) -> Self {
        Cell { value, variable: false, driver: Driver::Pickup(Pickup { surface, scale, offset: 0.0, column: None }) }
    }
    pub fn chief_ray(value: f64) -> Self {
        Cell { value, variable: false, driver: Driver::ChiefRay }
    }
}

impl Default for Cell {
    fn default() -> Self {
        Cell::fixed(0.0)
    }
}

impl From<f64> for Cell {
    fn from(v: f64) -> Self {
        Cell::fixed(v)
    }
}

/// What a cell may be written as, for messages.
const CELL_FORMS: &str = "a number, or a table such as { value = 50.0, variable = true }, { pickup = { surface = 7, scale = 1.0, offset = 0.0 } }, { solve = \"chief_ray\" } or { value = 30.0, unknown_pickup = true }";

/// Deserialized by hand (not `#[serde(untagged)]`) so that a wrong cell says which forms are accepted and,
/// inside a table, which key is wrong — instead of serde's "did not match any variant of untagged enum".
impl<'de> Deserialize<'de> for Cell {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct V;
        impl<'de> serde::de::Visitor<'de> for V {
            type Value = Cell;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str(CELL_FORMS)
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> Result<Cell, E> {
                Ok(Cell::fixed(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> Result<Cell, E> {
                Ok(Cell::fixed(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> Result<Cell, E> {
                Ok(Cell::fixed(v as f64))
            }
            /// An infinite distance (the object at infinity) is written `"infinity"`: JSON has no number for
            /// it (serde_json would write `null`); TOML's own `inf` is read too (through `visit_f64`).
            fn visit_str<E: serde::de::Error>(self, v: &str) -> Result<Cell, E> {
                let t = v.trim().trim_start_matches('+');
                if t.eq_ignore_ascii_case("infinity") || t.eq_ignore_ascii_case("inf") {
                    Ok(Cell::fixed(f64::INFINITY))
                } else {
                    Err(E::custom(format!("`{v}` is not a number; a cell is {CELL_FORMS}, or \"infinity\" (the object at infinity)")))
                }
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(self, map: A) -> Result<Cell, A::Error> {
                let t = CellTable::deserialize(serde::de::value::MapAccessDeserializer::new(map))?;
                // One driver per cell: `pickup`, `solve` and `unknown_pickup` exclude one another.
                let drivers = [t.pickup.is_some().then_some("pickup"), t.solve.is_some().then_some("solve"), t.unknown_pickup.then_some("unknown_pickup = true")];
                let given: Vec<&str> = drivers.into_iter().flatten().collect();
                if given.len() > 1 {
                    return Err(serde::de::Error::custom(format!("a cell has one driver, not {}", given.join(" and "))));
                }
                Ok(Cell::from(CellRepr::Table(t)))
            }
        }
        d.deserialize_any(V)
    }
}

#[derive(Serialize)]
#[serde(untagged)]
enum CellRepr {
    Value(f64),
    /// `"infinity"`: a fixed +∞ (an object at infinity), which JSON cannot hold as a number.
    Infinity(&'static str),
    Table(CellTable),
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct CellTable {
    #[serde(default)]
    value: f64,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    variable: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pickup: Option<Pickup>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    solve: Option<SolveName>,
    /// A pickup of unknown source ([`Driver::UnknownPickup`]).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    unknown_pickup: bool,
}

#[derive(Serialize, Deserialize, Clone, Copy)]
#[serde(rename_all = "snake_case")]
enum SolveName {
    ChiefRay,
}

impl From<CellRepr> for Cell {
    fn from(r: CellRepr) -> Self {
        match r {
            CellRepr::Value(v) => Cell::fixed(v),
            CellRepr::Infinity(_) => Cell::fixed(f64::INFINITY),
            CellRepr::Table(t) => {
                let driver = match (t.pickup, t.solve) {
                    (Some(p), _) => Driver::Pickup(p),
                    (None, Some(SolveName::ChiefRay)) => Driver::ChiefRay,
                    (None, None) if t.unknown_pickup => Driver::UnknownPickup,
                    (None, None) => Driver::Fixed,
                };
                Cell { value: t.value, variable: t.variable, driver }
            }
        }
    }
}

impl From<Cell> for CellRepr {
    fn from(c: Cell) -> Self {
        match c.driver {
            Driver::Fixed if !c.variable && c.value == f64::INFINITY => CellRepr::Infinity("infinity"),
            Driver::Fixed if !c.variable => CellRepr::Value(c.value),
            Driver::Fixed => CellRepr::Table(CellTable { value: c.value, variable: true, pickup: None, solve: None, unknown_pickup: false }),
            Driver::Pickup(p) => CellRepr::Table(CellTable { value: c.value, variable: c.variable, pickup: Some(p), solve: None, unknown_pickup: false }),
            Driver::ChiefRay => {
                CellRepr::Table(CellTable { value: c.value, variable: c.variable, pickup: None, solve: Some(SolveName::ChiefRay), unknown_pickup: false })
            }
            Driver::UnknownPickup => CellRepr::Table(CellTable { value: c.value, variable: c.variable, pickup: None, solve: None, unknown_pickup: true }),
        }
    }
}
