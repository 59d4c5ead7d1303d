//! The density-estimation workflow on the real image sets in `data/`, fetched by
//! `scripts/setup/fetch-data.sh` (`scripts/test.sh` and CI run it before the tests). Without the files
//! these tests are skipped and say so on stderr ("skipped: data/… absent"; libtest has no skipped
//! state, so they count as passed); with `NIS_REQUIRE_DATA=1`, as `scripts/test.sh` sets it, a
//! missing file fails them instead.

use std::io::Write;
use std::path::{Path, PathBuf};

use nis::TransformKind;
use nis_paper::data::Dataset;
use nis_paper::density::{Arch, DensityConfig, Session};

/// `data/` when `file` is in it; `None` (the test is skipped) when it is not, unless
/// `NIS_REQUIRE_DATA=1`, which makes a missing file a failure.
fn data_dir(test: &str, file: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data");
    if dir.join(file).exists() {
        return Some(dir);
    }
    let required = std::env::var_os("NIS_REQUIRE_DATA").is_some_and(|v| v == "1");
    assert!(
        !required,
        "data/{file} absent and NIS_REQUIRE_DATA=1: run scripts/setup/fetch-data.sh"
    );
    // Straight to stderr, not through `eprintln!`, which the test harness captures and hides for
    // a passing test: the skip must show in `cargo test`'s output.
    let _ = writeln!(
        std::io::stderr(),
        "{test}: skipped: data/{file} absent, run scripts/setup/fetch-data.sh"
    );
    None
}

#[test]
fn real_digits_train_below_the_uniform_bits_per_dim_with_both_architectures() {
    let Some(dir) = data_dir("real_digits", "digits.csv.gz") else {
        return;
    };
    let (train, valid) = Dataset::Digits.load_split(&dir).unwrap();
    assert_eq!((train.len(), valid.len()), (1497, 300));
    assert_eq!((train.width, train.height, train.levels), (8, 8, 17));
    assert_eq!(train.pixels.iter().max(), Some(&16));
    for arch in [Arch::Mlp, Arch::MultiScale] {
        let mut c =
            DensityConfig::defaults(Dataset::Digits, arch, TransformKind::Quadratic { bins: 4 });
        c.model.hidden_width = 16;
        c.model.features = 8;
        c.model.blocks = 1;
        let mut s = Session::new(c).unwrap();
        let before = s.evaluate(&valid).unwrap();
        assert!((before - 17f64.log2()).abs() < 1e-6, "{arch:?}: {before}");
        s.run(&train, &valid, 1, None, None, &mut |_| {}).unwrap();
        let after = s.history()[0].valid_bpd;
        assert!(after < before - 0.5, "{arch:?}: {before} → {after}");
    }
}

#[test]
fn real_mnist_json_loads_ten_thousand_eight_bit_images() {
    let Some(dir) = data_dir("real_mnist", "mnist/9.json") else {
        return;
    };
    let (train, valid) = Dataset::Mnist.load_split(&dir).unwrap();
    assert_eq!((train.len(), valid.len()), (8000, 2000));
    assert_eq!((train.width, train.height, train.levels), (28, 28, 256));
    assert_eq!(train.pixels.iter().max(), Some(&255));
}
