//! Declarative technique parameters: one table per technique of {name, what it does, what
//! higher and lower values do, range or choices, default}. Validation, preset round-trips, the
//! viewer's widgets and the parameter tables of docs/parameters.md all come from that one table, so they
//! cannot disagree.

use anyhow::{bail, Result};
use serde::Serialize;

/// The type and range of a parameter.
#[derive(Clone, Copy, Debug, Serialize)]
pub enum ParamKind {
    /// An integer in min..=max.
    Int { min: i64, max: i64 },
    /// A number in min..=max.
    Float { min: f64, max: f64 },
    /// A switch; presets may also write 0 or 1.
    Bool,
    /// One of several named settings, stored as its index; presets may write the name or the
    /// index (and `true`/`false` for the second and first, where a switch once stood).
    Choice(&'static [&'static str]),
}

/// Parameter tables as one: a technique's own and its parts' (`param_table![OWN, PART, ..]`,
/// each an array or slice of `ParamSpec`). The length is counted at compile time, so adding a
/// parameter to any table changes no number elsewhere.
#[macro_export]
macro_rules! param_table {
    ($($t:expr),+ $(,)?) => {{
        const N: usize = 0 $(+ $t.len())+;
        const TABLE: [$crate::render::params::ParamSpec; N] =
            $crate::render::params::concat_tables::<N>(&[$(&$t),+]);
        &TABLE
    }};
}

/// The tables one after another (`param_table!`); `N` is their summed length.
pub const fn concat_tables<const N: usize>(tables: &[&[ParamSpec]]) -> [ParamSpec; N] {
    assert!(
        !tables.is_empty() && !tables[0].is_empty(),
        "the first table is not empty"
    );
    let mut out = [tables[0][0]; N];
    let (mut t, mut i) = (0, 0);
    while t < tables.len() {
        let mut k = 0;
        while k < tables[t].len() {
            out[i] = tables[t][k];
            i += 1;
            k += 1;
        }
        t += 1;
    }
    assert!(i == N, "N is the summed length of the tables");
    out
}

/// One parameter of a technique.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct ParamSpec {
    pub name: &'static str,
    pub what: &'static str,
    pub higher: &'static str,
    pub lower: &'static str,
    pub kind: ParamKind,
    /// The default, as a number (switches and choices: 0 or 1 / the choice's index).
    pub default: f64,
}

impl ParamSpec {
    /// Slider range of the viewer.
    pub fn range(&self) -> (f64, f64) {
        match self.kind {
            ParamKind::Int { min, max } => (min as f64, max as f64),
            ParamKind::Float { min, max } => (min, max),
            ParamKind::Bool => (0.0, 1.0),
            ParamKind::Choice(c) => (0.0, (c.len() - 1) as f64),
        }
    }

    pub fn is_integer(&self) -> bool {
        !matches!(self.kind, ParamKind::Float { .. })
    }

    /// The value `v` as a number in this parameter's range, or why not.
    fn parse(&self, v: &toml::Value) -> Result<f64, String> {
        let num = v.as_float().or(v.as_integer().map(|i| i as f64));
        let out = match (self.kind, v) {
            (ParamKind::Bool, toml::Value::Boolean(b)) => Some(*b as u8 as f64),
            (ParamKind::Bool, _) => num.filter(|n| *n == 0.0 || *n == 1.0),
            (ParamKind::Choice(c), toml::Value::String(s)) => {
                c.iter().position(|n| n == s).map(|i| i as f64)
            }
            (ParamKind::Choice(_), toml::Value::Boolean(b)) => Some(*b as u8 as f64),
            (ParamKind::Choice(c), _) => {
                num.filter(|n| n.fract() == 0.0 && *n >= 0.0 && (*n as usize) < c.len())
            }
            (ParamKind::Int { min, max }, _) => {
                num.filter(|n| n.fract() == 0.0 && *n >= min as f64 && *n <= max as f64)
            }
            (ParamKind::Float { min, max }, _) => num.filter(|n| *n >= min && *n <= max),
        };
        out.ok_or_else(|| self.expected())
    }

