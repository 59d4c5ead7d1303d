//! The one reader of settings that every front end goes through: a *patch*, a JSON object, is
//! laid over the current settings field by field (nested objects too: a patch that names one
//! field of `flow` keeps the others) and the result is read back through the serde configs
//! ([`NisConfig`], [`VegasConfig`], [`PlainMcConfig`], the flow's [`crate::flow::FlowConfig`],
//! Adam's [`crate::nn::AdamConfig`]), so their fields are the schema and their `Default`s the
//! only defaults. The C ABI's JSON config and the CLI's `--nis-config` are patches
//! ([`Settings::patched`], [`NisConfig::patched`]); Python's keywords and the CLI's named flags
//! are keywords ([`Settings::with_keywords`]), each a field of the chosen method's section or a
//! shorthand of [`KEYWORDS`]. An unknown or ill-typed setting is an [`Error::Config`] that names
//! its path.

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};

use super::nis::NisConfig;
use super::uniform::PlainMcConfig;
use super::vegas::VegasConfig;
use super::{Method, Settings, TrainOn};
use crate::error::{Error, Result};

/// A keyword whose place in the schema is not `<method>.<keyword>`: its path from the top of a
/// [`Settings`] patch, and the shorthand values it takes besides the schema's own.
#[derive(Clone, Copy, Debug)]
pub struct Keyword {
    /// The keyword (Python's, the CLI's flag without `--`).
    pub name: &'static str,
    /// Where it lands, e.g. `["nis", "flow", "couplings"]` (`["seed"]`: every method's seed).
    pub path: &'static [&'static str],
    /// Shorthand values and the schema's values they stand for.
    pub values: &'static [(&'static str, &'static str)],
}

/// The shorthand keywords. Every other keyword is a field of the chosen method's section of
/// [`Settings`] under its own name (`batch`, `increments`, `iterations`, ...); besides these,
/// `stratify` takes a bool (true: stratified with the defaults, false: i.i.d., `null`) and
/// `train_on` a component index.
pub const KEYWORDS: &[Keyword] = &[
    Keyword {
        name: "seed",
        path: &["seed"],
        values: &[],
    },
    Keyword {
        name: "coupling",
        path: &["nis", "flow", "transform", "kind"],
        values: &[
            ("pq", "quadratic"),
            ("pl", "linear"),
            ("rq", "rational_quadratic"),
        ],
    },
    Keyword {
        name: "bins",
        path: &["nis", "flow", "transform", "bins"],
        values: &[],
    },
    Keyword {
        name: "layers",
        path: &["nis", "flow", "couplings"],
        values: &[],
    },
    Keyword {
        name: "masks",
        path: &["nis", "flow", "masks"],
        values: &[],
    },
    Keyword {
        name: "hidden_layers",
        path: &["nis", "flow", "hidden_layers"],
        values: &[],
    },
    Keyword {
        name: "hidden_width",
        path: &["nis", "flow", "hidden_width"],
        values: &[],
    },
    Keyword {
        name: "blob_bins",
        path: &["nis", "flow", "blob_bins"],
        values: &[],
    },
    Keyword {
        name: "learning_rate",
        path: &["nis", "adam", "learning_rate"],
        values: &[],
    },
    Keyword {
        name: "loss",
        path: &["nis", "loss"],
        values: &[("chi2", "chi_square")],
    },
];

/// What a [`Settings`] patch may name at its top: each method's section, and `seed` and
/// `train_on`, which set every method's (after the sections).
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Patchable {
    seed: Option<u64>,
    train_on: Option<TrainOn>,
    nis: NisConfig,
    vegas: VegasConfig,
    uniform: PlainMcConfig,
}

