//! Declarative technique parameters: one table per technique of {name, what it does, what
//! higher and lower values do, range or choices, default}. Validation, preset round-trips, the
//! viewer's widgets and the parameter tables of docs/parameters.md all come from that one table, so they
//! cannot disagree.

use anyhow::Result;
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

    /// The stored number `x` as a typed value.
    fn value_of(&self, x: f64) -> ParamValue {
        match self.kind {
            ParamKind::Int { .. } => ParamValue::Int(x as i64),
            ParamKind::Float { .. } => ParamValue::Float(x),
            ParamKind::Bool => ParamValue::Bool(x != 0.0),
            ParamKind::Choice(c) => ParamValue::Choice(c[(x as usize).min(c.len() - 1)]),
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

/// One parameter's value, typed as its spec says. Inside the engine parameters travel as
/// these; TOML (presets, `--set`, the Python API, the viewer's edits) is parsed into them once,
/// at the edge (`Params::parse`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ParamValue {
    Int(i64),
    Float(f64),
    Bool(bool),
    /// A choice by name (one of the spec's choices).
    Choice(&'static str),
}

impl ParamValue {
    /// This value as the number `Params` stores for `spec`, or what a valid value looks like.
    fn number(self, spec: &ParamSpec) -> Result<f64, String> {
        let out = match (spec.kind, self) {
            (ParamKind::Int { min, max }, ParamValue::Int(i)) => {
                Some(i as f64).filter(|_| i >= min && i <= max)
            }
            (ParamKind::Float { min, max }, ParamValue::Float(x)) => {
                Some(x).filter(|x| *x >= min && *x <= max)
            }
            (ParamKind::Float { min, max }, ParamValue::Int(i)) => {
                Some(i as f64).filter(|x| *x >= min && *x <= max)
            }
            (ParamKind::Bool, ParamValue::Bool(b)) => Some(b as u8 as f64),
            (ParamKind::Choice(c), ParamValue::Choice(name)) => {
                c.iter().position(|n| *n == name).map(|i| i as f64)
            }
            _ => None,
        };
        out.ok_or_else(|| spec.expected())
    }
}

impl std::fmt::Display for ParamValue {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ParamValue::Int(i) => write!(f, "{i}"),
            ParamValue::Float(x) => write!(f, "{x}"),
            ParamValue::Bool(b) => write!(f, "{b}"),
            ParamValue::Choice(c) => write!(f, "\"{c}\""),
        }
    }
}

/// Typed parameter changes: what `Technique::set_params` applies, all of them or none. Built
/// in code (`ParamChanges::new().int("ray_budget", n)`, the ray budget's mapping) or parsed
/// from TOML against a technique's table (`Params::parse`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParamChanges(Vec<(&'static str, ParamValue)>);

impl ParamChanges {
    pub fn new() -> ParamChanges {
        ParamChanges::default()
    }
    /// Adds (or replaces) one change.
    pub fn with(mut self, name: &'static str, value: ParamValue) -> ParamChanges {
        self.push(name, value);
        self
    }
    pub fn int(self, name: &'static str, v: i64) -> ParamChanges {
        self.with(name, ParamValue::Int(v))
    }
    pub fn float(self, name: &'static str, v: f64) -> ParamChanges {
        self.with(name, ParamValue::Float(v))
    }
    pub fn bool(self, name: &'static str, v: bool) -> ParamChanges {
        self.with(name, ParamValue::Bool(v))
    }
    pub fn choice(self, name: &'static str, v: &'static str) -> ParamChanges {
        self.with(name, ParamValue::Choice(v))
    }
    /// Adds (or replaces) one change in place.
    pub fn push(&mut self, name: &'static str, value: ParamValue) {
        match self.0.iter_mut().find(|(n, _)| *n == name) {
            Some(c) => c.1 = value,
            None => self.0.push((name, value)),
        }
    }
    /// Every change of `other` after this one's.
    pub fn extend(&mut self, other: &ParamChanges) {
        for &(n, v) in &other.0 {
            self.push(n, v);
        }
    }
    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
    pub fn iter(&self) -> impl Iterator<Item = &(&'static str, ParamValue)> {
        self.0.iter()
    }
    /// The value given for `name`, if any.
    pub fn get(&self, name: &str) -> Option<ParamValue> {
        self.0.iter().find(|(n, _)| *n == name).map(|(_, v)| *v)
    }
}

/// A technique's current parameter values, checked against its table.
#[derive(Clone, Debug)]
pub struct Params {
    technique: &'static str,
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
            technique,
            specs,
            values: specs.iter().map(|s| s.default).collect(),
        }
    }

    pub fn specs(&self) -> &'static [ParamSpec] {
        self.specs
    }

    fn index(&self, name: &str) -> Result<usize> {
        self.specs
            .iter()
            .position(|s| s.name == name)
            .ok_or_else(|| {
                let known: Vec<&str> = self.specs.iter().map(|s| s.name).collect();
                anyhow::anyhow!(
                    "{} has no parameter '{name}' (known: {})",
                    self.technique,
                    known.join(", ")
                )
            })
    }

    /// A TOML table (a preset's, `--set`'s, the Python API's) checked against this table and
    /// typed: the one place parameters are parsed. Nothing is applied.
    pub fn parse(&self, table: &toml::Table) -> Result<ParamChanges> {
        let mut parsed = Vec::new();
        for (k, v) in table {
            let i = self.index(k)?;
            let x = self.specs[i].parse(v).map_err(|want| {
                anyhow::anyhow!("{}: '{k}' must be {want}, got {v}", self.technique)
            })?;
            parsed.push((i, x));
        }
        // In the table's order, as `changes` gives them.
        parsed.sort_by_key(|(i, _)| *i);
        let mut out = ParamChanges::new();
        for (i, x) in parsed {
            out.push(self.specs[i].name, self.specs[i].value_of(x));
        }
        Ok(out)
    }

    /// Applies typed changes: all of them or, on the first bad one, none.
    pub fn apply(&mut self, changes: &ParamChanges) -> Result<()> {
        let mut next = self.values.clone();
        for &(k, v) in changes.iter() {
            let i = self.index(k)?;
            next[i] = v.number(&self.specs[i]).map_err(|want| {
                anyhow::anyhow!("{}: '{k}' must be {want}, got {v}", self.technique)
            })?;
        }
        self.values = next;
        Ok(())
    }

    /// Every value, as changes that would set a technique to these settings (a run's restore
    /// point).
    pub fn changes(&self) -> ParamChanges {
        let mut out = ParamChanges::new();
        for (s, &x) in self.specs.iter().zip(&self.values) {
            out.push(s.name, s.value_of(x));
        }
        out
    }

    /// The values as a preset table (round-trips through `parse`).
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

    /// The chosen name of a choice parameter.
    pub fn choice(&self, name: &str) -> &'static str {
        let spec = self
            .specs
            .iter()
            .find(|s| s.name == name)
            .unwrap_or_else(|| panic!("no parameter '{name}' in the table"));
        match spec.kind {
            ParamKind::Choice(c) => c[(self.value(name) as usize).min(c.len() - 1)],
            _ => panic!("parameter '{name}' is not a choice"),
        }
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
