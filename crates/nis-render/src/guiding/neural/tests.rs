//! Tests of the neural guide: the cached queries against the flow's own, the training step's
//! gradients against finite differences and in parts, the weights' average, the bounds of its
//! settings and its records' wire format.

use super::records::{PassSamples, Sample};
use super::training::StepGradients;
use super::*;
use crate::geometry::Rgb;
use crate::guiding::{PdfQuery, SampleQuery};
use nis::flow::{Bijection, Density};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// A guide whose networks have random weights everywhere (a new one is uniform), and
/// vertices, directions and random numbers to query it with.
fn random_guide(frame: GuideFrame) -> (NisGuide, Vec<GuideVertex>, Vec<Vec3>, Vec<Vec2>) {
    let bounds = Aabb {
        min: Vec3::new(-1.0, 0.0, -2.0),
        max: Vec3::new(1.0, 2.0, 0.5),
    };
    let config = NisGuideConfig {
        frame,
        ..NisGuideConfig::default()
    };
    let mut guide = NisGuide::new(bounds, config).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(11);
    for p in guide.flow.params_mut() {
        *p += 0.3 * (rng.random::<f32>() - 0.5);
    }
    for p in &mut guide.selection.params {
        *p += 0.3 * (rng.random::<f32>() - 0.5);
    }
    guide.refresh_context();
    guide.trained = true;
    let mut unit = || {
        let v = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
        v.normalize_or(Vec3::Z)
    };
    // More than a chunk of vertices, so rows are gathered across chunks.
    let vertices: Vec<GuideVertex> = (0..700)
        .map(|i| GuideVertex {
            p: Vec3::new(
                -1.0 + 2.0 * (i as f32 * 0.37).fract(),
                2.0 * (i as f32 * 0.61).fract(),
                -2.0 + 2.5 * (i as f32 * 0.13).fract(),
            ),
            n: unit(),
            wo: unit(),
            transmissive: i % 3 == 0,
        })
        .collect();
    let dirs = (0..1500).map(|_| unit()).collect();
    let us = (0..1500)
        .map(|_| Vec2::new(rng.random(), rng.random()))
        .collect();
    (guide, vertices, dirs, us)
}

/// The flow's own (uncached) context rows of the vertices `rows` refers to.
fn uncached_context(guide: &NisGuide, v: &[GuideVertex], rows: &[usize]) -> Vec<f32> {
    let s: Vec<_> = rows
        .iter()
        .map(|&r| guide.context_scalars(&v[r], &guide.map(&v[r])))
        .collect();
    guide.encode(&s)
}

/// A training batch of `n` records with random contexts, directions and weights.
fn random_batch(n: usize, seed: u64) -> (Vec<Sample>, Vec<f64>) {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let batch = (0..n)
        .map(|_| Sample {
            context: std::array::from_fn(|_| rng.random()),
            x: [rng.random(), rng.random()],
            f: if rng.random::<f32>() < 0.2 {
                0.0
            } else {
                rng.random::<f32>() * 3.0
            },
            pdf: 0.05 + rng.random::<f32>(),
            bsdf_pdf: 0.05 + rng.random::<f32>(),
            jacobian: 0.25 * std::f32::consts::FRAC_1_PI,
        })
        .collect();
    let scales = (0..n).map(|_| 0.5 + rng.random::<f64>()).collect();
    (batch, scales)
}

#[test]
fn a_step_in_parts_has_the_whole_batch_gradients() {
    let (guide, ..) = random_guide(GuideFrame::World);
    let (batch, scales) = random_batch(256, 5);
    let (s_parts, g_parts) = guide.gradients(&batch, &scales, true, 64).unwrap();
    let (s_whole, g_whole) = guide.gradients(&batch, &scales, true, 256).unwrap();
    let (g_parts, g_whole) = (g_parts.unwrap(), g_whole.unwrap());
    assert!((s_parts.loss - s_whole.loss).abs() <= 1e-12 * s_whole.loss.abs());
    for (a, b) in [
        (&g_parts.flow, &g_whole.flow),
        (
            g_parts.selection.as_ref().unwrap(),
            g_whole.selection.as_ref().unwrap(),
        ),
    ] {
        // Sums of 256 f32 terms in another order: within a few roundings of the largest.
        let scale = b.iter().fold(0.0f32, |m, g| m.max(g.abs()));
        assert!(scale > 0.0);
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 1e-5 * scale, "{x} against {y}");
        }
    }
}