impl Settings {
    /// These settings with the JSON object `patch` laid over them: `{"seed": 1, "nis":
    /// {"batch": 512, "flow": {"hidden_width": 64}}, "vegas": {...}, "uniform": {...},
    /// "train_on": "sum_abs"}`, any part left out. A field it names replaces the current one;
    /// an object it gives for an object changes the fields it names. `seed` and `train_on` set
    /// every method's after the sections. The result is checked ([`Settings::validate`]).
    ///
    /// ```
    /// use nis::integrate::Settings;
    /// let s = Settings::default()
    ///     .patched(serde_json::json!({"seed": 3, "nis": {"flow": {"hidden_width": 64}}}))?;
    /// assert_eq!((s.nis.flow.hidden_width, s.nis.flow.blob_bins, s.vegas.seed), (64, 8, 3));
    /// let e = Settings::default().patched(serde_json::json!({"nis": {"bach": 9}})).unwrap_err();
    /// assert!(e.to_string().contains("nis.bach"));
    /// # Ok::<(), nis::Error>(())
    /// ```
    pub fn patched(&self, patch: Value) -> Result<Settings> {
        let current = Patchable {
            seed: None,
            train_on: None,
            nis: self.nis.clone(),
            vegas: self.vegas.clone(),
            uniform: self.uniform.clone(),
        };
        let p = overlaid(&current, patch)?;
        let mut s = Settings {
            nis: p.nis,
            vegas: p.vegas,
            uniform: p.uniform,
        };
        if let Some(seed) = p.seed {
            s = s.seed(seed);
        }
        if let Some(t) = p.train_on {
            s = s.train_on(t);
        }
        s.validate()?;
        Ok(s)
    }

    /// These settings with `keywords` given for `method`, as Python's `nis.Integrator(...)` and
    /// the CLI's named flags give them: each keyword is a field of `method`'s section or one of
    /// [`KEYWORDS`]. A keyword of another method, or of none, is an error naming it; so is a
    /// value the schema refuses. The keywords become one patch ([`Settings::patched`]).
    ///
    /// ```
    /// use nis::integrate::{Method, Settings};
    /// use serde_json::json;
    /// let s = Settings::default().with_keywords(
    ///     Method::Nis,
    ///     [("coupling", json!("rq")), ("bins", json!(8)), ("batch", json!(512))],
    /// )?;
    /// assert_eq!(s.nis.flow.transform, nis::TransformKind::RationalQuadratic { bins: 8 });
    /// let e = Settings::default().with_keywords(Method::Vegas, [("batch", json!(512))]);
    /// assert!(e.unwrap_err().to_string().contains("batch"));
    /// # Ok::<(), nis::Error>(())
    /// ```
    pub fn with_keywords<'a>(
        &self,
        method: Method,
        keywords: impl IntoIterator<Item = (&'a str, Value)>,
    ) -> Result<Settings> {
        let mut placed = Vec::new();
        for (name, value) in keywords {
            let (path, value) = keyword_path(method, name, value)?;
            placed.push((name, path, value));
        }
        // A layout named by the keyword is kept: no run to a target switches it.
        let named = |n: &str| placed.iter().any(|(name, _, _)| *name == n);
        if named("masks") && !named("auto_masks") {
            let path = vec!["nis".to_string(), "auto_masks".to_string()];
            placed.push(("masks", path, Value::Bool(false)));
        }
        let patch_of = |placed: &[(&str, Vec<String>, Value)]| {
            let mut patch = Value::Object(Map::new());
            for (_, path, value) in placed {
                set_at(&mut patch, path, value.clone());
            }
            patch
        };
        self.patched(patch_of(&placed)).map_err(|e| {
            // Name the keyword whose value the reader refused, where one alone is refused.
            placed
                .iter()
                .find_map(|(name, path, value)| {
                    self.patched(patch_of(&[(*name, path.clone(), value.clone())]))
                        .err()
                        .map(|e| Error::Config(format!("{name}={value}: {}", message(&e))))
                })
                .unwrap_or(e)
        })
    }

    /// Checks every method's settings (as building its integrator does, less what depends on
    /// the dimension).
    pub fn validate(&self) -> Result<()> {
        self.nis.validate()?;
        self.nis.adam.validate()?;
        self.nis.flow.transform.validate()?;
        self.vegas.validate()?;
        self.uniform.validate()
    }
}