    /// What a valid value looks like, for error messages.
    pub fn expected(&self) -> String {
        match self.kind {
            ParamKind::Int { min, max } => format!("an integer in {min}..={max}"),
            ParamKind::Float { min, max } => format!("a number in {min}..={max}"),
            ParamKind::Bool => "true or false".into(),
            ParamKind::Choice(c) => format!(
                "one of {} (or its index 0..={})",
                c.iter()
                    .map(|n| format!("\"{n}\""))
                    .collect::<Vec<_>>()
                    .join(", "),
                c.len() - 1
            ),
        }
    }

    fn to_toml(self, x: f64) -> toml::Value {
        match self.kind {
            ParamKind::Int { .. } | ParamKind::Choice(_) => toml::Value::Integer(x as i64),
            ParamKind::Float { .. } => toml::Value::Float(x),
            ParamKind::Bool => toml::Value::Boolean(x != 0.0),
        }
    }
}

/// A technique's current parameter values, checked against its table.
#[derive(Clone, Debug)]
pub struct Params {
    specs: &'static [ParamSpec],
    values: Vec<f64>,
}

impl Params {
    /// Every parameter at its default.
    pub fn new(technique: &'static str, specs: &'static [ParamSpec]) -> Params {
        for s in specs {
            debug_assert!(
                s.parse(&s.to_toml(s.default)).is_ok(),
                "{technique}: default of '{}' outside its range",
                s.name
            );
        }
        Params {
            specs,
            values: specs.iter().map(|s| s.default).collect(),
        }
    }

    pub fn specs(&self) -> &'static [ParamSpec] {
        self.specs
    }

    /// Applies a table of new values: all of them or, on the first bad one, none.
    pub fn set(&mut self, technique: &str, table: &toml::Table) -> Result<()> {
        let mut next = self.values.clone();
        for (k, v) in table {
            let Some(i) = self.specs.iter().position(|s| s.name == k) else {
                let known: Vec<&str> = self.specs.iter().map(|s| s.name).collect();
                bail!(
                    "{technique} has no parameter '{k}' (known: {})",
                    known.join(", ")
                );
            };
            let spec = &self.specs[i];
            next[i] = spec
                .parse(v)
                .map_err(|want| anyhow::anyhow!("{technique}: '{k}' must be {want}, got {v}"))?;
        }
        self.values = next;
        Ok(())
    }

    /// The values as a preset table (round-trips through `set`).
    pub fn table(&self) -> toml::Table {
        self.specs
            .iter()
            .zip(&self.values)
            .map(|(s, &x)| (s.name.to_string(), s.to_toml(x)))
            .collect()
    }

    fn value(&self, name: &str) -> f64 {
        let i = self
            .specs
            .iter()
            .position(|s| s.name == name)
            .unwrap_or_else(|| panic!("no parameter '{name}' in the table"));
        self.values[i]
    }

    pub fn u32(&self, name: &str) -> u32 {
        self.value(name) as u32
    }

    pub fn f32(&self, name: &str) -> f32 {
        self.value(name) as f32
    }

    pub fn bool(&self, name: &str) -> bool {
        self.value(name) != 0.0
    }
}

/// The parameter table of one technique (docs/parameters.md) (Markdown), generated from its specs.
pub fn markdown_table(specs: &[ParamSpec]) -> String {
    let mut out = String::from(
        "| parameter | what it does | higher | lower | range | default |\n| --- | --- | --- | --- | --- | --- |\n",
    );
    for s in specs {
        let (range, default) = match s.kind {
            ParamKind::Int { min, max } => (format!("{min}–{max}"), format!("{}", s.default)),
            ParamKind::Float { min, max } => (format!("{min}–{max}"), format!("{}", s.default)),
            ParamKind::Bool => ("on / off".into(), (s.default != 0.0).to_string()),
            ParamKind::Choice(c) => (c.join(" / "), c[s.default as usize].to_string()),
        };
        out += &format!(
            "| `{}` | {} | {} | {} | {} | {} |\n",
            s.name, s.what, s.higher, s.lower, range, default
        );
    }
    out
}