/// Parameter `j` of the flow (`network` 0) or of the selection network (1).
fn param(g: &mut NisGuide, network: usize, j: usize) -> &mut f32 {
    if network == 0 {
        &mut g.flow.params_mut()[j]
    } else {
        &mut g.selection.params[j]
    }
}

/// Checks the gradients `grads` of `networks` (0 the flow, 1 the selection network) against
/// central differences of `loss` at their eight steepest parameters and four at random.
fn assert_finite_differences(
    guide: &mut NisGuide,
    grads: &StepGradients,
    networks: &[usize],
    loss: &dyn Fn(&NisGuide) -> f64,
) {
    let selection = grads.selection.as_ref().unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let h = 1e-3f32;
    for &network in networks {
        let grad = if network == 0 { &grads.flow } else { selection };
        let mut order: Vec<usize> = (0..grad.len()).collect();
        order.sort_by(|&a, &b| grad[b].abs().total_cmp(&grad[a].abs()));
        order.truncate(8);
        order.extend((0..4).map(|_| rng.random_range(0..grad.len())));
        assert!(grad[order[7]].abs() > 1e-2, "too flat to test");
        for j in order {
            let x = *param(guide, network, j);
            *param(guide, network, j) = x + h;
            let up = loss(guide);
            *param(guide, network, j) = x - h;
            let down = loss(guide);
            *param(guide, network, j) = x;
            let fd = (up - down) / (2.0 * f64::from(h));
            // Central differences of an f32 network: truncation O(h²), rounding ≈ 1e-7/h.
            let g = f64::from(grad[j]);
            assert!(
                (fd - g).abs() <= 2e-3 + 0.02 * g.abs(),
                "network {network}, parameter {j}: {g} against finite differences {fd}"
            );
        }
    }
}

#[test]
fn step_gradients_are_those_of_the_kl_loss() {
    let (mut guide, ..) = random_guide(GuideFrame::World);
    guide.config.selection_chi2_share = 0.0;
    let (batch, scales) = random_batch(256, 6);
    let loss = |g: &NisGuide| g.gradients(&batch, &scales, true, 64).unwrap().0.loss;
    let grads = guide
        .gradients(&batch, &scales, true, 64)
        .unwrap()
        .1
        .unwrap();
    assert_finite_differences(&mut guide, &grads, &[0, 1], &loss);
}

/// The mean χ² weight `F²/(p_s·q_mix·scale)` of `batch` under the guide's mixture: the χ²
/// divergence up to a constant (computed here from the networks, apart from the training code).
fn chi_square_mean(g: &NisGuide, batch: &[Sample], scales: &[f64]) -> f64 {
    let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
    let context = g.encode(&scalars);
    let x: Vec<f32> = batch.iter().flat_map(|s| s.x).collect();
    let log_q = g.flow.log_density(&x, Some(&context)).unwrap();
    let (_, c) = g.selection.forward(&context);
    let total: f64 = batch
        .iter()
        .zip(&log_q)
        .zip(c.iter().zip(scales))
        .map(|((s, l), (&c, scale))| {
            let q = l.exp() * f64::from(s.jacobian);
            let q_mix = f64::from(c) * q + (1.0 - f64::from(c)) * f64::from(s.bsdf_pdf);
            f64::from(s.f).powi(2) / (f64::from(s.pdf) * q_mix * scale)
        })
        .sum();
    total / batch.len() as f64
}