/// The keywords [`Settings::with_keywords`] takes for any method: [`KEYWORDS`] and the fields of
/// every method's section, sorted (the list the Python stub is checked against).
pub fn keyword_names() -> Vec<String> {
    let mut names: Vec<String> = KEYWORDS.iter().map(|k| k.name.to_string()).collect();
    for m in Method::ALL {
        names.extend(section_fields(m));
    }
    names.sort();
    names.dedup();
    names
}

/// The field names of `method`'s section.
fn section_fields(method: Method) -> Vec<String> {
    let section = match method {
        Method::Nis => serde_json::to_value(NisConfig::default()),
        Method::Vegas => serde_json::to_value(VegasConfig::default()),
        Method::Uniform => serde_json::to_value(PlainMcConfig::default()),
    };
    match section {
        Ok(Value::Object(fields)) => fields.keys().cloned().collect(),
        _ => Vec::new(),
    }
}

/// Where keyword `name` lands for `method`, with its shorthand value replaced.
fn keyword_path(method: Method, name: &str, value: Value) -> Result<(Vec<String>, Value)> {
    let refuse = |owner: &str| {
        Error::Config(format!(
            "method={:?} does not take {name} (a {owner} setting)",
            method.name()
        ))
    };
    if let Some(k) = KEYWORDS.iter().find(|k| k.name == name) {
        if k.path.len() > 1 && k.path[0] != method.name() {
            return Err(refuse(k.path[0]));
        }
        let value = match value
            .as_str()
            .and_then(|s| k.values.iter().find(|v| v.0 == s))
        {
            Some(&(_, schema)) => Value::from(schema),
            None => value,
        };
        return Ok((k.path.iter().map(|s| s.to_string()).collect(), value));
    }
    if !section_fields(method).iter().any(|f| f == name) {
        let owners: Vec<&str> = Method::ALL
            .into_iter()
            .filter(|&m| section_fields(m).iter().any(|f| f == name))
            .map(Method::name)
            .collect();
        if owners.is_empty() {
            return Err(Error::Config(format!(
                "unknown setting {name:?}; the settings are {}",
                keyword_names().join(", ")
            )));
        }
        return Err(refuse(&owners.join("/")));
    }
    let value = match (name, value) {
        ("stratify", Value::Bool(true)) => Value::Object(Map::new()),
        ("stratify", Value::Bool(false)) => Value::Null,
        ("train_on", Value::Number(j)) => serde_json::json!({ "component": j }),
        (_, v) => v,
    };
    Ok((vec![method.name().to_string(), name.to_string()], value))
}

impl NisConfig {
    /// These settings with the JSON object `patch` laid over them by the one reader of settings
    /// (`integrate::settings`): a field it names is replaced, an object it gives for an object
    /// (`"flow"`, `"adam"`, `"stratify"`) changes the fields it names and keeps the others of
    /// `self` (what `nis integrate --nis-config` applies on top of its own options). Not
    /// checked: building the integrator checks it.
    pub fn patched(&self, patch: serde_json::Value) -> Result<NisConfig> {
        overlaid(self, patch)
    }
}

/// `current` with the JSON object `patch` laid over it, read back as a `T`; an error names the
/// path of the first field that the reader refuses on its own.
pub(crate) fn overlaid<T: Serialize + DeserializeOwned>(current: &T, patch: Value) -> Result<T> {
    if !patch.is_object() {
        return Err(Error::Config(format!(
            "the settings must be a JSON object, got {}",
            kind_of(&patch)
        )));
    }
    let base = serde_json::to_value(current).map_err(|e| Error::Config(e.to_string()))?;
    let mut merged = base.clone();
    overlay(&mut merged, patch.clone());
    T::deserialize(&merged).map_err(|e| {
        let mut leaves = Vec::new();
        leaves_of(&base, &patch, &mut Vec::new(), &mut leaves);
        leaves
            .into_iter()
            .find_map(|(path, value)| {
                let mut one = base.clone();
                set_at(&mut one, &path, value);
                T::deserialize(&one)
                    .err()
                    .map(|e| Error::Config(format!("{}: {e}", path.join("."))))
            })
            .unwrap_or(Error::Config(e.to_string()))
    })
}

