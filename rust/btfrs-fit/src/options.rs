//! The option schema of a model's fit: every option's name, type, default, allowed values and
//! one-line doc, written once in the model's file ([`crate::Model::OPTIONS`]).
//!
//! Everything else reads it: [`build`] checks options given as [`Values`] (what the bindings make
//! of a Python dict: the Python functions, the CLI's `--set`, Dask) and fills the defaults before
//! serde builds the model's `Options` struct,
//! so the struct's fields, the defaults and the checks cannot drift apart (the registry test
//! `every_schema_builds_its_options` fails if a field is missing from either side);
//! `btfrs.fit.<kind>`'s signature and docstring, `_native.pyi`, the CLI's model list and the docs'
//! option tables are generated from [`schema_json`].

use btfrs_core::{Error, Result};
use serde::de::DeserializeOwned;
use serde_json::{Map, Value};

/// Options as given, by name: what the bindings convert a Python dict of options to (each value
/// converted once; no text in between), and what the registry's own facts (a model's examples,
/// written as JSON objects in its file) are read as ([`parse_json`]).
pub type Values = Map<String, Value>;

/// Options written as a JSON object: the registry's facts (`Model::EXAMPLES`, `Setting`s,
/// `Blockwise::Texels` overrides) and the tests.
pub fn parse_json(json: &str) -> Result<Values> {
    let v: Value = serde_json::from_str(json).map_err(|e| Error::arg("options", format!("not valid JSON: {e}")))?;
    match v {
        Value::Object(map) => Ok(map),
        _ => Err(Error::arg("options", "expected a JSON object of option names")),
    }
}

/// The type, default and allowed values of one option.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Kind {
    /// An integer in `min ..= max` (`max` `None`: no upper bound; seeds are `u64`).
    Int {
        /// The default.
        default: i64,
        /// The least allowed value.
        min: i64,
        /// The largest allowed value.
        max: Option<i64>,
    },
    /// One of a few integers.
    IntChoice {
        /// The default.
        default: i64,
        /// The allowed values.
        choices: &'static [i64],
    },
    /// An integer in `min ..= max`, or `null`, the default, meaning "derived" (the doc says how).
    OptInt {
        /// The least allowed value.
        min: i64,
        /// The largest allowed value.
        max: Option<i64>,
    },
    /// A real number above `min` (`min_open`) or at least `min`.
    Float {
        /// The default.
        default: f64,
        /// The bound below.
        min: f64,
        /// Whether `min` itself is excluded.
        min_open: bool,
    },
    /// `true` or `false`.
    Bool {
        /// The default.
        default: bool,
    },
    /// One of a few strings.
    Choice {
        /// The default.
        default: &'static str,
        /// The allowed strings.
        choices: &'static [&'static str],
    },
}

/// One option of a fit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spec {
    /// Its name (a JSON key, a Python keyword argument; a Python keyword gets a `_` appended).
    pub name: &'static str,
    /// Type, default and allowed values.
    pub kind: Kind,
    /// One line saying what it does.
    pub doc: &'static str,
}

