//! `nis fit-image` end to end: a tiny run writes its three outputs, and bad input files fail
//! with a message that names the problem.

use std::path::PathBuf;
use std::process::Command;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-cli-fit-image-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn fit_image_writes_pngs_and_a_json_summary() {
    let out = scratch("ok");
    let status = Command::new(env!("CARGO_BIN_EXE_nis"))
        .args([
            "fit-image",
            "--target",
            "checkerboard",
            "--steps",
            "3",
            "--batch",
            "256",
        ])
        .args(["--resolution", "32", "--eval-every", "1", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    for png in ["density.png", "curves.png"] {
        let bytes = std::fs::read(out.join(png)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{png}");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    for key in ["final_kl", "final_rel_var", "param_count", "seconds"] {
        assert!(json.get(key).is_some(), "summary.json lacks {key}: {json}");
    }
    assert_eq!(json["curve"].as_array().unwrap().len(), 4);
    std::fs::remove_dir_all(&out).ok();
}

#[test]
fn bad_image_files_fail_with_a_clear_message() {
    let dir = scratch("bad");
    let text = dir.join("notes.png");
    std::fs::write(&text, "hello").unwrap();
    let cases = [
        (text, "not a PNG or JPEG"),
        (dir.join("missing.png"), "cannot read it"),
    ];
    for (path, expected) in cases {
        let run = Command::new(env!("CARGO_BIN_EXE_nis"))
            .arg("fit-image")
            .arg(&path)
            .args(["--steps", "1", "--out"])
            .arg(dir.join("out"))
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success());
        assert!(stderr.contains(expected), "{path:?}: {stderr}");
    }
    std::fs::remove_dir_all(&dir).ok();
}