/// Lays `given` over `base`: the fields of an object over those of an object, recursively;
/// anything else replaces.
fn overlay(base: &mut Value, given: Value) {
    match (base, given) {
        (Value::Object(fields), Value::Object(given)) => {
            for (k, g) in given {
                match fields.get_mut(&k) {
                    Some(b) => overlay(b, g),
                    None => {
                        fields.insert(k, g);
                    }
                }
            }
        }
        (base, given) => *base = given,
    }
}

/// The paths and values that `overlay(base, given)` replaces or inserts.
fn leaves_of(
    base: &Value,
    given: &Value,
    at: &mut Vec<String>,
    out: &mut Vec<(Vec<String>, Value)>,
) {
    match (base, given) {
        (Value::Object(b), Value::Object(g)) => {
            for (k, gv) in g {
                at.push(k.clone());
                match b.get(k) {
                    Some(bv) => leaves_of(bv, gv, at, out),
                    None => out.push((at.clone(), gv.clone())),
                }
                at.pop();
            }
        }
        (_, g) => out.push((at.clone(), g.clone())),
    }
}

/// Sets `root`'s field at `path` to `value`, making objects on the way (replacing non-objects).
fn set_at(root: &mut Value, path: &[String], value: Value) {
    let Some((last, inner)) = path.split_last() else {
        *root = value;
        return;
    };
    let mut node = root;
    for k in inner {
        if !node.is_object() {
            *node = Value::Object(Map::new());
        }
        node = node
            .as_object_mut()
            .expect("made an object above")
            .entry(k.clone())
            .or_insert_with(|| Value::Object(Map::new()));
    }
    if !node.is_object() {
        *node = Value::Object(Map::new());
    }
    node.as_object_mut()
        .expect("made an object above")
        .insert(last.clone(), value);
}

