//! Fuzzing the renderer's readers of outside data (issue 16): Mitsuba XML scenes (random bytes,
//! byte edits and element-level mutations of the built-in scenes, absurd numbers and
//! parameters, deep nesting), OBJ meshes, EXR images and `--guide-config` JSON. Each reader must
//! return a typed error or a valid value within the memory and time limits of
//! `nis-fuzz-support`; an accepted scene must also render a few pixels without panicking.
//! `NIS_FUZZ_CASES=N` sets the cases per target (`scripts/test/fuzz.sh`).

use nis_fuzz_support as fuzz;

use std::path::Path;

use fuzz::{check, mutated, Counting};
use nis::flow::Density;
use nis_render::film::Image;
use nis_render::geometry::Rgb;
use nis_render::guiding::factory::GuideSpec;
use nis_render::guiding::NoGuide;
use nis_render::path_tracer::{PathTracer, Strategy as Technique};
use nis_render::render::{render, Budget, RenderOptions, Schedule};
use nis_render::scene::Scene;
use nis_render::scenes::SCENES;
use nis_render::shape::TriangleMesh;
use nis_render::xml::load_scene_str;
use proptest::prelude::*;

#[global_allocator]
static ALLOC: Counting = Counting;

/// Numbers that break naive readers: overflow to ±∞ in f32, NaN, signed zero, integers past
/// i32, u32, i64 and u64, denormals, empty and malformed values.
const ABSURD: [&str; 22] = [
    "1e39",
    "-1e39",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "-0",
    "0",
    "-1",
    "-2",
    "2147483648",
    "4294967297",
    "9223372036854775808",
    "18446744073709551616",
    "99999999999999999999999999",
    "-99999999999999999999999999",
    "1e-45",
    "",
    "1,2",
    "0x10",
    "$res",
    "100000",
];

/// A loaded scene is valid when its numbers are sane and it renders 2×2 pixels at one sample.
fn assert_usable(scene: &Scene) -> Result<(), TestCaseError> {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    prop_assert!(w >= 1 && h >= 1, "an empty film {w}×{h} was accepted");
    prop_assert!(
        (w as u64) * (h as u64) <= 1 << 28,
        "a film of {w}×{h} pixels was accepted"
    );
    prop_assert!(scene.settings.spp >= 1);
    let mut small = scene.clone();
    small.camera.set_resolution(2, 2);
    let mut path_tracer = PathTracer::from_scene(&small, Technique::Mis);
    path_tracer.max_depth = 4;
    let out = render(
        &small,
        &RenderOptions {
            path_tracer,
            budget: Budget::Samples(1),
            seed: 1,
            schedule: Schedule::Plain,
        },
        &mut NoGuide,
        &|_| {},
    );
    prop_assert_eq!(out.image.pixels.len(), 4);
    Ok(())
}

fn load_xml(
    tally: &std::cell::RefCell<fuzz::Tally>,
    text: &str,
    params: &[(String, String)],
) -> Result<(), TestCaseError> {
    let input = text.len() + params.iter().map(|(k, v)| k.len() + v.len()).sum::<usize>();
    let scene = check(
        tally,
        input,
        || load_scene_str(text, Path::new("/nonexistent"), "fuzz.xml", params),
        |_| 0,
    )?;
    match scene {
        Ok(scene) => assert_usable(&scene),
        Err(_) => Ok(()),
    }
}

#[test]
fn xml_random_bytes_are_rejected_or_loaded() {
    let bytes = prop::collection::vec(any::<u8>(), 0..512);
    fuzz::fuzz("xml-random-bytes", 300, bytes, |tally, bytes| {
        load_xml(tally, &String::from_utf8_lossy(&bytes), &[])
    });
}

/// The built-in scenes and the reader's feature scenes (`tests/scenes/features`: every BSDF,
/// filter, emitter and Mitsuba 0.x name the reader knows), without their comments.
fn corpus() -> Vec<(String, String)> {
    let mut scenes: Vec<(String, String)> = SCENES
        .iter()
        .map(|(n, x)| (n.to_string(), x.to_string()))
        .collect();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/scenes/features");
    let mut paths: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "xml"))
        .collect();
    paths.sort();
    for path in paths {
        let text = std::fs::read_to_string(&path).unwrap();
        let text: String = text
            .lines()
            .filter(|l| !l.trim_start().starts_with("<!--"))
            .map(|l| format!("{l}\n"))
            .collect();
        scenes.push((path.display().to_string(), text));
    }
    scenes
}