#[test]
fn the_selection_learns_from_kl_and_a_share_of_chi_square() {
    // With share λ the selection network descends (1 − λ)·(KL / mean KL weight) + λ·ln χ²
    // (the χ² gradient divided by the χ² itself); the flow keeps the KL gradient alone.
    let (mut guide, ..) = random_guide(GuideFrame::World);
    let share = 0.2;
    guide.config.selection_chi2_share = share;
    let (batch, scales) = random_batch(256, 6);
    let kl = |g: &NisGuide| g.gradients(&batch, &scales, true, 64).unwrap().0.loss;
    let blend = |g: &NisGuide| {
        (1.0 - share as f64) * kl(g) + share as f64 * chi_square_mean(g, &batch, &scales).ln()
    };
    let grads = guide
        .gradients(&batch, &scales, true, 64)
        .unwrap()
        .1
        .unwrap();
    assert_finite_differences(&mut guide, &grads, &[0], &kl);
    assert_finite_differences(&mut guide, &grads, &[1], &blend);
    // And the blend is not the KL gradient: the χ² share moved the selection's.
    guide.config.selection_chi2_share = 0.0;
    let plain = guide
        .gradients(&batch, &scales, true, 64)
        .unwrap()
        .1
        .unwrap();
    assert_eq!(plain.flow, grads.flow);
    let moved = plain
        .selection
        .unwrap()
        .iter()
        .zip(grads.selection.as_ref().unwrap())
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(moved > 1e-3, "{moved}");
    for bad in [-0.1, 1.5, f32::NAN] {
        let config = NisGuideConfig {
            selection_chi2_share: bad,
            ..NisGuideConfig::default()
        };
        let e = unit_box_guide(config).err().expect("rejected");
        assert!(e.to_string().contains("χ² share"), "{e}");
    }
}

/// A guide of `config` in the unit box (for the settings' checks).
fn unit_box_guide(config: NisGuideConfig) -> nis::Result<NisGuide> {
    let bounds = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    NisGuide::new(bounds, config)
}

#[test]
fn the_guide_serves_a_positive_number_of_bounces_or_all() {
    let guide = |guided_bounces| {
        unit_box_guide(NisGuideConfig {
            guided_bounces,
            ..NisGuideConfig::default()
        })
    };
    assert_eq!(guide(1).unwrap().guided_bounces(), 1);
    assert_eq!(guide(4).unwrap().guided_bounces(), 4);
    assert_eq!(guide(-1).unwrap().guided_bounces(), u32::MAX);
    for bad in [0, -2, i32::MIN] {
        let e = guide(bad).err().expect("rejected");
        assert!(e.to_string().contains("bounce"), "{e}");
    }
}

#[test]
fn cached_queries_match_the_uncached_flow() {
    for frame in [GuideFrame::World, GuideFrame::Local] {
        cached_queries_match_the_uncached_flow_in(frame);
    }
}

