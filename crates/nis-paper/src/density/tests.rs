//! Bits/dim of known densities, training, checkpoints and determinism of the density models.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::model::Arch;
use super::*;
use crate::data::{Dataset, Images};
use nis::transform::TransformKind;

/// `n` random w×h images with `levels` levels whose left half is bright and right half dark
/// (a learnable structure).
fn toy_images(n: usize, w: usize, h: usize, levels: usize, seed: u64) -> Images {
    use rand::Rng;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let pixels = (0..n * w * h)
        .map(|i| {
            let bright = (i % w) < w / 2;
            let v: usize = rng.random_range(0..levels / 2);
            (if bright { levels - 1 - v } else { v }) as u8
        })
        .collect();
    Images {
        width: w,
        height: h,
        levels,
        pixels,
    }
}

fn config(w: usize, h: usize, transform: TransformKind) -> DensityConfig {
    DensityConfig {
        dataset: Dataset::Digits,
        model: ModelConfig {
            arch: Arch::Mlp,
            width: w,
            height: h,
            transform,
            couplings: 4,
            hidden_layers: 1,
            hidden_width: 16,
            blob_bins: 4,
            scales: 1,
            features: 4,
            blocks: 1,
            seed: 1,
        },
        batch: 64,
        learning_rate: 5e-3,
        clip_norm: Some(100.0),
        seed: 2,
    }
}

#[test]
fn untrained_flow_scores_exactly_log2_levels() {
    for (levels, want) in [(17, 17f64.log2()), (256, 8.0)] {
        let images = toy_images(50, 4, 2, levels, 3);
        for t in [TransformKind::Affine, TransformKind::Quadratic { bins: 4 }] {
            let mut c = config(4, 2, t);
            c.model.couplings = 0;
            let s = Session::new(c).unwrap();
            let bpd = s.evaluate(&images).unwrap();
            assert!((bpd - want).abs() < 1e-6, "{bpd} vs {want}");
        }
    }
    assert!((bits_per_dim(0.0, 64, 17) - 4.087_462_841_250_339).abs() < 1e-12);
    // A density q = 2 on the dequantised points saves exactly one bit per image: 1/D per dim.
    assert!((bits_per_dim(-2f64.ln(), 4, 256) - (8.0 - 0.25)).abs() < 1e-12);
}

#[test]
fn dequantised_points_stay_in_their_cells() {
    let images = toy_images(20, 3, 3, 17, 4);
    let idx: Vec<usize> = (0..20).collect();
    let y = dequantize(&images, &idx, &mut Pcg64Mcg::seed_from_u64(0));
    for (v, &x) in y.iter().zip(&images.pixels) {
        assert!((0.0..=1.0).contains(v));
        assert_eq!(((*v * 17.0) as u8).min(16), x);
    }
}

#[test]
fn training_lowers_bits_per_dim_on_both_couplings() {
    let train = toy_images(400, 4, 4, 17, 5);
    let valid = toy_images(100, 4, 4, 17, 6);
    for t in [TransformKind::Affine, TransformKind::Quadratic { bins: 4 }] {
        let mut s = Session::new(config(4, 4, t)).unwrap();
        let before = s.evaluate(&valid).unwrap();
        s.run(&train, &valid, 8, None, None, &mut |_| {}).unwrap();
        let after = s.history().last().unwrap().valid_bpd;
        // The data use half the levels per pixel: one bit per dimension is there to learn.
        assert!(after < before - 0.5, "{t:?}: {before} → {after}");
    }
}