impl Spec {
    /// An integer option.
    pub const fn int(name: &'static str, default: i64, min: i64, max: Option<i64>, doc: &'static str) -> Spec {
        Spec { name, kind: Kind::Int { default, min, max }, doc }
    }
    /// An integer option taking one of `choices`.
    pub const fn int_choice(name: &'static str, default: i64, choices: &'static [i64], doc: &'static str) -> Spec {
        Spec { name, kind: Kind::IntChoice { default, choices }, doc }
    }
    /// An optional integer option (default `null`).
    pub const fn opt_int(name: &'static str, min: i64, max: Option<i64>, doc: &'static str) -> Spec {
        Spec { name, kind: Kind::OptInt { min, max }, doc }
    }
    /// A real option at least `min`.
    pub const fn float(name: &'static str, default: f64, min: f64, doc: &'static str) -> Spec {
        Spec { name, kind: Kind::Float { default, min, min_open: false }, doc }
    }
    /// A real option above `min`.
    pub const fn positive(name: &'static str, default: f64, doc: &'static str) -> Spec {
        Spec { name, kind: Kind::Float { default, min: 0.0, min_open: true }, doc }
    }
    /// A boolean option.
    pub const fn bool(name: &'static str, default: bool, doc: &'static str) -> Spec {
        Spec { name, kind: Kind::Bool { default }, doc }
    }
    /// A choice among strings.
    pub const fn choice(
        name: &'static str,
        default: &'static str,
        choices: &'static [&'static str],
        doc: &'static str,
    ) -> Spec {
        Spec { name, kind: Kind::Choice { default, choices }, doc }
    }
    /// The seed of a fit's random choices (any `u64`, default 0).
    pub const fn seed(doc: &'static str) -> Spec {
        Spec::int("seed", 0, 0, None, doc)
    }

    /// The default as JSON.
    pub fn default_value(&self) -> Value {
        match self.kind {
            Kind::Int { default, .. } | Kind::IntChoice { default, .. } => default.into(),
            Kind::OptInt { .. } => Value::Null,
            Kind::Float { default, .. } => default.into(),
            Kind::Bool { default } => default.into(),
            Kind::Choice { default, .. } => default.into(),
        }
    }

    /// What the option allows, in words ("an integer from 1 to 7", `"rgb" or "lrgb"`).
    pub fn allowed(&self) -> String {
        let range = |min: i64, max: Option<i64>| match max {
            Some(max) => format!("an integer from {min} to {max}"),
            None if min == 0 => "a non-negative integer".to_string(),
            None => format!("an integer >= {min}"),
        };
        let list = |q: Vec<String>| match q.len() {
            1 => q[0].clone(),
            n => format!("{} or {}", q[..n - 1].join(", "), q[n - 1]),
        };
        match self.kind {
            Kind::Int { min, max, .. } => range(min, max),
            Kind::IntChoice { choices, .. } => list(choices.iter().map(|c| c.to_string()).collect()),
            Kind::OptInt { min, max } => format!("null or {}", range(min, max)),
            Kind::Float { min, min_open: true, .. } => format!("a number > {min}"),
            Kind::Float { min, .. } => format!("a number >= {min}"),
            Kind::Bool { .. } => "true or false".to_string(),
            Kind::Choice { choices, .. } => list(choices.iter().map(|c| format!("{c:?}")).collect()),
        }
    }

    /// Check one value; the error names the option, the value and what is allowed.
    pub fn check(&self, v: &Value) -> Result<()> {
        // The JSON type first: a value of another type is a type error (a float for an integer).
        let typed = match (self.kind, v) {
            (Kind::OptInt { .. }, Value::Null) => true,
            (Kind::Int { .. } | Kind::OptInt { .. } | Kind::IntChoice { .. }, Value::Number(n)) => {
                n.as_i64().is_some() || n.as_u64().is_some()
            }
            (Kind::Float { .. }, Value::Number(_)) => true,
            (Kind::Bool { .. }, Value::Bool(_)) => true,
            (Kind::Choice { .. }, Value::String(_)) => true,
            _ => false,
        };
        if !typed {
            return Err(Error::value(self.name, v.clone(), self.allowed(), true));
        }
        let ok = match (self.kind, v) {
            (Kind::OptInt { .. }, Value::Null) => true,
            (Kind::Int { min, max, .. } | Kind::OptInt { min, max }, Value::Number(n)) => {
                if let Some(i) = n.as_i64() {
                    i >= min && max.is_none_or(|m| i <= m)
                } else {
                    // Above i64::MAX (a u64 seed): allowed where there is no upper bound.
                    n.as_u64().is_some() && max.is_none()
                }
            }
            (Kind::IntChoice { choices, .. }, Value::Number(n)) => n.as_i64().is_some_and(|i| choices.contains(&i)),
            (Kind::Float { min, min_open, .. }, Value::Number(n)) => {
                let x = n.as_f64().unwrap_or(f64::NAN);
                x.is_finite() && if min_open { x > min } else { x >= min }
            }
            (Kind::Bool { .. }, Value::Bool(_)) => true,
            (Kind::Choice { choices, .. }, Value::String(s)) => choices.contains(&s.as_str()),
            _ => false,
        };
        if ok {
            Ok(())
        } else {
            Err(Error::value(self.name, v.clone(), self.allowed(), false))
        }
    }
}