fn cached_queries_match_the_uncached_flow_in(frame: GuideFrame) {
    // f32 rounding: the first layers' sums run in another order (≈ 1e-6 relative per
    // activation); through two conditioners and the splines' exponentials the density
    // moves by far less than 1e-4 relative, the sampled point by less than 1e-5.
    let (guide, vertices, dirs, us) = random_guide(frame);
    let mut cache = ContextCache::default();
    guide.prepare(&vertices, &mut cache);
    let rows: Vec<usize> = (0..dirs.len())
        .map(|i| (i * 7919) % vertices.len())
        .collect();
    let context = uncached_context(&guide, &vertices, &rows);

    let queries: Vec<PdfQuery> = rows
        .iter()
        .zip(&dirs)
        .map(|(&vertex, &wi)| PdfQuery { vertex, wi })
        .collect();
    let mut cached = vec![0.0; queries.len()];
    guide.pdf_batch(&vertices, &cache, &queries, &mut cached);
    let maps: Vec<DirectionMap> = rows.iter().map(|&r| guide.map(&vertices[r])).collect();
    let squares: Vec<Option<Vec2>> = maps
        .iter()
        .zip(&dirs)
        .map(|(m, &w)| m.to_square(w))
        .collect();
    let x: Vec<f32> = squares
        .iter()
        .flat_map(|x| x.unwrap_or(Vec2::splat(0.5)).to_array())
        .collect();
    let log_q = guide.flow.log_density(&x, Some(&context)).unwrap();
    let (mut spread, mut below) = (0.0f64, 0);
    for (((c, l), m), x) in cached.iter().zip(&log_q).zip(&maps).zip(&squares) {
        if x.is_none() {
            // Below the surface of an opaque vertex.
            assert_eq!(*c, 0.0);
            below += 1;
            continue;
        }
        let plain = l.exp() * f64::from(m.jacobian());
        spread = spread.max((l.exp() - 1.0).abs());
        assert!((f64::from(*c) / plain - 1.0).abs() < 1e-4, "{c} vs {plain}");
    }
    // In the local frame, a third of the random directions lie below an opaque surface.
    assert_eq!(
        frame == GuideFrame::Local,
        below > 100,
        "{below} below the surface"
    );
    // The random weights must make the density far from uniform, or the test shows little.
    assert!(spread > 0.5, "density hardly varies: {spread}");

    let queries: Vec<SampleQuery> = rows
        .iter()
        .zip(&us)
        .map(|(&vertex, &u)| SampleQuery { vertex, u })
        .collect();
    let mut samples = vec![None; queries.len()];
    guide.sample_batch(&vertices, &cache, &queries, &mut samples);
    let z: Vec<f32> = us.iter().flat_map(|u| u.to_array()).collect();
    let (x, log_det) = guide.flow.inverse(&z, Some(&context)).unwrap();
    for (i, s) in samples.iter().enumerate() {
        let s = s.expect("a sample");
        let plain = maps[i].to_direction(Vec2::new(x[2 * i], x[2 * i + 1]));
        assert!((s.wi - plain).length() < 1e-4, "{:?} vs {plain:?}", s.wi);
        let pdf = (-log_det[i]).exp() * f64::from(maps[i].jacobian());
        assert!(
            (f64::from(s.pdf) / pdf - 1.0).abs() < 1e-4,
            "{} vs {pdf}",
            s.pdf
        );
    }

    let all: Vec<usize> = (0..vertices.len()).collect();
    let (_, plain) = guide
        .selection
        .forward(&uncached_context(&guide, &vertices, &all));
    let mut cached = vec![0.0; vertices.len()];
    guide.selection_probabilities(&vertices, &cache, &mut cached);
    for (c, p) in cached.iter().zip(&plain) {
        assert!((c - p).abs() < 1e-5, "{c} vs {p}");
    }
}

#[test]
fn averaging_the_weights_leaves_the_training_alone() {
    // Two guides, with and without the average, trained on the same records: the Adam
    // iterates must agree bit for bit after every phase, and the averaged guide must render
    // with other weights than its iterate.
    let sample = |i: usize| Sample {
        context: std::array::from_fn(|j| ((i * 13 + j * 5) % 17) as f32 / 17.0),
        x: [(i as f32 * 0.37).fract(), (i as f32 * 0.71).fract()],
        f: 0.1 + (i % 5) as f32,
        pdf: 1.0 / (4.0 * std::f32::consts::PI),
        bsdf_pdf: 0.1,
        jacobian: 1.0 / (4.0 * std::f32::consts::PI),
    };
    let bounds = Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    };
    let config = |average_span| NisGuideConfig {
        batch: 64,
        buffer: 1024,
        min_steps: 6,
        max_steps: 6,
        selection_warmup: 0,
        average_span,
        ..NisGuideConfig::default()
    };
    let mut plain = NisGuide::new(bounds, config(0.0)).unwrap();
    let mut averaged = NisGuide::new(bounds, config(0.5)).unwrap();
    for phase in 0..2 {
        for guide in [&mut plain, &mut averaged] {
            guide.update(PassSamples {
                samples: (phase * 300..phase * 300 + 300).map(sample).collect(),
                seen: 300,
                cap: None,
            });
        }
        let a = averaged.average.as_ref().unwrap();
        assert_eq!(a.steps(), 6 * (phase as i32 + 1));
        let iterate = [plain.flow.params(), &plain.selection.params].concat();
        assert_eq!(a.iterate(), &iterate[..]);
        assert_ne!(averaged.flow.params(), plain.flow.params());
        assert_ne!(averaged.selection.params, plain.selection.params);
    }
}