#[test]
fn resume_from_checkpoint_continues_exactly() {
    let dir = std::env::temp_dir().join(format!("nis-density-ckpt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ckpt.safetensors");
    let train = toy_images(200, 4, 4, 17, 7);
    let valid = toy_images(50, 4, 4, 17, 8);
    let c = config(4, 4, TransformKind::Quadratic { bins: 4 });
    let mut straight = Session::new(c.clone()).unwrap();
    straight
        .run(&train, &valid, 3, None, None, &mut |_| {})
        .unwrap();
    let mut first = Session::new(c).unwrap();
    first
        .run(&train, &valid, 2, None, Some(&path), &mut |_| {})
        .unwrap();
    let mut resumed = Session::load(&path).unwrap();
    assert_eq!(resumed.epoch(), 2);
    assert_eq!(resumed.steps(), first.steps());
    resumed
        .run(&train, &valid, 3, None, Some(&path), &mut |_| {})
        .unwrap();
    assert_eq!(resumed.model().params(), straight.model().params());
    assert_eq!(resumed.history().len(), 3);
    // A damaged checkpoint is an error, not a model.
    let mut bytes = std::fs::read(&path).unwrap();
    let last = bytes.len() - 5;
    bytes[last] ^= 1;
    std::fs::write(&path, &bytes).unwrap();
    assert!(Session::load(&path)
        .err()
        .expect("a damaged checkpoint")
        .to_string()
        .contains("checksum"));
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    assert!(Session::load(&path).is_err());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn resume_inside_an_epoch_continues_exactly() {
    // A time budget of 1 ns stops the run after exactly one step (the first step always runs,
    // and takes longer than that); the checkpoint then sits inside epoch 0.
    let dir = std::env::temp_dir().join(format!("nis-density-mid-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ckpt.safetensors");
    let train = toy_images(300, 4, 4, 17, 7);
    let valid = toy_images(50, 4, 4, 17, 8);
    let c = config(4, 4, TransformKind::Quadratic { bins: 4 });
    let mut straight = Session::new(c.clone()).unwrap();
    straight
        .run(&train, &valid, 2, None, None, &mut |_| {})
        .unwrap();
    let mut first = Session::new(c).unwrap();
    first
        .run(&train, &valid, 2, Some(1e-9), Some(&path), &mut |_| {})
        .unwrap();
    assert_eq!((first.epoch(), first.steps()), (0, 1));
    let mut resumed = Session::load(&path).unwrap();
    assert_eq!((resumed.epoch(), resumed.steps()), (0, 1));
    resumed
        .run(&train, &valid, 2, None, Some(&path), &mut |_| {})
        .unwrap();
    assert_eq!(resumed.steps(), straight.steps());
    assert_eq!(resumed.model().params(), straight.model().params());
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn training_is_identical_on_one_and_two_threads() {
    // Batches of 1100 rows span three parallel chunks of the flow.
    let train = toy_images(2200, 3, 2, 17, 9);
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| {
            let mut c = config(3, 2, TransformKind::Quadratic { bins: 4 });
            c.batch = 1100;
            let mut s = Session::new(c).unwrap();
            s.train_epoch(&train, None, &mut |_, _, _| {}).unwrap();
            (s.model().params().to_vec(), s.evaluate(&train).unwrap())
        })
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn samples_and_interpolation_have_the_right_shape_and_corners() {
    let train = toy_images(200, 4, 4, 17, 10);
    let mut s = Session::new(config(4, 4, TransformKind::Quadratic { bins: 4 })).unwrap();
    s.run(&train, &train, 2, None, None, &mut |_| {}).unwrap();
    let x = figure::samples(s.model(), 6, 0).unwrap();
    assert_eq!(x.len(), 6 * 16);
    let corners = cell_centres(&train, &[0, 1, 2, 3]);
    let grid = figure::interpolate(s.model(), &corners, 3).unwrap();
    assert_eq!(grid.len(), 9 * 16);
    for (k, at) in [(0, 0), (1, 2), (2, 6), (3, 8)] {
        for i in 0..16 {
            assert!((grid[at * 16 + i] - corners[k * 16 + i]).abs() < 1e-3);
        }
    }
    let png = figure::grid_png(&grid, 4, 4, 17, 3, 2).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    assert!(figure::interpolate(s.model(), &corners[..16], 3).is_err());
}
