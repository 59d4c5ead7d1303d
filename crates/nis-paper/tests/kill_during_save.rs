//! Runs killed with SIGKILL at random instants while they save: every file is afterwards the
//! previous intact version or the new intact one (it loads), never a truncated one; the strays
//! the kills leave are gone after the next run; and density training resumed after a kill ends
//! with exactly the parameters of an uninterrupted run.
//!
//! The writer is this test binary itself, re-run as a child with `NIS_KILL_CHILD` set: its
//! `child_process` test then saves in a loop (or trains) instead of returning at once.

#![cfg(unix)]

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use nis::integrate::unweight::{SampleFormat, SampleWriter};
use nis::{Density, Flow, FlowConfig, TransformKind};
use nis_paper::data::{Dataset, Images};
use nis_paper::density::{Arch, DensityConfig, ModelConfig, Session};
use nis_render::film::Image;
use nis_render::geometry::Rgb;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

const CHILD: &str = "NIS_KILL_CHILD";
const DIR: &str = "NIS_KILL_DIR";
/// Image side and sample count: files of ~1 MB, so that a save takes long enough to be hit.
const SIDE: u32 = 256;
const SAMPLES: u64 = 20_000;
const EPOCHS: usize = 8;
/// Kills of the file writers.
const KILLS: usize = 30;

/// The child's side: saves every kind of file in a loop (`files`), or trains (`train`). In a
/// normal test run (no `NIS_KILL_CHILD`) it returns at once.
#[test]
fn child_process() {
    let Ok(mode) = std::env::var(CHILD) else {
        return;
    };
    let dir = PathBuf::from(std::env::var(DIR).unwrap());
    match mode.as_str() {
        "files" => loop {
            save_all(&dir, version(&dir) + 1);
        },
        "files-once" => save_all(&dir, version(&dir) + 1),
        "train" => train(&dir),
        other => panic!("unknown child mode {other}"),
    }
}

/// The version the files on disk have reached (the JSON file is written last).
fn version(dir: &Path) -> u64 {
    std::fs::read(dir.join("v.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| v["version"].as_u64())
        .unwrap_or(0)
}

fn flow() -> Flow {
    Flow::new(FlowConfig {
        transform: TransformKind::Quadratic { bins: 16 },
        hidden_width: 256,
        ..FlowConfig::new(4)
    })
    .unwrap()
}

/// Every writer once, each file carrying `v`.
fn save_all(dir: &Path, v: u64) {
    let mut f = flow();
    f.params_mut().iter_mut().for_each(|p| *p = v as f32);
    let meta = HashMap::from([("version".to_string(), v.to_string())]);
    nis::io::save_with(&f, &dir.join("model.safetensors"), &meta).unwrap();
    let mut img = Image::new(SIDE, SIDE);
    img.pixels.fill(Rgb::new(v as f32, 0.5, 0.25));
    img.write(&dir.join("image.exr")).unwrap();
    img.write(&dir.join("image.png")).unwrap();
    let path = dir.join("samples.csv");
    let mut out = SampleWriter::create(&path, SampleFormat::Csv, 3, SAMPLES).unwrap();
    for i in 0..SAMPLES {
        out.push(&[i as f64 / SAMPLES as f64, 0.5, 0.25], v as f64)
            .unwrap();
    }
    out.finish().unwrap();
    let json = serde_json::json!({ "version": v, "pad": vec![v; 100_000] });
    nis_paper::report::write_file(&dir.join("v.json"), json.to_string().as_bytes()).unwrap();
}

/// Checks every file that exists: it loads, and says one version `>= at_least`. Returns the
/// versions it found.
fn check_files(dir: &Path, at_least: u64) -> Vec<u64> {
    let mut found = Vec::new();
    let model = dir.join("model.safetensors");
    if model.exists() {
        let (f, meta) = nis::io::load_with(&model).expect("an intact model");
        let v: u64 = meta["version"].parse().unwrap();
        assert!(f.params().iter().all(|p| *p == v as f32));
        found.push(v);
    }
    let exr = dir.join("image.exr");
    if exr.exists() {
        let img = Image::read_exr(&exr).expect("an intact EXR");
        assert_eq!(img.pixels.len(), (SIDE * SIDE) as usize);
        let v = img.pixels[0].x;
        assert!(img.pixels.iter().all(|p| *p == Rgb::new(v, 0.5, 0.25)));
        found.push(v as u64);
    }
    let png = dir.join("image.png");
    if png.exists() {
        let img = image::open(&png).expect("an intact PNG").to_rgb8();
        assert_eq!(img.dimensions(), (SIDE, SIDE));
    }
    let csv = dir.join("samples.csv");
    if csv.exists() {
        let text = std::fs::read_to_string(&csv).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len() as u64, SAMPLES + 1, "a complete sample file");
        assert!(text.ends_with('\n'));
        let v: f64 = lines[1].rsplit(',').next().unwrap().parse().unwrap();
        assert!(lines[1..]
            .iter()
            .all(|l| l.rsplit(',').next().unwrap().parse::<f64>().unwrap() == v));
        found.push(v as u64);
    }
    let json = dir.join("v.json");
    if json.exists() {
        let value: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&json).unwrap()).expect("intact JSON");
        found.push(value["version"].as_u64().unwrap());
    }
    for &v in &found {
        assert!(v >= at_least, "version {v} went back below {at_least}");
    }
    found
}

