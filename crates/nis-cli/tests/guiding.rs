//! `nis render --guide` and `nis bench guiding` end to end at a tiny size: the benchmark
//! writes its table and montage, caches its reference, and bad settings fail clearly.

use std::path::PathBuf;
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-cli-guiding-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn nis(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_nis"))
        .args(args)
        .output()
        .unwrap()
}

#[test]
fn bench_guiding_writes_a_table_a_montage_and_a_cached_reference() {
    let dir = scratch("bench");
    let docs = dir.join("docs/results/guiding.md");
    let img = dir.join("docs/img");
    let out = dir.join("out");
    let args = [
        "bench",
        "guiding",
        "--scene",
        "cornell-box",
        "--spp",
        "4",
        "--res",
        "8",
        "--reference-spp",
        "16",
        "--seconds",
        "0.2",
        "--curve-points",
        "2",
        "--docs",
        docs.to_str().unwrap(),
        "--img",
        img.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let o = nis(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(&docs).unwrap();
    for method in ["none", "nis-kl", "nis-chi2"] {
        assert!(
            md.contains(&format!("| cornell-box | {method} |")),
            "{method} missing from\n{md}"
        );
    }
    assert!(md.contains("](../img/guiding-cornell-box.png)"), "{md}");
    assert!(md.contains("](../img/guiding-error-time.png)"), "{md}");
    assert!(md.contains("seconds to MAPE"), "{md}");
    for png in ["guiding-cornell-box.png", "guiding-error-time.png"] {
        assert!(std::fs::read(img.join(png))
            .unwrap()
            .starts_with(b"\x89PNG"));
    }
    let reference = out.join("reference/built-in/cornell-box-8-16spp.exr");
    assert!(reference.is_file());
    // A second run reuses the reference, and a Mitsuba reference of Bitterli's `cornell-box`
    // (a published scene of the same name and size) is not taken for the built-in one's.
    std::fs::copy(
        &reference,
        out.join("reference/cornell-box-8-16spp-mitsuba.exr"),
    )
    .unwrap();
    let o = nis(&args);
    assert!(o.status.success());
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(
        log.contains("built-in/cornell-box-8-16spp.exr (nis path tracing"),
        "{log}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bench_guiding_reads_a_scene_file_over_seeds_and_prefers_a_mitsuba_reference() {
    let dir = scratch("file");
    let xml = dir.join("box/scene.xml");
    std::fs::create_dir_all(xml.parent().unwrap()).unwrap();
    let o = nis(&[
        "render",
        "cornell-box",
        "--export-xml",
        xml.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (docs, out, img) = (dir.join("R.md"), dir.join("out"), dir.join("img"));
    let args = [
        "bench",
        "guiding",
        "--scene",
        xml.to_str().unwrap(),
        "--method",
        "none",
        "--method",
        "nis-kl",
        "--spp",
        "4",
        "--res",
        "8",
        "--reference-spp",
        "16",
        "--seconds",
        "0.1",
        "--curve-points",
        "1",
        "--seeds",
        "2",
        "--docs",
        docs.to_str().unwrap(),
        "--img",
        img.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ];
    let o = nis(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(&docs).unwrap();
    // Named by its folder; two seeds give a range in every error cell.
    assert!(md.contains("| box | nis-kl | "), "{md}");
    assert!(md.contains("reference nis path tracing, 16 spp"), "{md}");
    assert!(md.contains("--seeds 2"), "{md}");
    assert!(md.contains("far off"), "{md}");
    assert!(
        md.contains("## Path guiding on published scenes: the table"),
        "{md}"
    );
    assert!(img.join("guiding-scenes-box.png").is_file());
    for seed in [0, 1] {
        assert!(out.join(format!("box-none-4spp-seed{seed}.exr")).is_file());
    }
    // A Mitsuba reference beside it is preferred, and one of another size refused.
    let ours = out.join("reference/box-8-16spp.exr");
    let theirs = out.join("reference/box-8-16spp-mitsuba.exr");
    std::fs::copy(&ours, &theirs).unwrap();
    let o = nis(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(&docs).unwrap();
    assert!(md.contains("reference Mitsuba 3, 16 spp"), "{md}");
    let o = nis(&[
        "render",
        "cornell-box",
        "--res",
        "4",
        "--spp",
        "1",
        "--out",
        theirs.to_str().unwrap(),
    ]);
    assert!(o.status.success());
    let o = nis(&args);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("is 4×4, the renders 8×8"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn bench_guiding_rejects_an_empty_curve() {
    let dir = scratch("curve");
    let o = nis(&[
        "bench",
        "guiding",
        "--curve-points",
        "0",
        "--docs",
        dir.join("R.md").to_str().unwrap(),
        "--out",
        dir.join("out").to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("curve needs"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!dir.join("R.md").exists());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn guided_render_rejects_bad_settings() {
    let dir = scratch("bad");
    let exr = dir.join("x.exr");
    let o = nis(&[
        "render",
        "cornell-box",
        "--spp",
        "2",
        "--res",
        "4",
        "--guide",
        "nis-kl",
        "--guide-config",
        "{\"batch\": 0}",
        "--out",
        exr.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(
        String::from_utf8_lossy(&o.stderr).contains("batch"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let o = nis(&[
        "render",
        "cornell-box",
        "--guide",
        "nis-kl",
        "--guide-config",
        "{\"hidden_widht\": 3}",
    ]);
    assert!(!o.status.success());
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown field"));
    assert!(!exr.exists());
    std::fs::remove_dir_all(&dir).ok();
}