#[test]
fn xml_byte_edits_of_the_built_in_scenes() {
    let scenes = prop::sample::select(corpus());
    let strategy = scenes.prop_flat_map(|(_, xml)| mutated(xml.as_bytes().to_vec(), 6));
    fuzz::fuzz("xml-byte-edits", 400, strategy, |tally, bytes| {
        load_xml(tally, &String::from_utf8_lossy(&bytes), &[])
    });
}

/// The byte ranges of the elements of `xml` (start tag to end tag), found by matching tags; the
/// XML of the built-in scenes is simple enough (no `<` in attribute values).
fn element_spans(xml: &str) -> Vec<(usize, usize)> {
    let b = xml.as_bytes();
    let (mut spans, mut open) = (Vec::new(), Vec::new());
    let mut i = 0;
    while let Some(off) = xml[i..].find('<') {
        let start = i + off;
        let end = start + xml[start..].find('>').expect("tags close") + 1;
        i = end;
        match b[start + 1] {
            b'?' | b'!' => {}
            b'/' => {
                let s = open.pop().expect("balanced");
                spans.push((s, end));
            }
            _ if b[end - 2] == b'/' => spans.push((start, end)),
            _ => open.push(start),
        }
    }
    spans
}

/// An element-level edit of a scene: delete, duplicate or swap elements, set an attribute to an
/// absurd value, or nest an element deeply.
#[derive(Clone, Debug)]
enum XmlEdit {
    Delete(usize),
    Duplicate(usize),
    Swap(usize, usize),
    Absurd(usize, usize),
    Nest(usize, &'static str, usize),
}

fn xml_edit() -> impl Strategy<Value = XmlEdit> {
    let wrapper = prop::sample::select(vec![
        "transform",
        "bsdf type=\"twosided\"",
        "shape type=\"cube\"",
        "scene",
        "x",
    ]);
    prop_oneof![
        3 => any::<usize>().prop_map(XmlEdit::Delete),
        2 => any::<usize>().prop_map(XmlEdit::Duplicate),
        2 => (any::<usize>(), any::<usize>()).prop_map(|(a, b)| XmlEdit::Swap(a, b)),
        4 => (any::<usize>(), 0..ABSURD.len()).prop_map(|(a, v)| XmlEdit::Absurd(a, v)),
        1 => (any::<usize>(), wrapper, prop_oneof![1usize..64, 1000usize..200_000])
            .prop_map(|(a, w, d)| XmlEdit::Nest(a, w, d)),
    ]
}

fn apply_xml_edit(xml: &str, e: &XmlEdit) -> String {
    let spans = element_spans(xml);
    if spans.is_empty() {
        return xml.to_string();
    }
    let pick = |i: usize| spans[i % spans.len()];
    match *e {
        XmlEdit::Delete(a) => {
            let (s, t) = pick(a);
            format!("{}{}", &xml[..s], &xml[t..])
        }
        XmlEdit::Duplicate(a) => {
            let (s, t) = pick(a);
            format!("{}{}", &xml[..t], &xml[s..])
        }
        XmlEdit::Swap(a, b) => {
            let ((s1, t1), (s2, t2)) = (pick(a), pick(b));
            if t1 <= s2 {
                format!(
                    "{}{}{}{}{}",
                    &xml[..s1],
                    &xml[s2..t2],
                    &xml[t1..s2],
                    &xml[s1..t1],
                    &xml[t2..]
                )
            } else if t2 <= s1 {
                apply_xml_edit(xml, &XmlEdit::Swap(b, a))
            } else {
                xml.to_string() // one contains the other
            }
        }
        XmlEdit::Absurd(a, v) => {
            let values: Vec<_> = xml.match_indices("value=\"").collect();
            if values.is_empty() {
                return xml.to_string();
            }
            let start = values[a % values.len()].0 + "value=\"".len();
            let end = start + xml[start..].find('"').expect("quoted");
            format!("{}{}{}", &xml[..start], ABSURD[v], &xml[end..])
        }
        XmlEdit::Nest(a, wrapper, depth) => {
            let (s, t) = pick(a);
            let name = wrapper.split(' ').next().expect("a name");
            format!(
                "{}{}{}{}{}",
                &xml[..s],
                format!("<{wrapper}>").repeat(depth),
                &xml[s..t],
                format!("</{name}>").repeat(depth),
                &xml[t..]
            )
        }
    }
}

#[test]
fn xml_element_mutations_of_the_built_in_scenes() {
    let scenes = prop::sample::select(corpus());
    let strategy = (scenes, prop::collection::vec(xml_edit(), 1..4));
    fuzz::fuzz("xml-elements", 400, strategy, |tally, ((_, xml), edits)| {
        let text = edits
            .iter()
            .fold(xml.to_string(), |x, e| apply_xml_edit(&x, e));
        load_xml(tally, &text, &[])
    });
}

#[test]
fn xml_absurd_parameters_of_the_built_in_scenes() {
    let scenes = prop::sample::select(SCENES.to_vec());
    let param = (
        prop::sample::select(vec!["spp", "res", "max_depth", "other"]),
        prop::sample::select(ABSURD.to_vec()),
    );
    let strategy = (scenes, prop::collection::vec(param, 1..4));
    fuzz::fuzz(
        "xml-parameters",
        200,
        strategy,
        |tally, ((_, xml), params)| {
            let params: Vec<(String, String)> = params
                .into_iter()
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect();
            load_xml(tally, xml, &params)
        },
    );
}

/// A mesh a reader returned is usable: it has triangles, every index names a vertex, and each
/// per-vertex attribute has one value per vertex.
fn usable_mesh(mesh: &TriangleMesh) -> Result<(), TestCaseError> {
    let n = mesh.positions.len();
    prop_assert!(!mesh.indices.is_empty());
    prop_assert!(mesh.indices.iter().flatten().all(|&i| (i as usize) < n));
    prop_assert!(mesh.normals.as_ref().is_none_or(|v| v.len() == n));
    prop_assert!(mesh.uvs.as_ref().is_none_or(|v| v.len() == n));
    Ok(())
}

/// A small valid OBJ: a quad with normals, a triangle and a polygon.
const OBJ: &str =
    "# fuzz seed\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0.5 0.5 1\nvn 0 0 1\nvt 0 0\n\
f 1//1 2//1 3//1\nf 1 3 4\nf 1 2 5 4\no second\nv 2 2 2\nf -1 -2 -3\n";

/// OBJ statements, with indices out of range, zero, negative and huge, and long polygons.
fn obj_line() -> impl Strategy<Value = String> {
    let index = prop_oneof![
        -8i64..16,
        Just(0i64),
        Just(i32::MAX as i64 + 1),
        Just(u32::MAX as i64 + 2),
        Just(i64::MIN),
        Just(i64::MAX),
    ];
    let number = prop_oneof![
        -10.0f64..10.0,
        Just(f64::NAN),
        Just(f64::INFINITY),
        Just(1e39),
        Just(-0.0)
    ];
    prop_oneof![
        3 => prop::collection::vec(number, 3).prop_map(|v| format!("v {} {} {}", v[0], v[1], v[2])),
        1 => prop::collection::vec(-1.0f64..1.0, 3).prop_map(|v| format!("vn {} {} {}", v[0], v[1], v[2])),
        3 => prop::collection::vec(index.clone(), 1..8)
            .prop_map(|ix| format!("f {}", ix.iter().map(i64::to_string).collect::<Vec<_>>().join(" "))),
        1 => (index.clone(), index).prop_map(|(a, b)| format!("f {a}/{b}/{a} {b}//{a} {a}/{b}")),
        1 => (3usize..20_000).prop_map(|n| format!("f {}", (1..=n).map(|i| i.to_string()).collect::<Vec<_>>().join(" "))),
        1 => Just("o x".to_string()),
        1 => Just("mtllib missing.mtl".to_string()),
        1 => Just("usemtl nothing".to_string()),
        1 => "[ -~]{0,40}",
    ]
}

#[test]
fn obj_meshes_random_and_mutated() {
    let dir = fuzz::scratch("obj");
    let path = dir.join("mesh.obj");
    let text = prop_oneof![
        prop::collection::vec(obj_line(), 0..40).prop_map(|l| l.join("\n").into_bytes()),
        mutated(OBJ.as_bytes().to_vec(), 6),
    ];
    fuzz::fuzz("obj", 400, text, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let mesh = check(
            tally,
            bytes.len(),
            || TriangleMesh::load_obj(&path, &glam::Mat4::IDENTITY, false),
            |_| 0,
        )?;
        match mesh {
            Ok(mesh) => usable_mesh(&mesh),
            Err(_) => Ok(()),
        }
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Mitsuba serialized meshes: byte edits of a valid two-mesh file (a corrupt zlib stream,
/// counts past the data, offsets past the end) and random bytes after a valid header.
#[test]
fn serialized_meshes_mutated() {
    let mesh = |z: f32| TriangleMesh {
        positions: vec![glam::Vec3::new(0.0, 0.0, z), glam::Vec3::X, glam::Vec3::Y],
        normals: Some(vec![glam::Vec3::Z; 3]),
        indices: vec![[0, 1, 2]],
        uvs: Some(vec![glam::Vec2::ZERO, glam::Vec2::X, glam::Vec2::Y]),
        attributes: Vec::new(),
    };
    let valid = nis_render::serialized::write(&[mesh(0.0), mesh(1.0)]);
    let bytes = prop_oneof![
        3 => mutated(valid, 6),
        1 => prop::collection::vec(any::<u8>(), 0..256).prop_map(|mut b| {
            let mut v = vec![0x1C, 0x04, 4, 0];
            v.append(&mut b);
            v
        }),
    ];
    fuzz::fuzz(
        "serialized",
        400,
        (bytes, 0u32..3),
        |tally, (bytes, index)| {
            let mesh = check(
                tally,
                bytes.len(),
                || nis_render::serialized::parse(&bytes, index),
                |_| 0,
            )?;
            if let Ok(mesh) = &mesh {
                prop_assert!(mesh.positions.iter().all(|p| p.is_finite()));
            }
            match mesh {
                Ok(mesh) => usable_mesh(&mesh),
                Err(_) => Ok(()),
            }
        },
    );
}

/// A small valid PLY: a quad with normals and texture coordinates, and a triangle.
const PLY: &str = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
    property float z\nproperty float nx\nproperty float ny\nproperty float nz\nproperty float u\n\
    property float v\nelement face 2\nproperty list uchar int vertex_indices\nend_header\n\
    0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n1 1 0 0 0 1 1 1\n0 1 0 0 0 1 0 1\n4 0 1 2 3\n3 0 1 2\n";

/// PLY meshes: byte edits of a valid file (counts past the data, lists past the vertices,
/// broken headers) and random headers with absurd element counts.
#[test]
fn ply_meshes_mutated() {
    let dir = fuzz::scratch("ply");
    let path = dir.join("mesh.ply");
    let counts = prop_oneof![Just(0u64), 1u64..10, Just(u32::MAX as u64), Just(u64::MAX)];
    let bytes = prop_oneof![
        3 => mutated(PLY.as_bytes().to_vec(), 6),
        1 => (counts.clone(), counts).prop_map(|(v, f)| {
            PLY.replace("vertex 4", &format!("vertex {v}"))
                .replace("face 2", &format!("face {f}"))
                .into_bytes()
        }),
    ];
    fuzz::fuzz("ply", 300, bytes, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let mesh = check(tally, bytes.len(), || nis_render::ply::load(&path), |_| 0)?;
        match mesh {
            Ok(mesh) => usable_mesh(&mesh),
            Err(_) => Ok(()),
        }
    });
    let _ = std::fs::remove_dir_all(&dir);
}

fn small_exr(dir: &Path) -> Vec<u8> {
    let mut img = Image::new(5, 3);
    for (i, p) in img.pixels.iter_mut().enumerate() {
        *p = Rgb::new(i as f32, 0.5, 1e-3 * i as f32);
    }
    let path = dir.join("seed.exr");
    img.write_exr(&path).expect("an EXR");
    std::fs::read(&path).expect("the EXR")
}

/// `exr` with the data window (the box after the attribute name) replaced by `window`.
fn forge_data_window(exr: &[u8], window: [i32; 4]) -> Vec<u8> {
    let mut out = exr.to_vec();
    let key = b"dataWindow\0box2i\0";
    let at = exr
        .windows(key.len())
        .position(|w| w == key)
        .expect("an EXR has a data window")
        + key.len()
        + 4; // the attribute's size
    for (k, v) in window.iter().enumerate() {
        out[at + 4 * k..at + 4 * k + 4].copy_from_slice(&v.to_le_bytes());
    }
    out
}

#[test]
fn exr_images_mutated_and_forged() {
    let dir = fuzz::scratch("exr");
    let seed = small_exr(&dir);
    let path = dir.join("case.exr");
    let corner = prop_oneof![
        Just(0i32),
        Just(-1),
        Just(1 << 16),
        Just(100_000),
        Just(i32::MAX),
        Just(i32::MIN),
        -4i32..8
    ];
    let strategy = prop_oneof![
        3 => mutated(seed.clone(), 4),
        1 => prop::collection::vec(corner, 4).prop_map({
            let seed = seed.clone();
            move |w| forge_data_window(&seed, [w[0], w[1], w[2], w[3]])
        }),
    ];
    fuzz::fuzz("exr", 300, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let img = check(
            tally,
            bytes.len(),
            || Image::read_exr(&path),
            |img| img.pixels.len() * std::mem::size_of::<Rgb>(),
        )?;
        if let Ok(img) = img {
            prop_assert_eq!(img.pixels.len(), img.width as usize * img.height as usize);
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

/// Numbers that configs must reject or survive: zero, negative, huge, fractional.
fn absurd_number() -> impl Strategy<Value = serde_json::Value> {
    prop::sample::select(vec![
        serde_json::json!(0),
        serde_json::json!(-1),
        serde_json::json!(1),
        serde_json::json!(2),
        serde_json::json!(1_000_000_000_000u64),
        serde_json::json!(u64::MAX),
        serde_json::json!(65536),
        serde_json::json!(0.5),
        serde_json::json!(-0.0),
        serde_json::json!(1e300),
        serde_json::json!("nan"),
        serde_json::json!(null),
    ])
}

/// The neural guide's settings as JSON: random values, or the defaults with fields set to
/// absurd numbers.
fn guide_config() -> impl Strategy<Value = String> {
    let defaults = serde_json::to_value(nis_render::guiding::neural::NisGuideConfig::default())
        .expect("serialises");
    let keys: Vec<String> = defaults
        .as_object()
        .expect("an object")
        .keys()
        .cloned()
        .collect();
    prop_oneof![
        fuzz::json_value().prop_map(|v| v.to_string()),
        prop::collection::vec((prop::sample::select(keys), absurd_number()), 1..5).prop_map(
            move |fields| {
                let mut v = defaults.clone();
                for (k, x) in fields {
                    v[k] = x;
                }
                v.to_string()
            }
        ),
        "[ -~]{0,64}",
    ]
}

#[test]
fn guide_configs_random_and_absurd() {
    let names = prop::sample::select(GuideSpec::NAMES.to_vec());
    fuzz::fuzz(
        "guide-config",
        400,
        (names, guide_config()),
        |tally, (name, json)| {
            let spec = check(
                tally,
                json.len(),
                || GuideSpec::parse(name, Some(&json), 3),
                |_| 0,
            )?;
            if let Ok(GuideSpec::Neural(config)) = spec {
                // An accepted configuration builds its guide within the limits too.
                let bounds = nis_render::bvh::Aabb {
                    min: glam::Vec3::ZERO,
                    max: glam::Vec3::ONE,
                };
                let guide = check(
                    tally,
                    json.len(),
                    || nis_render::guiding::neural::NisGuide::new(bounds, config.clone()),
                    |g| 16 * g.flow().param_count() * std::mem::size_of::<f32>(),
                )?;
                prop_assert!(
                    guide.is_ok(),
                    "accepted by parse, refused by new: {:?}",
                    guide.err()
                );
            }
            Ok(())
        },
    );
}