/// What kind of JSON value `v` is, for messages.
fn kind_of(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a bool",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// An error's message without the kind prefix `Display` adds.
fn message(e: &Error) -> String {
    match e {
        Error::Config(m) => m.clone(),
        e => e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flow::mask::Masks;
    use crate::loss::Loss;
    use crate::transform::TransformKind;
    use serde_json::json;

    #[test]
    fn a_patch_reads_as_the_c_abi_sections_did() {
        // A section read on its own (the C ABI's reading before the one reader) and the same
        // section laid over the defaults give the same settings.
        for nis in [
            json!({}),
            json!({"batch": 512, "flow": {"hidden_width": 16}, "loss": "chi_square"}),
            json!({"flow": {"transform": {"kind": "affine"}}, "adam": {"beta1": 0.8}}),
            json!({"stratify": {"beta": 0}, "train_on": "sum_abs", "reuse_training": 0}),
            json!({"stratify": null}),
        ] {
            let read: NisConfig = serde_json::from_value(nis.clone()).unwrap();
            let s = Settings::default().patched(json!({"nis": nis})).unwrap();
            assert_eq!(s.nis, read, "{nis}");
        }
        let s = Settings::default()
            .patched(json!({"seed": 4, "train_on": {"component": 1}, "vegas": {"alpha": 1.0}}))
            .unwrap();
        let expected = Settings {
            vegas: VegasConfig {
                alpha: 1.0,
                ..VegasConfig::default()
            },
            ..Settings::default()
        }
        .seed(4)
        .train_on(TrainOn::Component(1));
        assert_eq!(s, expected);
    }

    #[test]
    fn errors_name_the_path_of_the_refused_field() {
        for (patch, path) in [
            (json!({"nis": {"bach": 9}}), "nis.bach"),
            (json!({"nis": {"flow": {"width": 1}}}), "nis.flow.width"),
            (json!({"nis": {"batch": "many"}}), "nis.batch"),
            (json!({"vegas": {"alpha": [1]}}), "vegas.alpha"),
            (json!({"colour": 1}), "colour"),
        ] {
            let e = Settings::default().patched(patch.clone()).unwrap_err();
            assert!(matches!(e, Error::Config(_)), "{patch}");
            assert!(e.to_string().contains(path), "{patch}: {e}");
        }
        let e = Settings::default()
            .patched(json!({"colour": 1}))
            .unwrap_err();
        assert!(e.to_string().contains("unknown field"), "{e}");
        assert!(Settings::default().patched(json!(3)).is_err());
        // Read, then checked.
        assert!(Settings::default()
            .patched(json!({"nis": {"batch": 1}}))
            .is_err());
        assert!(Settings::default()
            .patched(json!({"uniform": {"iterations": 0}}))
            .is_err());
    }

    #[test]
    fn keywords_land_where_the_python_module_put_them() {
        let s = Settings::default()
            .with_keywords(
                Method::Nis,
                [
                    ("seed", json!(1)),
                    ("coupling", json!("pl")),
                    ("layers", json!(3)),
                    ("masks", json!("codes")),
                    ("hidden_width", json!(16)),
                    ("learning_rate", json!(0.001)),
                    ("loss", json!("chi2")),
                    ("stratify", json!(false)),
                    ("train_on", json!(1)),
                    ("batch", json!(512)),
                ],
            )
            .unwrap();
        let mut n = Settings::default().seed(1).nis;
        n.flow.transform = TransformKind::Linear { bins: 16 };
        n.flow.couplings = 3;
        n.flow.masks = Masks::Codes;
        // A layout named is kept: no run to a target switches it.
        n.auto_masks = false;
        n.flow.hidden_width = 16;
        n.adam.learning_rate = 0.001;
        n.loss = Loss::ChiSquare;
        n.stratify = None;
        n.train_on = TrainOn::Component(1);
        n.batch = 512;
        assert_eq!(s.nis, n);
        // bins alone keeps the kind; affine takes no bins.
        let t = |kw: &[(&str, Value)]| {
            Settings::default()
                .with_keywords(Method::Nis, kw.iter().cloned())
                .unwrap()
                .nis
                .flow
                .transform
        };
        assert_eq!(
            t(&[("bins", json!(8))]),
            TransformKind::Quadratic { bins: 8 }
        );
        assert_eq!(
            t(&[("coupling", json!("affine")), ("bins", json!(8))]),
            TransformKind::Affine
        );
        let s = Settings::default()
            .with_keywords(
                Method::Vegas,
                [("iterations", json!(8)), ("warmup", json!(2))],
            )
            .unwrap();
        assert_eq!((s.vegas.iterations, s.vegas.warmup), (8, 2));
        let s = Settings::default()
            .with_keywords(Method::Uniform, [("iterations", json!(5))])
            .unwrap();
        assert_eq!(s.uniform.iterations, 5);
    }

    #[test]
    fn a_refused_keyword_is_named() {
        for (method, kw, value, needle) in [
            (Method::Vegas, "coupling", json!("pq"), "coupling"),
            (Method::Vegas, "stratify", json!(false), "stratify"),
            (Method::Nis, "iterations", json!(5), "iterations"),
            (Method::Uniform, "train_on", json!(0), "train_on"),
            (Method::Nis, "colour", json!(1), "unknown setting"),
            (Method::Nis, "layers", json!(-1), "layers=-1"),
            (Method::Nis, "coupling", json!("spline"), "coupling"),
            (Method::Nis, "train_fraction", json!(1.5), "train_fraction"),
            (Method::Nis, "loss", json!("nll"), "nll"),
        ] {
            let e = Settings::default()
                .with_keywords(method, [(kw, value)])
                .unwrap_err();
            assert!(matches!(e, Error::Config(_)));
            assert!(e.to_string().contains(needle), "{kw}: {e}");
        }
    }

    #[test]
    fn the_keyword_list_is_the_schemas() {
        let names = keyword_names();
        for n in [
            "coupling",
            "batch",
            "flow",
            "adam",
            "increments",
            "iterations",
            "seed",
        ] {
            assert!(names.iter().any(|k| k == n), "{n}");
        }
        assert!(!names.iter().any(|k| k == "couplings"));
    }
}
