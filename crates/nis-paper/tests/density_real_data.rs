//! The density-estimation workflow on the real image sets in `data/`, fetched by
//! `scripts/fetch-data.sh` (CI runs it before the tests; without the files these tests say so and
//! pass, since the loaders are covered by unit tests on files they make themselves).

use std::path::{Path, PathBuf};

use nis::TransformKind;
use nis_paper::data::Dataset;
use nis_paper::density::{Arch, DensityConfig, Session};

fn data_dir(file: &str) -> Option<PathBuf> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data");
    if dir.join(file).exists() {
        Some(dir)
    } else {
        eprintln!("data/{file} absent: run scripts/fetch-data.sh");
        None
    }
}

#[test]
fn real_digits_train_below_the_uniform_bits_per_dim_with_both_architectures() {
    let Some(dir) = data_dir("digits.csv.gz") else {
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
    let Some(dir) = data_dir("mnist/9.json") else {
        return;
    };
    let (train, valid) = Dataset::Mnist.load_split(&dir).unwrap();
    assert_eq!((train.len(), valid.len()), (8000, 2000));
    assert_eq!((train.width, train.height, train.levels), (28, 28, 256));
    assert_eq!(train.pixels.iter().max(), Some(&255));
}