fn temps(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.ends_with(".tmp"))
        .collect()
}

fn spawn(mode: &str, dir: &Path) -> Child {
    Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "child_process", "--test-threads", "1"])
        .env(CHILD, mode)
        .env(DIR, dir)
        .env("RAYON_NUM_THREADS", "1")
        .stdout(Stdio::null())
        .spawn()
        .unwrap()
}

/// Kills `child` after a random delay in `[0, max_ms)` ms and reaps it; whether it had already
/// finished on its own.
fn kill_after(mut child: Child, rng: &mut Pcg64Mcg, max_ms: u64) -> bool {
    std::thread::sleep(Duration::from_micros(rng.random_range(0..max_ms * 1000)));
    let finished = child.try_wait().unwrap().is_some();
    let _ = child.kill();
    child.wait().unwrap();
    finished
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-kill-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn files_killed_mid_save_are_old_or_new_never_truncated() {
    let dir = scratch("files");
    let mut rng = Pcg64Mcg::seed_from_u64(16);
    let (mut at_least, mut kills_with_strays) = (0, 0);
    for _ in 0..KILLS {
        kill_after(spawn("files", &dir), &mut rng, 800);
        let found = check_files(&dir, at_least);
        at_least = found.iter().copied().min().unwrap_or(0).max(at_least);
        kills_with_strays += usize::from(!temps(&dir).is_empty());
    }
    eprintln!("{kills_with_strays} of {KILLS} kills left a stray temporary file; versions reached {at_least}");
    // The kills did land inside saves (each stray is a save cut short) …
    assert!(
        kills_with_strays > 0,
        "no kill hit a save: the test is not testing"
    );
    // … and one clean run removes every stray and leaves intact files.
    let mut once = spawn("files-once", &dir);
    assert!(once.wait().unwrap().success());
    assert_eq!(temps(&dir), Vec::<String>::new());
    assert_eq!(check_files(&dir, at_least).len(), 4);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `n` random 8×8 images with 17 levels, bright on the left half (a learnable structure).
fn toy_images(n: usize, seed: u64) -> Images {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let pixels = (0..n * 64)
        .map(|i| {
            let v: u8 = rng.random_range(0..8);
            if i % 8 < 4 {
                16 - v
            } else {
                v
            }
        })
        .collect();
    Images {
        width: 8,
        height: 8,
        levels: 17,
        pixels,
    }
}

fn density_config() -> DensityConfig {
    DensityConfig {
        dataset: Dataset::Digits,
        model: ModelConfig {
            arch: Arch::Mlp,
            width: 8,
            height: 8,
            transform: TransformKind::Quadratic { bins: 4 },
            couplings: 6,
            hidden_layers: 1,
            hidden_width: 32,
            blob_bins: 4,
            scales: 1,
            features: 4,
            blocks: 1,
            seed: 1,
        },
        batch: 32,
        learning_rate: 5e-3,
        clip_norm: Some(100.0),
        seed: 2,
    }
}

/// The child's training run: resumes from the checkpoint when there is one.
fn train(dir: &Path) {
    let ckpt = dir.join("checkpoint.safetensors");
    let mut session = if ckpt.exists() {
        Session::load(&ckpt).unwrap()
    } else {
        Session::new(density_config()).unwrap()
    };
    let (train, valid) = (toy_images(600, 1), toy_images(100, 2));
    session
        .run(&train, &valid, EPOCHS, None, Some(&ckpt), &mut |_| {})
        .unwrap();
    session.write_history(&dir.join("history.json")).unwrap();
}

fn fnv(params: &[f32]) -> u64 {
    let bytes: Vec<u8> = params.iter().flat_map(|p| p.to_le_bytes()).collect();
    nis::io::fnv1a(nis::io::FNV_OFFSET, &bytes)
}

#[test]
fn density_training_resumed_after_kills_equals_an_uninterrupted_run() {
    let dir = scratch("train");
    let (train_set, valid) = (toy_images(600, 1), toy_images(100, 2));
    let mut straight = Session::new(density_config()).unwrap();
    straight
        .run(&train_set, &valid, EPOCHS, None, None, &mut |_| {})
        .unwrap();
    let want = fnv(straight.model().params());
    let mut rng = Pcg64Mcg::seed_from_u64(1616);
    let ckpt = dir.join("checkpoint.safetensors");
    let mut epochs_seen = Vec::new();
    // An epoch takes ~0.1–0.6 s here, the whole run 1–5 s: kills land before the first
    // checkpoint, between checkpoints and during saves, and each child resumes the last.
    for _ in 0..10 {
        kill_after(spawn("train", &dir), &mut rng, 2000);
        if ckpt.exists() {
            let s = Session::load(&ckpt).expect("an intact checkpoint");
            epochs_seen.push(s.epoch());
        }
    }
    eprintln!("checkpoints found after the kills were at epochs {epochs_seen:?}");
    let mut last = spawn("train", &dir);
    assert!(last.wait().unwrap().success());
    assert_eq!(temps(&dir), Vec::<String>::new());
    let resumed = Session::load(&ckpt).unwrap();
    assert_eq!(resumed.epoch(), EPOCHS);
    assert_eq!(resumed.steps(), straight.steps());
    assert_eq!(
        fnv(resumed.model().params()),
        want,
        "checkpoints after kills held epochs {epochs_seen:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