/// Check options against `schema` (unknown names, types, ranges, choices: each error names the
/// option, the value and what is allowed), fill the defaults and build the model's options
/// struct.
pub fn build<O: DeserializeOwned>(schema: &[Spec], mut map: Values) -> Result<O> {
    check(schema, &map)?;
    for s in schema {
        map.entry(s.name).or_insert_with(|| s.default_value());
    }
    // The schema has checked every value: a failure here is a schema that does not describe its
    // struct (caught by the registry tests), reported as such rather than as the user's error.
    serde_json::from_value(Value::Object(map)).map_err(|e| {
        Error::arg("options", format!("internal: the option schema does not match its options struct: {e}"))
    })
}

/// Check options against `schema` without building them (the CLI checks `--set` before any
/// work): unknown names, types, ranges, choices.
pub fn check(schema: &[Spec], map: &Values) -> Result<()> {
    for (k, v) in map {
        match schema.iter().find(|s| s.name == k) {
            Some(s) => s.check(v)?,
            None => {
                let names: Vec<&str> = schema.iter().map(|s| s.name).collect();
                let expected = if names.is_empty() {
                    "this model takes no options".to_string()
                } else {
                    format!("expected one of {}", names.join(", "))
                };
                let allowed = if names.is_empty() { "no option".to_string() } else { names.join(", ") };
                return Err(Error::InvalidArgument {
                    name: k.clone(),
                    msg: format!("unknown option; {expected}"),
                    detail: Some(Box::new(btfrs_core::Detail { value: v.clone(), allowed })),
                });
            }
        }
    }
    Ok(())
}

/// The defaults of `schema` as the options struct (what `Options::default()` returns: the
/// schema is the one place a default is written).
pub fn defaults<O: DeserializeOwned>(schema: &[Spec]) -> O {
    // Checked for every registered model by `every_schema_builds_its_options`.
    build(schema, Map::new()).expect("an option schema's defaults build its options struct")
}

/// The schema as JSON: `[{name, type, default, min, max, min_open, choices, doc}]`.
pub fn schema_json(schema: &[Spec]) -> Value {
    let items = schema
        .iter()
        .map(|s| {
            let mut o = Map::new();
            o.insert("name".into(), s.name.into());
            o.insert("default".into(), s.default_value());
            o.insert("doc".into(), s.doc.into());
            o.insert("allowed".into(), s.allowed().into());
            let ty = match s.kind {
                Kind::Int { min, max, .. } | Kind::OptInt { min, max } => {
                    o.insert("min".into(), min.into());
                    o.insert("max".into(), max.map_or(Value::Null, Value::from));
                    if matches!(s.kind, Kind::OptInt { .. }) {
                        "optional_int"
                    } else {
                        "int"
                    }
                }
                Kind::Float { min, min_open, .. } => {
                    o.insert("min".into(), min.into());
                    o.insert("min_open".into(), min_open.into());
                    "float"
                }
                Kind::IntChoice { choices, .. } => {
                    o.insert("choices".into(), choices.iter().map(|&c| Value::from(c)).collect());
                    "int_choice"
                }
                Kind::Bool { .. } => "bool",
                Kind::Choice { choices, .. } => {
                    o.insert("choices".into(), choices.iter().map(|&c| Value::from(c)).collect());
                    "choice"
                }
            };
            o.insert("type".into(), ty.into());
            Value::Object(o)
        })
        .collect();
    Value::Array(items)
}

