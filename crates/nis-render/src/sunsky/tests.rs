//! The sun and sky: sampling against its density and its radiance on a made-up table (no
//! data files needed), and the radiance against Mitsuba 3.9.1's on its own tables (skipped,
//! with a message, when they have not been fetched).

use glam::{Mat3, Vec2, Vec3};

use super::dataset::{
    Dataset, ALBEDOS, IRRADIANCE_ELEVATIONS, SKY_CONTROL_POINTS, SUN_CONTROL_POINTS,
    SUN_LIMB_PARAMS, SUN_SEGMENTS, TURBIDITIES, WAVELENGTHS,
};
use super::*;
use crate::geometry::luminance;
use crate::sampling::square_to_uniform_sphere;

/// A made-up table: a smooth sky brighter around the sun and towards the horizon, a sun of a
/// few thousand times its radiance.
fn synthetic() -> Dataset {
    let abcdefghi = [-1.0, -0.3, 1.0, 5.0, -8.0, 0.3, 0.1, 0.5, 0.5];
    let sky_params = (0..TURBIDITIES * ALBEDOS * SKY_CONTROL_POINTS * 3)
        .flat_map(|i| abcdefghi.map(|v| v * (1.0 + 0.01 * (i % 7) as f64)))
        .collect();
    let sky_radiance = (0..TURBIDITIES * ALBEDOS * SKY_CONTROL_POINTS * 3)
        .map(|i| 8.0 + (i % 3) as f64)
        .collect();
    let per_segment = 3 * SUN_CONTROL_POINTS * SUN_LIMB_PARAMS;
    let sun_radiance = (0..TURBIDITIES * SUN_SEGMENTS * per_segment)
        .map(|i| match i % SUN_LIMB_PARAMS {
            0 => 5e4,
            1 => 4e4,
            _ => 2e3,
        })
        .collect();
    let sun_irradiance = (0..TURBIDITIES * IRRADIANCE_ELEVATIONS * WAVELENGTHS)
        .map(|i| 1.0 + 0.1 * (i % WAVELENGTHS) as f64)
        .collect();
    Dataset {
        sky_params,
        sky_radiance,
        sun_radiance,
        sun_irradiance,
        dir: Default::default(),
    }
}

fn params(complex: bool) -> SunSkyParams {
    SunSkyParams {
        turbidity: 4.5,
        albedo: Rgb::new(0.2, 0.5, 0.8),
        sun: SunPosition::Direction(Vec3::new(0.4, 0.5, 0.3)),
        sun_aperture: 6.0,
        sun_scale: 0.02,
        complex_sun: complex,
        // Z-up to y-up, turned about y.
        to_world: Mat3::from_rotation_y(0.7) * Mat3::from_rotation_x(-std::f32::consts::FRAC_PI_2),
        ..SunSkyParams::default()
    }
}

/// ∫ pdf dω over the sphere by a fine midpoint rule in (cos θ, φ) around the sun's axis (so
/// that the small cone is resolved), and ∫ L dω likewise.
fn integrals(s: &SunSky) -> (f64, f64) {
    let axis = Frame::from_normal(s.sun_direction());
    let (mut pdf, mut radiance) = (0.0f64, 0.0f64);
    // Inside the cone, then outside it.
    let bands = [(s.cos_radius, 1.0f32, 200usize), (-1.0, s.cos_radius, 2000)];
    for (lo, hi, n) in bands {
        let m = 400;
        let cell = f64::from(hi - lo) / n as f64 * std::f64::consts::TAU / m as f64;
        for i in 0..n {
            let z = lo + (hi - lo) * (i as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).max(0.0).sqrt();
            for k in 0..m {
                let phi = std::f32::consts::TAU * (k as f32 + 0.5) / m as f32;
                let d = axis.to_world(Vec3::new(r * phi.cos(), r * phi.sin(), z));
                pdf += f64::from(s.pdf(d)) * cell;
                radiance += f64::from(luminance(s.eval(d))) * cell;
            }
        }
    }
    (pdf, radiance)
}

#[test]
fn the_density_integrates_to_one_and_matches_the_samples() {
    let data = synthetic();
    for complex in [false, true] {
        let s = SunSky::new(&params(complex), &data).unwrap().unwrap();
        assert!(s.p_sun > 0.05 && s.p_sun < 0.95, "{}", s.p_sun);
        let (integral, _) = integrals(&s);
        assert!((integral - 1.0).abs() < 5e-3, "∫ pdf = {integral}");
        let mut checked = 0;
        for k in 0..4000 {
            let u = Vec2::new(
                (k as f32 + 0.5) / 4000.0,
                ((k * 617) % 4000) as f32 / 4000.0,
            );
            let Some(x) = s.sample(u) else { continue };
            // A hair from the disk's edge, rounding may move a sample across it.
            let local = s.local(x.wi);
            if (local.dot(s.sun_dir) - s.cos_radius).abs() < 1e-5 {
                continue;
            }
            let pdf = s.pdf(x.wi);
            assert!((x.pdf - pdf).abs() <= 2e-3 * pdf, "{} vs {pdf}", x.pdf);
            let l = s.eval(x.wi);
            assert!(
                (x.radiance - l).abs().max_element() <= 1e-3 * l.max_element(),
                "{} vs {l}",
                x.radiance
            );
            checked += 1;
        }
        assert!(checked > 3900, "{checked}");
    }
}

