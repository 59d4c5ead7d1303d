//! Fuzzing the core library's readers of outside data (issue 16): model files (`nis::io`,
//! `NisIntegrator::load`) truncated, bit-flipped and with forged safetensors headers and
//! configs, and `--nis-config` JSON (`NisConfig`). Each must give a typed error or a valid value
//! within the limits of `nis-fuzz-support`. `NIS_FUZZ_CASES=N` sets the cases per target.

use nis_fuzz_support as fuzz;

use fuzz::{check, mutated, Counting};
use nis::flow::{Density, FlowConfig};
use nis::integrate::nis::{NisConfig, NisIntegrator};
use nis::integrate::Integrator;
use proptest::prelude::*;

#[global_allocator]
static ALLOC: Counting = Counting;

/// A small trained integrator's file: a real model with real metadata to mutate.
fn saved_integrator(path: &std::path::Path) -> Vec<u8> {
    let config = NisConfig::builder()
        .flow(FlowConfig {
            hidden_width: 8,
            hidden_layers: 1,
            blob_bins: 4,
            ..FlowConfig::default()
        })
        .batch(64)
        .seed(5)
        .build()
        .expect("valid settings");
    let mut integ = NisIntegrator::new(3, config).expect("an integrator");
    let f = |x: &[f64]| 1.0 + x[0] * x[1];
    integ.integrate(&f, 1_000).expect("an estimate");
    integ.save(path).expect("saved");
    std::fs::read(path).expect("the file")
}

