use std::io::Write;
use std::path::PathBuf;

use super::*;

/// A fresh directory for one test's files.
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("nis-data-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut e = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    e.write_all(bytes).unwrap();
    e.finish().unwrap()
}

fn digits_line(seed: usize) -> String {
    let mut f: Vec<String> = (0..64).map(|k| ((k * 7 + seed) % 17).to_string()).collect();
    f.push((seed % 10).to_string());
    f.join(",")
}

fn data_error(e: Error) -> String {
    match e {
        Error::Data { reason, .. } => reason,
        other => panic!("expected a data error, got {other}"),
    }
}

#[test]
fn digits_csv_reads_gzipped_and_plain_files() {
    let dir = scratch("digits");
    let text = format!("{}\n{}\n", digits_line(0), digits_line(3));
    std::fs::write(dir.join("d.csv.gz"), gzip(text.as_bytes())).unwrap();
    std::fs::write(dir.join("d.csv"), &text).unwrap();
    for name in ["d.csv.gz", "d.csv"] {
        let im = read_digits_csv(&dir.join(name)).unwrap();
        assert_eq!((im.len(), im.width, im.height, im.levels), (2, 8, 8, 17));
        assert_eq!(im.image(1)[3], ((3 * 7 + 3) % 17) as u8);
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn digits_csv_truncated_or_malformed_is_a_clear_error() {
    let dir = scratch("digits-bad");
    let good = gzip(format!("{}\n{}\n", digits_line(0), digits_line(1)).as_bytes());
    let p = dir.join("cut.csv.gz");
    std::fs::write(&p, &good[..good.len() - 10]).unwrap();
    assert!(data_error(read_digits_csv(&p).unwrap_err()).contains("gzip"));
    let short = digits_line(0).rsplit_once(',').unwrap().0.to_string();
    for (text, want) in [
        (short, "65"),
        (digits_line(0).replacen('0', "17", 1), "0..=16"),
        (digits_line(0).replacen('0', "x", 1), "no number"),
        (String::new(), "no images"),
    ] {
        std::fs::write(&p, gzip(text.as_bytes())).unwrap();
        let reason = data_error(read_digits_csv(&p).unwrap_err());
        assert!(reason.contains(want), "{reason}");
    }
    let missing = read_digits_csv(&dir.join("nope.csv.gz")).unwrap_err();
    assert!(matches!(missing, Error::MissingData { .. }));
    assert!(missing.to_string().contains("scripts/setup/fetch-data.sh"));
    std::fs::remove_dir_all(&dir).ok();
}

fn write_mnist_json(dir: &std::path::Path, per_class: usize) {
    for c in 0..10 {
        let v: Vec<String> = (0..per_class * 784)
            .map(|i| format!("{:.3}", ((i + c) % 256) as f64 / 255.0))
            .collect();
        std::fs::write(
            dir.join(format!("{c}.json")),
            format!("{{ \"data\": [{}] }}", v.join(",")),
        )
        .unwrap();
    }
}

#[test]
fn mnist_json_recovers_the_eight_bit_values() {
    let dir = scratch("mnist-json");
    write_mnist_json(&dir, 1);
    let im = read_mnist_json(&dir).unwrap();
    assert_eq!((im.len(), im.width, im.levels), (10, 28, 256));
    for c in 0..10 {
        for i in 0..784 {
            assert_eq!(im.image(c)[i] as usize, (i + c) % 256);
        }
    }
    // Malformed: a partial image, a value outside [0, 1], broken JSON, a missing class.
    let out_of_range = format!("{{\"data\": [2.0{}]}}", ",0".repeat(783));
    for (text, want) in [
        ("{\"data\": [0.5, 0.25]}", "28×28"),
        (out_of_range.as_str(), "outside"),
        ("{\"data\": [0.5, ", "JSON"),
    ] {
        std::fs::write(dir.join("3.json"), text).unwrap();
        let reason = data_error(read_mnist_json(&dir).unwrap_err());
        assert!(reason.contains(want), "{reason}");
    }
    std::fs::remove_file(dir.join("3.json")).unwrap();
    assert!(matches!(
        read_mnist_json(&dir).unwrap_err(),
        Error::MissingData { .. }
    ));
    std::fs::remove_dir_all(&dir).ok();
}

fn idx_bytes(n: u32, rows: u32, cols: u32) -> Vec<u8> {
    let mut b = vec![0, 0, 8, 3];
    for v in [n, rows, cols] {
        b.extend(v.to_be_bytes());
    }
    b.extend((0..n * rows * cols).map(|i| (i % 251) as u8));
    b
}

#[test]
fn idx_reads_raw_and_gzipped_and_rejects_damage() {
    let dir = scratch("idx");
    let bytes = idx_bytes(3, 4, 5);
    std::fs::write(dir.join("a-idx3-ubyte"), &bytes).unwrap();
    std::fs::write(dir.join("a-idx3-ubyte.gz"), gzip(&bytes)).unwrap();
    for name in ["a-idx3-ubyte", "a-idx3-ubyte.gz"] {
        let im = read_idx_images(&dir.join(name)).unwrap();
        assert_eq!((im.len(), im.width, im.height, im.levels), (3, 5, 4, 256));
        assert_eq!(im.image(2)[0], 40);
    }
    let p = dir.join("bad");
    let mut wrong_magic = bytes.clone();
    wrong_magic[3] = 1;
    for (b, want) in [
        (bytes[..bytes.len() - 1].to_vec(), "truncated"),
        (bytes[..10].to_vec(), "header"),
        (wrong_magic, "magic"),
        ([bytes.clone(), vec![0]].concat(), "promises"),
    ] {
        std::fs::write(&p, b).unwrap();
        let reason = data_error(read_idx_images(&p).unwrap_err());
        assert!(reason.contains(want), "{reason}");
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn split_is_fixed_disjoint_and_complete() {
    let im = Images {
        width: 1,
        height: 1,
        levels: 256,
        pixels: (0..=99).collect(),
    };
    let (a, b) = im.split(0.2, 0).unwrap();
    let (a2, b2) = im.split(0.2, 0).unwrap();
    assert_eq!((a.len(), b.len()), (80, 20));
    assert_eq!((&a, &b), (&a2, &b2));
    let mut all: Vec<u8> = a.pixels.iter().chain(&b.pixels).copied().collect();
    all.sort();
    assert_eq!(all, im.pixels);
}

#[test]
fn mnist_prefers_the_full_idx_file_and_names_missing_files() {
    let dir = scratch("mnist-idx");
    let err = Dataset::Mnist.load(&dir).unwrap_err();
    assert!(matches!(err, Error::MissingData { .. }), "{err}");
    std::fs::write(
        dir.join("train-images-idx3-ubyte.gz"),
        gzip(&idx_bytes(3, 28, 28)),
    )
    .unwrap();
    let im = Dataset::Mnist.load(&dir).unwrap();
    assert_eq!((im.len(), im.width, im.height, im.levels), (3, 28, 28, 256));
    assert!("mnist".parse::<Dataset>().is_ok() && "cifar".parse::<Dataset>().is_err());
    std::fs::remove_dir_all(&dir).ok();
}