/// E[L/p] over samples is ∫ L dω by quadrature; and nothing comes from below the horizon.
#[test]
fn importance_sampled_radiance_is_unbiased() {
    let data = synthetic();
    for complex in [false, true] {
        let s = SunSky::new(&params(complex), &data).unwrap().unwrap();
        let (_, quad) = integrals(&s);
        let (mut est, k) = (0.0f64, 400);
        for a in 0..k {
            for b in 0..k {
                let u = Vec2::new((a as f32 + 0.5) / k as f32, (b as f32 + 0.5) / k as f32);
                if let Some(x) = s.sample(u) {
                    est += f64::from(luminance(x.radiance) / x.pdf);
                    assert!(s.local(x.wi).z >= 0.0);
                }
            }
        }
        let est = est / (k * k) as f64;
        assert!(
            (est - quad).abs() < 5e-3 * quad,
            "complex {complex}: {est} vs {quad}"
        );
        for i in 0..100 {
            let d = square_to_uniform_sphere(Vec2::new((i as f32 + 0.5) / 100.0, 0.37));
            if s.local(d).z < 0.0 {
                assert_eq!(s.eval(d), Rgb::ZERO);
            }
        }
    }
}

/// The sun's irradiance does not change with its aperture (Mitsuba's area ratio), and the
/// limb-darkened sun is brightest at its centre.
#[test]
fn the_suns_power_keeps_with_its_aperture() {
    let data = synthetic();
    let sun_only = |aperture: f32, complex: bool| {
        let p = SunSkyParams {
            sky_scale: 0.0,
            sun_aperture: aperture,
            ..params(complex)
        };
        let s = SunSky::new(&p, &data).unwrap().unwrap();
        assert_eq!(s.p_sun, 1.0);
        let (mut e, k) = (0.0f64, 200);
        for a in 0..k {
            for b in 0..k {
                let u = Vec2::new((a as f32 + 0.5) / k as f32, (b as f32 + 0.5) / k as f32);
                let x = s.sample(u).unwrap();
                e += f64::from(luminance(x.radiance) / x.pdf);
            }
        }
        e / (k * k) as f64
    };
    let (a, b) = (sun_only(0.5358, false), sun_only(3.0, false));
    assert!((a / b - 1.0).abs() < 1e-3, "{a} vs {b}");
    let s = SunSky::new(&params(true), &data).unwrap().unwrap();
    let centre = s.sun_direction();
    let edge = (s.to_world * (s.sun_frame.to_world(Vec3::new(0.05, 0.0, 1.0)))).normalize();
    assert!(luminance(s.eval(centre)) > luminance(s.eval(edge)));
}

#[test]
fn bad_parameters_are_refused_and_a_set_sun_is_dark() {
    let data = synthetic();
    for p in [
        SunSkyParams {
            turbidity: 0.5,
            ..Default::default()
        },
        SunSkyParams {
            albedo: Rgb::new(0.1, 1.2, 0.1),
            ..Default::default()
        },
        SunSkyParams {
            sun_scale: -1.0,
            ..Default::default()
        },
        SunSkyParams {
            sun_aperture: 0.0,
            ..Default::default()
        },
        SunSkyParams {
            sun: SunPosition::Direction(Vec3::ZERO),
            ..Default::default()
        },
        SunSkyParams {
            to_world: Mat3::from_diagonal(Vec3::new(1.0, 2.0, 1.0)),
            ..Default::default()
        },
    ] {
        assert!(SunSky::new(&p, &data).is_err(), "{p:?}");
    }
    let night = SunSkyParams {
        sun: SunPosition::Direction(Vec3::new(0.0, 0.3, -1.0)),
        ..Default::default()
    };
    assert!(SunSky::new(&night, &data).unwrap().is_none());
    let off = SunSkyParams {
        sun_scale: 0.0,
        sky_scale: 0.0,
        ..Default::default()
    };
    assert!(SunSky::new(&off, &data).unwrap().is_none());
}

/// Mitsuba's tables, or `None` (with the reason printed) when they are not fetched.
fn mitsuba_tables() -> Option<Dataset> {
    match Dataset::find(&[]) {
        Ok(d) => Some(d),
        Err(e) => {
            eprintln!("skipped: {e}");
            None
        }
    }
}