/// A safetensors file from a header (JSON) and a body, as the format lays it out.
fn safetensors(header: &str, body: &[u8]) -> Vec<u8> {
    let mut out = (header.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(body);
    out
}

/// Files that lie: a header length past the file, tensors claiming terabytes, configs claiming
/// flows far too large, integrator settings out of range.
fn forged() -> impl Strategy<Value = Vec<u8>> {
    let huge = prop::sample::select(vec![
        0u64,
        1,
        1 << 20,
        1 << 31,
        1 << 40,
        u32::MAX as u64,
        u64::MAX / 4,
        u64::MAX,
    ]);
    let config = |width: u64, layers: u64, dim: u64| {
        format!(
            r#"{{\"dim\":{dim},\"transform\":{{\"kind\":\"quadratic\",\"bins\":16}},\"couplings\":0,\"hidden_layers\":{layers},\"hidden_width\":{width},\"blob_bins\":16,\"context_dim\":0,\"seed\":0}}"#
        )
    };
    prop_oneof![
        // The length prefix claims a header longer than the file.
        (huge.clone(), prop::collection::vec(any::<u8>(), 0..64)).prop_map(|(n, rest)| {
            let mut v = n.to_le_bytes().to_vec();
            v.extend(rest);
            v
        }),
        // A tensor claiming a huge shape and data range.
        (huge.clone(), huge.clone()).prop_map(|(a, b)| safetensors(
            &format!(
                r#"{{"__metadata__":{{"format":"nis-flow/1"}},"t":{{"dtype":"F32","shape":[{a},{b}],"data_offsets":[0,{}]}}}}"#,
                a.wrapping_mul(b).wrapping_mul(4)
            ),
            &[0; 16]
        )),
        // A config claiming a flow far too large for the file (or for any machine).
        (huge.clone(), 0u64..70, prop::sample::select(vec![1u64, 2, 3, 4096, 1 << 40]))
            .prop_map(move |(w, l, d)| safetensors(
                &format!(
                    r#"{{"__metadata__":{{"format":"nis-flow/1","checksum":"0","config":"{}","nis_integrator":"{{\"batch\":{w}}}"}}}}"#,
                    config(w, l, d)
                ),
                &[]
            )),
    ]
}

#[test]
fn model_files_truncated_flipped_and_forged() {
    let dir = fuzz::scratch("model");
    let path = dir.join("case.safetensors");
    let original = saved_integrator(&dir.join("seed.safetensors"));
    let strategy = prop_oneof![
        3 => mutated(original.clone(), 4),
        1 => (0..original.len()).prop_map({
            let o = original.clone();
            move |n| o[..n].to_vec()
        }),
        2 => forged(),
    ];
    fuzz::fuzz("model", 400, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let meta = check(
            tally,
            bytes.len(),
            || nis::io::read_metadata(&bytes, "nis-flow/1", "a nis model"),
            |_| 0,
        )?;
        let flow = check(tally, bytes.len(), || nis::io::load_with(&path), |_| 0)?;
        let integ = check(tally, bytes.len(), || NisIntegrator::load(&path), |_| 0)?;
        if let Ok((flow, _)) = &flow {
            prop_assert!(meta.is_ok());
            prop_assert!(flow.params().iter().all(|p| p.is_finite()));
            prop_assert!(4 * flow.param_count() <= bytes.len());
        }
        if let Ok(integ) = integ {
            // An accepted integrator estimates (a few evaluations, within the same limits).
            let f = |x: &[f64]| x[0];
            let mut integ = integ;
            let r = check(tally, bytes.len(), || integ.estimate(&f, 256), |_| 0)?;
            prop_assert!(r.is_ok(), "a loaded integrator failed: {:?}", r.err());
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Zero, negative, huge and fractional numbers, and values of the wrong type.
fn absurd() -> impl Strategy<Value = serde_json::Value> {
    prop::sample::select(vec![
        serde_json::json!(0),
        serde_json::json!(-1),
        serde_json::json!(1),
        serde_json::json!(2),
        serde_json::json!(1_000_000_000_000u64),
        serde_json::json!(u64::MAX),
        serde_json::json!(65536),
        serde_json::json!(4096),
        serde_json::json!(0.5),
        serde_json::json!(-0.0),
        serde_json::json!(1e300),
        serde_json::json!(1e-300),
        serde_json::json!("nan"),
        serde_json::json!(null),
        serde_json::json!([1]),
    ])
}

/// `--nis-config` as the CLI reads it: the defaults with fields (of `flow` and `adam` too)
/// set to absurd values, or random JSON.
fn nis_config() -> impl Strategy<Value = String> {
    let defaults = serde_json::to_value(NisConfig::default()).expect("serialises");
    let mut paths: Vec<(String, Option<String>)> = Vec::new();
    for (k, v) in defaults.as_object().expect("an object") {
        paths.push((k.clone(), None));
        if let Some(inner) = v.as_object() {
            paths.extend(inner.keys().map(|k2| (k.clone(), Some(k2.clone()))));
        }
    }
    prop_oneof![
        1 => fuzz::json_value().prop_map(|v| v.to_string()),
        3 => prop::collection::vec((prop::sample::select(paths), absurd()), 1..5).prop_map(
            move |fields| {
                let mut v = defaults.clone();
                for ((k, k2), x) in fields {
                    match k2 {
                        Some(k2) if v[&k].is_object() => v[&k][&k2] = x,
                        Some(_) => {}
                        None => v[&k] = x,
                    }
                }
                v.to_string()
            }
        ),
    ]
}

#[test]
fn nis_configs_random_and_absurd() {
    fuzz::fuzz("nis-config", 400, nis_config(), |tally, json| {
        let config = check(
            tally,
            json.len(),
            || {
                serde_json::from_str::<NisConfig>(&json)
                    .map_err(|e| nis::Error::Config(e.to_string()))
            },
            |_| 0,
        )?;
        let Ok(config) = config else { return Ok(()) };
        // Building the integrator allocates the flow the config describes (checked against
        // MAX_PARAMS first): the allowance counts its weights, gradients and Adam's moments.
        let dim = 4;
        let params = FlowConfig {
            dim,
            ..config.flow.clone()
        }
        .param_count()
        .unwrap_or(0)
        .min(nis::flow::config::MAX_PARAMS);
        let _built = check(
            tally,
            json.len() + 4 * 4 * params,
            || NisIntegrator::new(dim, config.clone()),
            |_| 0,
        )?;
        Ok(())
    });
}

#[test]
fn forged_config_claiming_a_huge_flow_is_refused_before_allocating() {
    // Regression: from_bytes built the flow from the file's config before looking at the
    // weights, so 70 bytes of JSON could ask for 64 layers of 65536² weights.
    let header = r#"{"__metadata__":{"format":"nis-flow/1","config":"{\"dim\":64,\"transform\":{\"kind\":\"affine\"},\"hidden_layers\":4,\"hidden_width\":256}"}}"#;
    let e = nis::io::from_bytes(&safetensors(header, &[])).unwrap_err();
    assert!(e.contains("bytes of weights"), "{e}");
}

#[test]
fn integrator_settings_in_a_model_file_are_validated_on_load() {
    // Regression: NisIntegrator::load took the stored settings unchecked (a batch of 0 or a
    // train_fraction of 7 reached the integrator).
    let dir = fuzz::scratch("settings");
    let path = dir.join("m.safetensors");
    saved_integrator(&path);
    let flow = NisIntegrator::load(&path).expect("loads").flow().clone();
    let mut settings = serde_json::to_value(NisConfig::default()).expect("serialises");
    settings["batch"] = 0.into();
    let meta =
        std::collections::HashMap::from([("nis_integrator".to_string(), settings.to_string())]);
    std::fs::write(&path, nis::io::to_bytes(&flow, &meta).expect("bytes")).expect("written");
    let e = NisIntegrator::load(&path)
        .err()
        .expect("refused")
        .to_string();
    assert!(e.contains("integrator settings"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// A settings patch as the C ABI's config, Python's keywords and the CLI's flags reach the one
/// reader: the defaults' paths (every section, and `flow`, `adam`, `stratify`, `transform`
/// within NIS's) set to absurd values, or random JSON anywhere.
fn settings_patch() -> impl Strategy<Value = serde_json::Value> {
    let defaults = serde_json::to_value(nis::integrate::Settings::default()).expect("serialises");
    let mut paths: Vec<Vec<String>> = vec![vec!["seed".into()], vec!["train_on".into()]];
    fn walk(v: &serde_json::Value, at: &mut Vec<String>, out: &mut Vec<Vec<String>>) {
        if let Some(fields) = v.as_object() {
            for (k, inner) in fields {
                at.push(k.clone());
                out.push(at.clone());
                walk(inner, at, out);
                at.pop();
            }
        }
    }
    walk(&defaults, &mut Vec::new(), &mut paths);
    let value = prop_oneof![3 => absurd(), 1 => fuzz::json_value()];
    prop_oneof![
        1 => fuzz::json_value(),
        4 => prop::collection::vec((prop::sample::select(paths), value), 0..5).prop_map(
            |fields| {
                let mut patch = serde_json::json!({});
                for (path, x) in fields {
                    let mut node = &mut patch;
                    for k in &path[..path.len() - 1] {
                        if !node[k].is_object() {
                            node[k] = serde_json::json!({});
                        }
                        node = &mut node[k];
                    }
                    node[path.last().expect("a path has a field")] = x;
                }
                patch
            }
        ),
    ]
}

/// Keywords as Python passes them: known names (and unknown ones) with absurd values, for any
/// method.
fn settings_keywords() -> impl Strategy<Value = (usize, Vec<(String, serde_json::Value)>)> {
    let mut names = nis::integrate::settings::keyword_names();
    names.extend(["colour".to_string(), "dim".to_string(), String::new()]);
    let value = prop_oneof![3 => absurd(), 1 => fuzz::json_value()];
    (
        0..3usize,
        prop::collection::vec((prop::sample::select(names), value), 0..6),
    )
}

#[test]
fn settings_patches_and_keywords_random_and_absurd() {
    use nis::integrate::{Method, Settings};
    // Ok must be valid settings; an error must be a typed one (a panic fails the case).
    let judge = |r: nis::Result<Settings>| -> Result<(), TestCaseError> {
        match r {
            Ok(s) => prop_assert!(s.validate().is_ok(), "accepted, not valid: {s:?}"),
            Err(e) => prop_assert!(matches!(e, nis::Error::Config(_)), "{e}"),
        }
        Ok(())
    };
    fuzz::fuzz("settings-patch", 400, settings_patch(), |tally, patch| {
        let len = patch.to_string().len();
        let r = check(
            tally,
            len,
            || Settings::default().patched(patch.clone()),
            |_| 0,
        )?;
        judge(r)
    });
    fuzz::fuzz(
        "settings-keywords",
        400,
        settings_keywords(),
        |tally, (m, keywords)| {
            let len = serde_json::to_string(&keywords).map_or(0, |s| s.len());
            let r = check(
                tally,
                len,
                || {
                    Settings::default().with_keywords(
                        Method::ALL[m],
                        keywords.iter().map(|(k, v)| (k.as_str(), v.clone())),
                    )
                },
                |_| 0,
            )?;
            judge(r)
        },
    );
}
