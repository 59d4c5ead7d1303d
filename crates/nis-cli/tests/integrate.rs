//! `nis integrate` end to end: every method side by side in one JSON object with a warnings
//! array, one method alone, and budgets too small for an error bar.

use std::path::PathBuf;
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-cli-integrate-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn nis(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_nis"))
        .args(args)
        .output()
        .unwrap()
}

/// The JSON `nis` prints for `args`, which must succeed.
fn json_of(args: &[&str]) -> serde_json::Value {
    let out = nis(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn json_without_a_method_holds_every_method_and_the_warnings() {
    let out = nis(&[
        "integrate",
        "gauss",
        "--dim",
        "2",
        "--evals",
        "20000",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let exact = v["exact"].as_f64().unwrap();
    for method in ["nis", "vegas", "uniform"] {
        let r = &v["results"][method];
        let (value, err) = (r["value"].as_f64().unwrap(), r["std_err"].as_f64().unwrap());
        assert!(
            (value - exact).abs() < 5.0 * err,
            "{method}: {value} ± {err}"
        );
        assert_eq!(r["n_eval"].as_u64(), Some(20000));
    }
    assert!(v["warnings"].is_array());
    // With a method, one result object as before.
    let out = nis(&[
        "integrate",
        "gauss",
        "--evals",
        "20000",
        "--method",
        "vegas",
        "--json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["value"].is_f64() && v.get("results").is_none());
}

#[test]
fn a_budget_too_small_for_an_error_bar_is_an_error() {
    for method in ["nis", "vegas", "uniform"] {
        let out = nis(&["integrate", "camel", "--evals", "0", "--method", method]);
        assert!(!out.status.success());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            err.contains("needs at least") && !err.contains("panicked"),
            "{err}"
        );
    }
}

/// The stratified final phase is the default; `--nis-config` turns it off or tunes it, and bad
/// settings are a clear error, not a panic.
#[test]
fn nis_config_sets_the_stratification_of_the_latent() {
    let run = |config: &str| {
        let out = nis(&[
            "integrate",
            "camel",
            "--dim",
            "2",
            "--evals",
            "20000",
            "--method",
            "nis",
            "--json",
            "--nis-config",
            config,
        ]);
        (
            out.status.success(),
            out.stdout,
            String::from_utf8_lossy(&out.stderr).into_owned(),
        )
    };
    let value = |stdout: &[u8]| {
        let v: serde_json::Value = serde_json::from_slice(stdout).unwrap();
        (
            v["value"].as_f64().unwrap(),
            v["std_err"].as_f64().unwrap(),
            v["exact"].as_f64(),
        )
    };
    let (ok, default, err) = run("{}");
    assert!(ok, "{err}");
    let (ok, iid, err) = run(r#"{"stratify": null}"#);
    assert!(ok, "{err}");
    let (ok, even, err) = run(r#"{"stratify": {"beta": 0}}"#);
    assert!(ok, "{err}");
    let (d, i, e) = (value(&default), value(&iid), value(&even));
    assert!(d != i && d != e && i != e, "three distinct final phases");
    for (v, s, _) in [d, i, e] {
        assert!((v - 0.9816603).abs() < 5.0 * s, "{v} ± {s}");
    }
    let (ok, _, err) = run(r#"{"stratify": {"min_per_cube": 1}}"#);
    assert!(
        !ok && err.contains("invalid NIS settings") && !err.contains("panicked"),
        "{err}"
    );
}

/// A loaded integrator keeps the settings it was saved with: options that would change them are
/// an error, not silently ignored.
#[test]
fn settings_that_a_loaded_integrator_would_ignore_are_an_error() {
    let dir = scratch("load-conflicts");
    let model = dir.join("gauss.nis");
    let model = model.to_str().unwrap();
    let base = ["integrate", "gauss", "--evals", "20000", "--method", "nis"];
    let out = nis(&[&base[..], &["--save", model]].concat());
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let loaded = nis(&[&base[..], &["--load", model]].concat());
    assert!(
        loaded.status.success(),
        "{}",
        String::from_utf8_lossy(&loaded.stderr)
    );
    for extra in [
        &["--nis-config", r#"{"stratify": null}"#][..],
        &["--coupling", "rq"],
        &["--bins", "8"],
        &["--loss", "chi2"],
        &["--masks", "codes"],
    ] {
        let out = nis(&[&base[..], &["--load", model], extra].concat());
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success()
                && err.contains("cannot be used with")
                && !err.contains("panicked"),
            "{extra:?}: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `--masks codes` builds the flow of fewer layers, a saved model keeps it (its weights fit no
/// other layout), and an unknown layout is an error.
#[test]
fn the_code_masks_are_saved_with_the_model() {
    let dir = scratch("codes");
    let model = dir.join("gauss.nis");
    let model = model.to_str().unwrap();
    let base = [
        "integrate",
        "gauss",
        "--dim",
        "5",
        "--evals",
        "40000",
        "--method",
        "nis",
    ];
    let run = |extra: &[&str]| {
        let out = nis(&[&base[..], extra, &["--json"]].concat());
        let err = String::from_utf8_lossy(&out.stderr).to_string();
        assert!(out.status.success(), "{extra:?}: {err}");
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let (value, std_err) = (v["value"].as_f64().unwrap(), v["std_err"].as_f64().unwrap());
        let exact = v["exact"].as_f64().unwrap();
        assert!((value - exact).abs() < 5.0 * std_err, "{extra:?}: {v}");
        value
    };
    let codes = run(&["--masks", "codes", "--save", model]);
    let binary = run(&[]);
    assert_ne!(codes, binary);
    let saved = std::fs::read(model).unwrap();
    // The config is JSON inside the safetensors header's JSON, its quotes escaped.
    let needle = br#"\"masks\":\"codes\""#;
    assert!(saved.windows(needle.len()).any(|w| w == needle));
    run(&["--load", model]);
    let out = nis(&[&base[..], &["--masks", "gray"]].concat());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("gray") && !err.contains("panicked"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `nis eval` with and without a synthetic cost: the same values, bit for bit.
#[test]
fn eval_serves_the_same_values_with_a_synthetic_cost() {
    use std::io::Write;
    let points: Vec<f64> = (0..3 * 4).map(|i| (i as f64 * 0.37).fract()).collect();
    let mut frame = 3u64.to_le_bytes().to_vec();
    frame.extend(points.iter().flat_map(|v| v.to_le_bytes()));
    frame.extend(0u64.to_le_bytes());
    let serve = |extra: &[&str]| {
        let mut child = Command::new(env!("CARGO_BIN_EXE_nis"))
            .args(["eval", "camel-sharp", "--dim", "4"])
            .args(extra)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        child.stdin.take().unwrap().write_all(&frame).unwrap();
        let out = child.wait_with_output().unwrap();
        assert!(out.status.success());
        out.stdout
    };
    let plain = serve(&[]);
    assert_eq!(plain.len(), 3 * 8);
    assert_eq!(serve(&["--spins", "5000"]), plain);
}

#[test]
fn a_target_stops_each_method_and_bad_targets_are_errors() {
    let out = nis(&[
        "integrate",
        "camel",
        "--dim",
        "2",
        "--method",
        "uniform",
        "--rel-err",
        "1e-2",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["stop"], "target");
    assert!(v["std_err"].as_f64().unwrap() <= 1e-2 * v["value"].as_f64().unwrap());
    // The figures the warnings read come with the result.
    assert!(
        v["convergence"]["divergence"].as_f64().unwrap() >= 0.0,
        "{v}"
    );
    // A limit: not an error, the reason and a warning on stderr.
    let out = nis(&[
        "integrate",
        "camel",
        "--dim",
        "2",
        "--method",
        "uniform",
        "--rel-err",
        "1e-5",
        "--max-evals",
        "20000",
        "--json",
    ]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["stop"], "max_evals");
    assert!(String::from_utf8_lossy(&out.stderr).contains("was not met"));
    // A budget and a target, a limit without a target, a non-positive target: errors.
    for args in [
        &["--evals", "1000", "--rel-err", "1e-2"][..],
        &["--max-evals", "1000"][..],
        &["--rel-err", "0"][..],
        &["--rel-err", "1e-2", "--seconds", "-1"][..],
    ] {
        let mut all = vec!["integrate", "camel", "--dim", "2", "--method", "vegas"];
        all.extend_from_slice(args);
        let out = nis(&all);
        assert!(!out.status.success(), "{args:?} was accepted");
    }
}

#[test]
fn channels_run_on_the_multi_channel_examples_only() {
    let out = nis(&[
        "integrate",
        "dalitz",
        "--channels",
        "--method",
        "vegas",
        "--evals",
        "100000",
        "--json",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let c = &v["channels"];
    assert_eq!(c["means"].as_array().unwrap().len(), 2);
    let pull = (v["value"].as_f64().unwrap() - v["exact"].as_f64().unwrap())
        / v["std_err"].as_f64().unwrap();
    assert!(pull.abs() < 5.0, "{v}");
    // Through the channels to a target: the run stops there.
    let out = nis(&[
        "integrate",
        "dalitz",
        "--channels",
        "--method",
        "uniform",
        "--rel-err",
        "1e-2",
        "--json",
    ]);
    assert!(out.status.success());
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["stop"], "target", "{v}");
    assert!(v["std_err"].as_f64().unwrap() <= 1e-2 * v["value"].as_f64().unwrap());
    assert_eq!(v["channels"]["means"].as_array().unwrap().len(), 2);
    let out = nis(&[
        "integrate",
        "camel",
        "--dim",
        "2",
        "--channels",
        "--method",
        "vegas",
    ]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("resonances-4d"));
    // NIS with a flow per channel; the flag needs channels or signs.
    let args = [
        "integrate",
        "dalitz",
        "--method",
        "nis",
        "--evals",
        "100000",
        "--json",
    ];
    let v = json_of(&[&args[..], &["--channels", "--flow-per-channel"]].concat());
    assert_eq!(v["channels"]["means"].as_array().unwrap().len(), 2);
    let out = nis(&[&args[..], &["--flow-per-channel"]].concat());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--channels or --signs"));
    // Without learned channel weights; the flag needs channels.
    let v = json_of(&[&args[..], &["--channels", "--no-weight-network"]].concat());
    let pull = (v["value"].as_f64().unwrap() - v["exact"].as_f64().unwrap())
        / v["std_err"].as_f64().unwrap();
    assert!(pull.abs() < 5.0, "{v}");
    let out = nis(&[&args[..], &["--signs", "split", "--no-weight-network"]].concat());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--no-weight-network needs --channels"));
    // resonances-4d's channels weigh by their propagators unless told not to: two estimates,
    // each of the exact value.
    let res = [
        "integrate",
        "resonances-4d",
        "--method",
        "uniform",
        "--evals",
        "100000",
        "--json",
        "--channels",
    ];
    let enhanced = json_of(&res);
    let by_densities = json_of(&[&res[..], &["--no-enhancement"]].concat());
    assert_ne!(enhanced["value"], by_densities["value"]);
    for v in [&enhanced, &by_densities] {
        let pull = (v["value"].as_f64().unwrap() - v["exact"].as_f64().unwrap())
            / v["std_err"].as_f64().unwrap();
        assert!(pull.abs() < 5.0, "{v}");
    }
    let out = nis(&[&res[..7], &["--no-enhancement"]].concat());
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--no-enhancement needs --channels"));
}

#[test]
fn sampled_events_through_channels_carry_their_channel() {
    let dir = scratch("events");
    let out = dir.join("events.csv");
    let run = |name: &str| {
        nis(&[
            "sample",
            name,
            "--channels",
            "--n",
            "300",
            "--evals",
            "60000",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    let done = run("dalitz");
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let text = std::fs::read_to_string(&out).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("x0,x1,weight,channel"));
    let channels: Vec<usize> = lines
        .map(|l| l.rsplit(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(channels.len(), 300);
    assert!(channels.iter().all(|k| *k < 2));
    // An integrand without channels: an error that names the examples, no file.
    std::fs::remove_file(&out).unwrap();
    let failed = run("camel");
    assert!(!failed.status.success());
    assert!(String::from_utf8_lossy(&failed.stderr).contains("resonances-4d"));
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