/// Mitsuba 3.9.1's radiance (`scalar_rgb`) towards directions `d` of its own frame, from
/// `e = mi.load_dict({"type": "sunsky", …})`, `si = dr.zeros(mi.SurfaceInteraction3f)`,
/// `si.wi = -dr.normalize(mi.Vector3f(d))`, `e.eval(si)`, in the venv of
/// `scripts/scenes/compare-scenes.py`; the last directions of each case are at the sun's centre
/// and 0.6 of its radius off it.
#[test]
fn the_radiance_is_mitsubas() {
    let Some(data) = mitsuba_tables() else { return };
    let at_time = |hour: f32| SunPosition::Time {
        time: DateTime {
            hour,
            ..DateTime::default()
        },
        location: Location::default(),
    };
    let towards = |x: f32, y: f32, z: f32| SunPosition::Direction(Vec3::new(x, y, z));
    type Case = (SunSkyParams, Vec<([f32; 3], [f32; 3])>);
    let cases: Vec<Case> = vec![
        (
            // {"hour": 10.5, "turbidity": 4, "albedo": rgb (0.2, 0.3, 0.4), "sun_scale": 0}
            SunSkyParams {
                sun: at_time(10.5),
                turbidity: 4.0,
                albedo: Rgb::new(0.2, 0.3, 0.4),
                sun_scale: 0.0,
                ..Default::default()
            },
            vec![
                ([0.0, 0.0, 1.0], [0.08322682, 0.10716, 0.1605727]),
                ([1.0, 0.0, 0.2], [0.09372264, 0.1566619, 0.2647834]),
                ([0.1, -0.9, 0.4], [0.07602379, 0.1270833, 0.2214908]),
                (
                    [0.2049786, -0.3031969, 0.930621],
                    [0.2455789, 0.2836781, 0.316614],
                ),
            ],
        ),
        (
            // {"sun_direction": [0.3, -0.5, 0.2], "turbidity": 7.3, "albedo": 0.6,
            //  "sun_scale": 0, "sky_scale": 2}
            SunSkyParams {
                sun: towards(0.3, -0.5, 0.2),
                turbidity: 7.3,
                albedo: Rgb::splat(0.6),
                sun_scale: 0.0,
                sky_scale: 2.0,
                ..Default::default()
            },
            vec![
                ([0.0, 0.0, 1.0], [0.04873953, 0.06975042, 0.1069338]),
                ([0.1, -0.9, 0.4], [0.6923764, 0.6272442, 0.4882504]),
                (
                    [0.4866643, -0.8111072, 0.3244429],
                    [2.388947, 2.032192, 1.236259],
                ),
            ],
        ),
        (
            // {"sun_direction": [0.9, 0.1, 0.03], "turbidity": 1.5, "sun_scale": 0}
            SunSkyParams {
                sun: towards(0.9, 0.1, 0.03),
                turbidity: 1.5,
                sun_scale: 0.0,
                ..Default::default()
            },
            vec![
                ([1.0, 0.0, 0.2], [0.07387078, 0.06496163, 0.03816193]),
                (
                    [0.9934609, 0.1100728, 0.03032441],
                    [0.1467085, 0.09265015, 0.02893439],
                ),
            ],
        ),
        (
            // {"sun_direction": [0.3, -0.5, 0.6], "turbidity": 5, "sky_scale": 0,
            //  "sun_aperture": 2}, then with "complex_sun": true
            SunSkyParams {
                sun: towards(0.3, -0.5, 0.6),
                turbidity: 5.0,
                sky_scale: 0.0,
                sun_aperture: 2.0,
                ..Default::default()
            },
            vec![
                (
                    [0.3585686, -0.5976143, 0.7171372],
                    [1424.413, 1162.601, 862.6448],
                ),
                (
                    [0.3682366, -0.5962747, 0.713343],
                    [1424.413, 1162.601, 862.6448],
                ),
            ],
        ),
        (
            SunSkyParams {
                sun: towards(0.3, -0.5, 0.6),
                turbidity: 5.0,
                sky_scale: 0.0,
                sun_aperture: 2.0,
                complex_sun: true,
                ..Default::default()
            },
            vec![
                (
                    [0.3585686, -0.5976143, 0.7171372],
                    [1717.772, 1454.775, 1142.331],
                ),
                (
                    [0.3682366, -0.5962747, 0.713343],
                    [1557.878, 1292.197, 981.9797],
                ),
            ],
        ),
        (
            // The kitchen's reading: {"hour": 9, "turbidity": 5, "sun_aperture": 2.1432,
            //  "sun_scale": 50, "sky_scale": 50, "albedo": 0.15}
            SunSkyParams {
                sun: at_time(9.0),
                turbidity: 5.0,
                sun_aperture: 2.1432,
                sun_scale: 50.0,
                sky_scale: 50.0,
                albedo: Rgb::splat(0.15),
                ..Default::default()
            },
            vec![
                ([0.0, 0.0, 1.0], [2.304837, 3.143131, 5.077444]),
                ([0.1, -0.9, 0.4], [10.52087, 12.29064, 14.48668]),
                ([0.2, 0.2, -0.5], [0.0, 0.0, 0.0]),
                (
                    [0.09569518, -0.6147862, 0.7828667],
                    [63089.05, 51973.06, 39344.5],
                ),
            ],
        ),
    ];
    for (params, points) in cases {
        let s = SunSky::new(&params, &data).unwrap().unwrap();
        for (d, want) in points {
            let got = s.eval(Vec3::from(d).normalize());
            let want = Rgb::from(want);
            let err = (got - want).abs().max_element();
            assert!(
                err <= 2e-5 * want.max_element(),
                "{params:?} at {d:?}: {got} vs {want}"
            );
        }
    }
}