#[test]
fn pass_samples_cross_processes_whole() {
    // What ranks send each other: the cap, the count of records seen (beyond f32's 2^24)
    // and the kept records, bit for bit; no cap stays no cap, and a cap of 0 stays one.
    let sample = |i: usize| Sample {
        context: std::array::from_fn(|j| (i * 31 + j) as f32 * 0.37 - 5.0),
        x: [i as f32 * 0.1, -0.25],
        f: 1.5e-7 * i as f32,
        pdf: 0.3,
        bsdf_pdf: f32::MIN_POSITIVE,
        jacobian: 0.125,
    };
    let bits = |s: &Sample| {
        let mut w = s.context.to_vec();
        w.extend([s.x[0], s.x[1], s.f, s.pdf, s.bsdf_pdf, s.jacobian]);
        w.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
    };
    for cap in [None, Some(0), Some(3), Some(1 << 40)] {
        let pass = PassSamples {
            samples: (0..3).map(sample).collect(),
            seen: (1 << 33) + 12_345,
            cap,
        };
        let back: PassSamples =
            crate::guiding::from_bytes(&crate::guiding::to_bytes(&pass)).unwrap();
        assert_eq!((back.seen, back.cap), (pass.seen, pass.cap));
        assert_eq!(back.samples.len(), 3);
        for (a, b) in pass.samples.iter().zip(&back.samples) {
            assert_eq!(bits(a), bits(b));
        }
    }
    let empty: PassSamples =
        crate::guiding::from_bytes(&crate::guiding::to_bytes(&PassSamples::default())).unwrap();
    assert_eq!((empty.seen, empty.cap, empty.samples.len()), (0, None, 0));
}

#[test]
fn the_guide_leaves_lobes_narrower_than_its_setting_and_rejects_bad_ones() {
    let guide = |narrowest_lobe_degrees| {
        unit_box_guide(NisGuideConfig {
            narrowest_lobe_degrees,
            ..NisGuideConfig::default()
        })
    };
    let default = unit_box_guide(NisGuideConfig::default()).unwrap();
    assert_eq!(
        default.narrowest_lobe(),
        crate::guiding::NARROWEST_LOBE_DEGREES.to_radians()
    );
    assert_eq!(guide(0.0).unwrap().narrowest_lobe(), 0.0);
    assert!((guide(90.0).unwrap().narrowest_lobe() - std::f32::consts::FRAC_PI_2).abs() < 1e-6);
    for bad in [-1.0, 90.5, f32::NAN, f32::INFINITY] {
        let e = guide(bad).err().expect("rejected");
        assert!(e.to_string().contains("narrowest lobe"), "{e}");
    }
}

#[test]
fn records_weigh_in_by_their_paths_throughput_when_set() {
    // Two records alike but for the throughput their paths arrived with: their `F` differ by
    // its factor, unless the guide weighs by `F` alone; a path that brings nothing is dropped.
    let record = |throughput| GuideRecord {
        vertex: GuideVertex {
            p: Vec3::splat(0.5),
            n: Vec3::Z,
            wo: Vec3::Z,
            transmissive: false,
        },
        wi: Vec3::new(0.0, 0.6, 0.8),
        pdf: 0.4,
        bsdf_pdf: 0.2,
        bsdf_cos: Rgb::splat(0.3),
        radiance: Rgb::new(1.0, 2.0, 3.0),
        throughput,
    };
    let records = [record(1.0), record(0.25), record(0.0)];
    let f_of = |weight_by_throughput| {
        let guide = unit_box_guide(NisGuideConfig {
            weight_by_throughput,
            ..NisGuideConfig::default()
        })
        .unwrap();
        let mut pass = PassSamples::default();
        guide.accumulate(&records, &mut pass);
        pass.samples.iter().map(|s| s.f).collect::<Vec<_>>()
    };
    let f = luminance(Rgb::new(1.0, 2.0, 3.0) * 0.3);
    let weighted = f_of(true);
    assert_eq!(weighted.len(), 2);
    assert!((weighted[0] - f).abs() <= 1e-6 * f && (weighted[1] - 0.25 * f).abs() <= 1e-6 * f);
    assert_eq!(f_of(false), vec![weighted[0]; 3]);
}