/// Options of something that is not a model (a tile set's synthesis, ...) read by serde,
/// naming the option at fault; models declare a schema instead ([`build`]).
pub fn from_serde<O: DeserializeOwned + Default>(map: &Values) -> Result<O> {
    match serde_json::from_value::<O>(Value::Object(map.clone())) {
        Ok(o) => Ok(o),
        Err(whole) => {
            // serde names an unknown field but not the field of a type error: try each option
            // alone (the others defaulted) to find the culprit.
            for (k, x) in map {
                let one = serde_json::Value::Object([(k.clone(), x.clone())].into_iter().collect());
                if let Err(e) = serde_json::from_value::<O>(one) {
                    let msg = e.to_string();
                    let msg = msg.split(" at line ").next().unwrap_or(&msg).to_string();
                    return Err(Error::arg(k, format!("{msg} (got {x})")));
                }
            }
            Err(Error::arg("options", whole.to_string()))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, serde::Deserialize, PartialEq)]
    #[serde(deny_unknown_fields)]
    struct O {
        n: usize,
        x: f64,
        c: String,
        k: Option<usize>,
        b: bool,
        seed: u64,
    }

    const S: &[Spec] = &[
        Spec::int("n", 2, 1, Some(7), "n"),
        Spec::positive("x", 0.5, "x"),
        Spec::choice("c", "rgb", &["rgb", "lrgb", "ycc"], "c"),
        Spec::opt_int("k", 0, Some(64), "k"),
        Spec::bool("b", true, "b"),
        Spec::seed("seed"),
    ];

    #[test]
    fn defaults_fill_and_values_are_checked_against_the_schema() {
        let d: O = defaults(S);
        assert_eq!(d, O { n: 2, x: 0.5, c: "rgb".into(), k: None, b: true, seed: 0 });
        let parse = |j: &str| parse_json(j).and_then(|m| build::<O>(S, m));
        let o: O = parse(r#"{"n": 7, "k": 3, "seed": 18446744073709551615}"#).unwrap();
        assert_eq!((o.n, o.k, o.seed), (7, Some(3), u64::MAX));
        let err = |j: &str| parse(j).unwrap_err().to_string();
        assert_eq!(err(r#"{"n": 8}"#), "n: expected an integer from 1 to 7, got 8");
        assert_eq!(err(r#"{"n": 2.5}"#), "n: expected an integer from 1 to 7, got 2.5");
        assert_eq!(err(r#"{"n": true}"#), "n: expected an integer from 1 to 7, got true");
        assert_eq!(err(r#"{"x": 0}"#), "x: expected a number > 0, got 0");
        assert_eq!(err(r#"{"c": "xyz"}"#), "c: expected \"rgb\", \"lrgb\" or \"ycc\", got \"xyz\"");
        assert_eq!(err(r#"{"k": -1}"#), "k: expected null or an integer from 0 to 64, got -1");
        assert_eq!(err(r#"{"b": 1}"#), "b: expected true or false, got 1");
        assert_eq!(err(r#"{"seed": -1}"#), "seed: expected a non-negative integer, got -1");
        assert_eq!(err(r#"{"nn": 1}"#), "nn: unknown option; expected one of n, x, c, k, b, seed");
        assert_eq!(err("[1]"), "options: expected a JSON object of option names");
        assert!(err("{").starts_with("options: not valid JSON"));
        assert_eq!(
            build::<O>(&[], parse_json(r#"{"a": 1}"#).unwrap()).unwrap_err().to_string(),
            "a: unknown option; this model takes no options"
        );
    }

    #[test]
    fn errors_carry_the_option_the_value_and_what_is_allowed() {
        // The fields the bindings set on the Python exception, apart from the message.
        let fields = |j: &str| {
            let e = parse_json(j).and_then(|m| build::<O>(S, m)).unwrap_err();
            let wrong_type = matches!(e, Error::ArgumentType { .. });
            let (name, d) = e.argument().unwrap();
            let d = d.unwrap();
            (name.to_string(), d.value.clone(), d.allowed.clone(), wrong_type)
        };
        assert_eq!(fields(r#"{"n": 8}"#), ("n".into(), serde_json::json!(8), "an integer from 1 to 7".into(), false));
        assert_eq!(
            fields(r#"{"n": 2.5}"#),
            ("n".into(), serde_json::json!(2.5), "an integer from 1 to 7".into(), true)
        );
        assert_eq!(fields(r#"{"c": "xyz"}"#).2, "\"rgb\", \"lrgb\" or \"ycc\"");
        assert_eq!(fields(r#"{"nn": 1}"#), ("nn".into(), serde_json::json!(1), "n, x, c, k, b, seed".into(), false));
    }

    #[test]
    fn the_schema_as_json_names_every_fact() {
        let j = schema_json(S);
        assert_eq!(j[0]["type"], "int");
        assert_eq!(j[0]["max"], 7);
        assert_eq!(j[2]["choices"], serde_json::json!(["rgb", "lrgb", "ycc"]));
        assert_eq!(j[3]["default"], Value::Null);
        assert_eq!(j[1]["min_open"], true);
        assert_eq!(j[5]["max"], Value::Null);
    }
}
