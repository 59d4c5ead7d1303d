//! `nis` under `mpirun` with 1, 2 and 3 ranks (oversubscribed on a 2-core machine), on tiny
//! budgets. Ignored unless asked for: `scripts/test/test-mpi.sh` installs MPI, builds the binary with
//! the feature `mpi` into target/mpi and runs these with `NIS_MPI_BIN` (that binary) and
//! `NIS_MPI_EXAMPLE` (the library's `mpi_ranks` example) set.
//!
//! What must hold: one result per seed and rank count, the same on every run; results of
//! different rank counts within 5 combined standard errors; one rank under mpirun gives exactly
//! what the build without MPI gives; identical flows on all ranks after every step; a model saved
//! under MPI loads without it; a failing integrand on one rank stops all of them with rank 0
//! printing why; a rank that dies makes mpirun exit non-zero within 30 s and leaves no file; a
//! plain path-traced image is bit-identical to the single-process one.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Output, Stdio};
use std::time::{Duration, Instant};

use serde_json::Value;

/// The default build's binary (no MPI).
const NIS: &str = env!("CARGO_BIN_EXE_nis");

fn env_path(var: &str) -> PathBuf {
    PathBuf::from(std::env::var(var).unwrap_or_else(|_| {
        panic!("{var} is not set: run scripts/test/test-mpi.sh, which builds the MPI binaries")
    }))
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-mpi-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// `mpirun -n ranks program args…`, as root if need be, oversubscribed, one thread per rank.
fn mpirun(ranks: usize, program: &Path, args: &[&str]) -> Command {
    let mut c = Command::new("mpirun");
    c.args(["--oversubscribe", "-n", &ranks.to_string()])
        .arg(program)
        .args(args)
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .env("RAYON_NUM_THREADS", "1");
    c
}

fn ok(mut c: Command) -> Output {
    let out = c.output().expect("mpirun runs");
    assert!(
        out.status.success(),
        "{c:?} failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// `child`'s exit status; kills it and fails, naming `what`, if it still runs `limit` after
/// `since`.
fn wait_within(child: &mut Child, since: Instant, limit: Duration, what: &str) -> ExitStatus {
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        if since.elapsed() > limit {
            let _ = child.kill();
            panic!("{what} still running after {} s", limit.as_secs());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The JSON result of one method, without its wall time.
fn result(out: &Output) -> Value {
    let stdout = String::from_utf8_lossy(&out.stdout);
    let lines: Vec<&str> = stdout.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "one JSON line, from rank 0 only: {stdout}");
    let mut v: Value = serde_json::from_str(lines[0]).unwrap();
    v.as_object_mut().unwrap().remove("seconds");
    v
}

const INTEGRATE: [&str; 8] = [
    "integrate",
    "camel",
    "--dim",
    "2",
    "--evals",
    "40000",
    "--json",
    "--method",
];

fn integrate(ranks: usize, method: &str, extra: &[&str]) -> Value {
    let mut args = INTEGRATE.to_vec();
    args.push(method);
    args.extend_from_slice(&["--seed", "3"]);
    args.extend_from_slice(extra);
    result(&ok(mpirun(ranks, &env_path("NIS_MPI_BIN"), &args)))
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn one_seed_and_rank_count_give_one_result_and_rank_counts_agree() {
    for method in ["nis", "vegas", "uniform"] {
        let mut by_ranks = Vec::new();
        for ranks in 1..=3 {
            let a = integrate(ranks, method, &[]);
            let b = integrate(ranks, method, &[]);
            let (mut a0, mut b0) = (a.clone(), b.clone());
            // Checksums are compared below; the numbers must be equal bit for bit.
            a0.as_object_mut().unwrap().remove("rank_checksums");
            b0.as_object_mut().unwrap().remove("rank_checksums");
            assert_eq!(a0, b0, "{method} with {ranks} ranks, two runs");
            if let Some(sums) = a.get("rank_checksums") {
                let sums = sums.as_array().unwrap();
                assert_eq!(sums.len(), ranks);
                assert!(sums.iter().all(|s| s == &sums[0]), "{sums:?}");
            }
            by_ranks.push(a);
        }
        let value = |v: &Value| v["value"].as_f64().unwrap();
        let err = |v: &Value| v["std_err"].as_f64().unwrap();
        // Distinct rank counts draw distinct points: independent estimates of one integral.
        for (i, a) in by_ranks.iter().enumerate() {
            for b in &by_ranks[i + 1..] {
                let pull = (value(a) - value(b)).abs() / err(a).hypot(err(b));
                assert!(pull < 5.0, "{method}: {a} vs {b}: {pull:.1} σ");
            }
            let exact = a["exact"].as_f64().unwrap();
            assert!((value(a) - exact).abs() < 5.0 * err(a), "{method}: {a}");
        }
        // 3 ranks evaluate what one does, no more.
        assert_eq!(by_ranks[0]["n_eval"], by_ranks[2]["n_eval"], "{method}");
        // The reliability figures are those of all ranks' weights: a rank's own ESS would be
        // about 1/P of the whole (≤ ½ here), while the ESS of independent runs of one budget
        // differs by a few percent at most (its relative spread is ~√(kurtosis/N), N ≥ 10⁴).
        let ess = |v: &Value| v["ess"].as_f64().unwrap();
        for a in &by_ranks[1..] {
            let ratio = ess(a) / ess(&by_ranks[0]);
            assert!((0.75..1.33).contains(&ratio), "{method}: ESS ratio {ratio}");
        }
    }
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn one_rank_under_mpirun_is_the_build_without_mpi() {
    for method in ["nis", "vegas", "uniform"] {
        let under_mpi = integrate(1, method, &[]);
        let mut args = INTEGRATE.to_vec();
        args.extend_from_slice(&[method, "--seed", "3"]);
        let plain = result(&ok({
            let mut c = Command::new(NIS);
            c.args(&args);
            c
        }));
        assert_eq!(under_mpi, plain, "{method}");
    }
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn flows_are_identical_on_every_rank_after_every_step() {
    let out = ok(mpirun(3, &env_path("NIS_MPI_EXAMPLE"), &["checksums"]));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("parameters of 3 ranks identical after 20 steps"),
        "{stdout}"
    );
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn a_model_saved_under_mpi_loads_without_it() {
    let path = tmp("saved.safetensors");
    let p = path.to_str().unwrap();
    let trained = integrate(2, "nis", &["--save", p]);
    let dir = path.parent().unwrap();
    let files: Vec<_> = std::fs::read_dir(dir).unwrap().collect();
    assert_eq!(
        files.len(),
        1,
        "only rank 0 writes, and no temporary file is left"
    );
    let mut args = INTEGRATE.to_vec();
    args.extend_from_slice(&["nis", "--seed", "4", "--load", p]);
    let loaded = result(&ok({
        let mut c = Command::new(NIS);
        c.args(&args);
        c
    }));
    let (a, b) = (&trained, &loaded);
    let pull = (a["value"].as_f64().unwrap() - b["value"].as_f64().unwrap()).abs()
        / a["std_err"]
            .as_f64()
            .unwrap()
            .hypot(b["std_err"].as_f64().unwrap());
    assert!(pull < 5.0, "{a} vs {b}");
    std::fs::remove_file(&path).unwrap();
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn an_integrand_failing_on_one_rank_stops_every_rank() {
    let started = Instant::now();
    let out = mpirun(3, &env_path("NIS_MPI_EXAMPLE"), &["fail", "2"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("error: rank 2 failed: the integrand failed: deliberate failure on rank 2"),
        "{stderr}"
    );
    assert_eq!(
        stderr.matches("error:").count(),
        1,
        "rank 0 alone prints: {stderr}"
    );
    assert!(started.elapsed() < Duration::from_secs(60));
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn a_rank_that_dies_ends_mpirun_within_30_s_without_a_partial_file() {
    let path = tmp("never.safetensors");
    let p = path.to_str().unwrap();
    // An integrand of ~100 µs per point and a budget of minutes: the ranks are busy when one dies.
    let mut child = mpirun(
        2,
        &env_path("NIS_MPI_BIN"),
        &[
            "integrate",
            "costly",
            "--dim",
            "4",
            "--method",
            "nis",
            "--evals",
            "100000000",
            "--json",
            "--save",
            p,
        ],
    )
    .stdout(Stdio::null())
    .stderr(Stdio::null())
    .spawn()
    .unwrap();
    std::thread::sleep(Duration::from_secs(3));
    // The ranks are mpirun's children (the binary's name is `nis`); kill the last one.
    let ps = Command::new("pgrep")
        .args(["-P", &child.id().to_string()])
        .output()
        .unwrap();
    let ranks: Vec<u32> = String::from_utf8_lossy(&ps.stdout)
        .split_whitespace()
        .filter_map(|s| s.parse().ok())
        .collect();
    assert!(!ranks.is_empty(), "mpirun has rank processes");
    let killed = Instant::now();
    let victim = ranks.last().unwrap().to_string();
    assert!(Command::new("kill")
        .args(["-9", &victim])
        .status()
        .unwrap()
        .success());
    let status = wait_within(
        &mut child,
        killed,
        Duration::from_secs(30),
        "mpirun after a rank died",
    );
    assert!(!status.success());
    let left: Vec<_> = std::fs::read_dir(path.parent().unwrap())
        .unwrap()
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("never"))
        .collect();
    assert!(left.is_empty(), "no partial file: {left:?}");
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn guided_renders_are_one_image_per_seed_and_rank_count() {
    // Every rank trains its guide on the records of all ranks, so they stay in step (a rank whose
    // guide differed would sample other directions, and the two runs below would differ).
    for guide in ["ppg", "nis-kl"] {
        let runs: Vec<Vec<u8>> = (0..2)
            .map(|run| {
                let out = tmp(&format!("{guide}-{run}.exr"));
                let mut args = vec!["render", "cornell-box", "--spp", "8", "--res", "24"];
                args.extend_from_slice(&["--guide", guide, "--seed", "1"]);
                args.extend_from_slice(&["--out", out.to_str().unwrap()]);
                ok(mpirun(2, &env_path("NIS_MPI_BIN"), &args));
                std::fs::read(&out).unwrap()
            })
            .collect();
        assert!(runs[0] == runs[1], "{guide}: two runs on 2 ranks differ");
    }
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn a_plain_path_traced_image_is_bit_identical_to_one_process() {
    // 20 spp: two sample slices (16 and 4), whose waves are cut differently; a tile keeps its
    // rank in both, so each pixel is still traced by one rank, slices in order.
    for spp in ["4", "20"] {
        let render = [
            "render",
            "cornell-box",
            "--spp",
            spp,
            "--res",
            "40",
            "--seed",
            "2",
        ];
        let single = tmp(&format!("single-{spp}.exr"));
        let mut c = Command::new(NIS);
        c.args(render).arg("--out").arg(&single);
        ok(c);
        let single = std::fs::read(&single).unwrap();
        for ranks in [2, 3] {
            let out = tmp(&format!("ranks{ranks}-{spp}.exr"));
            let mut args = render.to_vec();
            args.extend_from_slice(&["--out", out.to_str().unwrap()]);
            ok(mpirun(ranks, &env_path("NIS_MPI_BIN"), &args));
            assert!(
                std::fs::read(&out).unwrap() == single,
                "{ranks} ranks, {spp} spp"
            );
        }
    }
}

/// `nis integrate …` under `mpirun -n ranks` with `args`, its JSON result.
fn run_json(ranks: usize, args: &[&str]) -> Value {
    result(&ok(mpirun(ranks, &env_path("NIS_MPI_BIN"), args)))
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn targets_and_channels_run_alike_on_every_rank() {
    let pull = |v: &Value| {
        (v["value"].as_f64().unwrap() - v["exact"].as_f64().unwrap())
            / v["std_err"].as_f64().unwrap()
    };
    for ranks in [2, 3] {
        // A run to a target, which must stop there with an honest result.
        let to_target = |args: &[&str], what: &str| {
            let a = run_json(ranks, args);
            assert_eq!(a["stop"], "target", "{what}, {ranks} ranks: {a}");
            assert!(pull(&a).abs() < 5.0, "{what}, {ranks} ranks: {a}");
            a
        };
        // To a target: VEGAS+ and plain MC plan from counts alone, so two runs agree to the bit;
        // NIS decides its training from the slowest rank's times, the same on every rank.
        for method in ["vegas", "uniform", "nis"] {
            let args = [
                "integrate",
                "camel",
                "--dim",
                "2",
                "--json",
                "--seed",
                "3",
                "--method",
                method,
                "--rel-err",
                "1e-2",
            ];
            let a = to_target(&args, method);
            if method == "nis" {
                let sums = a["rank_checksums"].as_array().unwrap();
                assert!(sums.iter().all(|s| s == &sums[0]), "{sums:?}");
            } else {
                assert_eq!(
                    a,
                    run_json(ranks, &args),
                    "{method}, {ranks} ranks, two runs"
                );
            }
        }
        // NIS to a target on a smooth integrand in d = 6: the race with VEGAS+ (on by default)
        // and, without it, the switch to the codes and the training after it decide alike on
        // every rank.
        for config in ["{}", r#"{"race_vegas": false}"#] {
            let args = [
                "integrate",
                "gauss",
                "--dim",
                "6",
                "--json",
                "--seed",
                "3",
                "--method",
                "nis",
                "--rel-err",
                "1e-2",
                "--nis-config",
                config,
            ];
            let a = to_target(&args, config);
            let sums = a["rank_checksums"].as_array().unwrap();
            assert!(sums.iter().all(|s| s == &sums[0]), "{config}: {sums:?}");
        }
        // Through channels, split by sign where the pilot sees both, and NIS with one flow
        // shared by the channels (its training reduces counts and gradients over the ranks) and
        // learned channel weights (every rank fits the same network on the same points), with a
        // flow per channel, and without the network: one result per seed.
        let cases = [
            ("dalitz", "vegas", None),
            ("gauss-pm", "uniform", None),
            ("dalitz", "nis", None),
            ("dalitz", "nis", Some("--flow-per-channel")),
            ("dalitz", "nis", Some("--no-weight-network")),
        ];
        for (name, method, extra) in cases {
            let mut args = vec![
                "integrate",
                name,
                "--channels",
                "--json",
                "--seed",
                "3",
                "--method",
                method,
                "--evals",
                "100000",
            ];
            args.extend(extra);
            let a = run_json(ranks, &args);
            assert!(pull(&a).abs() < 5.0, "{name}, {ranks} ranks: {a}");
            assert_eq!(a, run_json(ranks, &args), "{name}, {ranks} ranks, two runs");
        }
        // Through channels to a target with a time limit: every rank sizes the adaptation
        // from the slowest rank's measured cost (a rank deciding otherwise would hang the run).
        for method in ["nis", "uniform"] {
            let args = [
                "integrate",
                "dalitz",
                "--channels",
                "--json",
                "--seed",
                "3",
                "--method",
                method,
                "--rel-err",
                "1e-2",
                "--seconds",
                "60",
            ];
            to_target(&args, method);
        }
    }
}

#[test]
#[ignore = "needs MPI: scripts/test/test-mpi.sh"]
fn a_time_budget_ends_on_every_rank_after_the_same_passes() {
    // Rank 0 sizes each rendering pass from its clock and tells the others, so that every rank
    // traces the same samples and all stop after the same pass.
    for (ranks, guide) in [(2, "none"), (3, "none"), (2, "nis-kl")] {
        let out = tmp(&format!("timed-{ranks}-{guide}.exr"));
        let args = [
            "render",
            "cornell-box",
            "--seconds",
            "1",
            "--res",
            "24",
            "--guide",
            guide,
            "--out",
        ];
        let mut c = mpirun(ranks, &env_path("NIS_MPI_BIN"), &args);
        let mut child = c
            .arg(&out)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("mpirun runs");
        let what = format!("a 1 s render on {ranks} ranks, {guide},");
        let status = wait_within(&mut child, Instant::now(), Duration::from_secs(60), &what);
        let (mut stdout, mut stderr) = (String::new(), String::new());
        std::io::Read::read_to_string(&mut child.stdout.take().unwrap(), &mut stdout).unwrap();
        std::io::Read::read_to_string(&mut child.stderr.take().unwrap(), &mut stderr).unwrap();
        assert!(status.success(), "{ranks} ranks, {guide}: {stdout}{stderr}");
        let spp: u32 = stdout
            .split(" spp in ")
            .next()
            .and_then(|s| s.rsplit(' ').next())
            .and_then(|s| s.parse().ok())
            .unwrap_or_else(|| panic!("no sample count in: {stdout}"));
        assert!(spp > 1 && out.exists(), "{ranks} ranks, {guide}: {spp} spp");
    }
}
