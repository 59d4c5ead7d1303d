//! Stanford PLY meshes (ASCII and binary, read with the `ply-rs-bw` crate), as Mitsuba 3's
//! `ply` plugin reads them: the `vertex` element's `x y z`, optional normals `nx ny nz` and
//! texture coordinates (`u v`, `s t` or `texture_u texture_v`, kept as stored, without
//! Mitsuba's OBJ flip), and the `face` element's index lists (`vertex_indices` or
//! `vertex_index`), polygons split into fans. The two elements' other number properties become
//! mesh attributes as Mitsuba names them (`vertex_color` from `r g b` or `red green blue`,
//! `face_weight` from a lone `weight_0`, `vertex_n` from `n_x n_y n_z`: see [`attribute_groups`]),
//! values as stored; other elements are skipped.

use std::io::BufReader;
use std::path::Path;

use glam::{Vec2, Vec3};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{Property, PropertyAccess, PropertyAccessResult, PropertyType};

use crate::shape::{MeshAttribute, TriangleMesh};
use crate::Error;

#[derive(Default)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
    uv: [f32; 2],
    has_n: bool,
    has_uv: bool,
    /// The other number properties, in the header's order.
    extra: Vec<f32>,
}

#[derive(Default)]
struct Face {
    indices: Vec<i64>,
    /// The number properties, in the header's order.
    extra: Vec<f32>,
}

/// What a vertex property nis reads itself sets; any other is an attribute's column.
enum Role {
    Position(usize),
    Normal(usize),
    Uv(usize),
}

/// The role of the vertex property `name`, if nis reads it itself.
fn vertex_role(name: &str) -> Option<Role> {
    Some(match name {
        "x" => Role::Position(0),
        "y" => Role::Position(1),
        "z" => Role::Position(2),
        "nx" => Role::Normal(0),
        "ny" => Role::Normal(1),
        "nz" => Role::Normal(2),
        "u" | "s" | "texture_u" | "texture_s" => Role::Uv(0),
        "v" | "t" | "texture_v" | "texture_t" => Role::Uv(1),
        _ => return None,
    })
}

/// Any numeric PLY scalar as `f64`.
fn scalar(p: &Property) -> Option<f64> {
    Some(match *p {
        Property::Char(v) => f64::from(v),
        Property::UChar(v) => f64::from(v),
        Property::Short(v) => f64::from(v),
        Property::UShort(v) => f64::from(v),
        Property::Int(v) => f64::from(v),
        Property::UInt(v) => f64::from(v),
        Property::Float(v) => f64::from(v),
        Property::Double(v) => v,
        _ => return None,
    })
}

impl PropertyAccess for Vertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let Some(v) = scalar(&property) else {
            return PropertyAccessResult::Ignored;
        };
        let v = v as f32;
        match vertex_role(name) {
            Some(Role::Position(i)) => self.p[i] = v,
            Some(Role::Normal(i)) => {
                self.n[i] = v;
                self.has_n = true;
            }
            Some(Role::Uv(i)) => {
                self.uv[i] = v;
                // The first coordinate marks a vertex that has texture coordinates.
                self.has_uv |= i == 0;
            }
            None => self.extra.push(v),
        }
        PropertyAccessResult::Set
    }
}

impl PropertyAccess for Face {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        if name != "vertex_indices" && name != "vertex_index" {
            return match scalar(&property) {
                Some(v) => {
                    self.extra.push(v as f32);
                    PropertyAccessResult::Set
                }
                None => PropertyAccessResult::Ignored,
            };
        }
        self.indices = match property {
            Property::ListChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUChar(v) => v.into_iter().map(i64::from).collect(),
            Property::ListShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUShort(v) => v.into_iter().map(i64::from).collect(),
            Property::ListInt(v) => v.into_iter().map(i64::from).collect(),
            Property::ListUInt(v) => v.into_iter().map(i64::from).collect(),
            _ => return PropertyAccessResult::UnsupportedType,
        };
        PropertyAccessResult::Set
    }
}

/// A PLY file's mesh, in its own coordinates.
pub fn load(path: &Path) -> Result<TriangleMesh, Error> {
    if !path.is_file() {
        return Err(Error::MissingMesh {
            path: path.display().to_string(),
        });
    }
    let fail = |message: String| Error::Mesh {
        path: path.display().to_string(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| fail(e.to_string()))?;
    let mut reader = Reader::new(BufReader::new(file));
    let vertex_parser = Parser::<Vertex>::new();
    let face_parser = Parser::<Face>::new();
    let skip_parser = Parser::<Face>::new();
    let header = vertex_parser
        .read_header(&mut reader)
        .map_err(|e| fail(format!("malformed PLY header: {e}")))?;
    let (mut vertices, mut faces) = (Vec::new(), Vec::new());
    for element in header.elements.values() {
        let read = |e| fail(format!("malformed PLY {} data: {e}", element.name));
        match element.name.as_str() {
            "vertex" => {
                vertices = vertex_parser
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(read)?
            }
            "face" => {
                faces = face_parser
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(read)?
            }
            _ => {
                skip_parser
                    .read_payload_for_element(&mut reader, element, &header)
                    .map_err(read)?;
            }
        }
    }
    let n = vertices.len();
    let mut indices = Vec::with_capacity(faces.len());
    // The face each triangle comes from.
    let mut face_of = Vec::with_capacity(faces.len());
    for (j, f) in faces.iter().enumerate() {
        if let Some(bad) = f.indices.iter().find(|&&i| i < 0 || i as usize >= n) {
            return Err(fail(format!("a face refers to vertex {bad} of {n}")));
        }
        for k in 1..f.indices.len().saturating_sub(1) {
            indices.push([f.indices[0], f.indices[k], f.indices[k + 1]].map(|i| i as u32));
            face_of.push(j);
        }
    }
    let columns = |element: &str, own: &dyn Fn(&str) -> bool| -> Vec<String> {
        header.elements.get(element).map_or(Vec::new(), |e| {
            e.properties
                .values()
                .filter(|d| matches!(d.data_type, PropertyType::Scalar(_)) && !own(&d.name))
                .map(|d| d.name.clone())
                .collect()
        })
    };
    // Each attribute's values, row after row, from the rows' other properties (`extra`).
    let gather = |kind: &str, what: &str, cols: &[String], rows: &[&[f32]]| {
        attribute_groups(kind, cols)
            .into_iter()
            .map(|(name, cols)| {
                let mut values = Vec::with_capacity(rows.len() * cols.len());
                for row in rows {
                    for &c in &cols {
                        values.push(
                            *row.get(c)
                                .ok_or_else(|| fail(format!("a {what} lacks {name}")))?,
                        );
                    }
                }
                Ok(MeshAttribute {
                    name,
                    dim: cols.len(),
                    values,
                })
            })
            .collect::<Result<Vec<_>, Error>>()
    };
    let vertex_rows: Vec<&[f32]> = vertices.iter().map(|v| v.extra.as_slice()).collect();
    let face_rows: Vec<&[f32]> = face_of.iter().map(|&j| faces[j].extra.as_slice()).collect();
    let mut attributes = gather(
        "vertex_",
        "vertex",
        &columns("vertex", &|name| vertex_role(name).is_some()),
        &vertex_rows,
    )?;
    attributes.extend(gather(
        "face_",
        "face",
        &columns("face", &|_| false),
        &face_rows,
    )?);
    if indices.is_empty() {
        return Err(fail("the file has no triangles".into()));
    }
    if vertices.iter().any(|v| !v.p.iter().all(|c| c.is_finite())) {
        return Err(fail("a vertex position is not finite".into()));
    }
    let all = |f: fn(&Vertex) -> bool| vertices.iter().all(f);
    Ok(TriangleMesh {
        positions: vertices.iter().map(|v| Vec3::from_array(v.p)).collect(),
        normals: all(|v| v.has_n).then(|| vertices.iter().map(|v| Vec3::from_array(v.n)).collect()),
        indices,
        uvs: all(|v| v.has_uv).then(|| vertices.iter().map(|v| Vec2::from_array(v.uv)).collect()),
        attributes,
    })
}

/// Mitsuba 3's grouping of an element's other properties (`columns`, in the header's order)
/// into attributes named `{kind}…` with the columns they read: `r g b [a]` (or
/// `red green blue [alpha]`) make `{kind}color`; consecutive `{prefix}_{x y z}`, `_{0 1 2}` or
/// `_{1 2 3}` make a 3-channel `{kind}{prefix}`, `{prefix}_{r g b}` a `{kind}{prefix}_color`,
/// and a lone `{prefix}_x` (`_r`, `_0`, `_1`) a 1-channel one. Other properties (no
/// one-letter suffix, 2 or 4 channels, a repeated prefix) are skipped, as Mitsuba skips them
/// with a warning.
pub fn attribute_groups(kind: &str, columns: &[String]) -> Vec<(String, Vec<usize>)> {
    const SUFFIXES: [&[u8; 4]; 4] = [b"xr01", b"yg12", b"zb23", b"wa34"];
    let find = |n: &str| columns.iter().position(|c| c == n);
    let mut out = Vec::new();
    let mut colour = Vec::new();
    for set in [["r", "g", "b", "a"], ["red", "green", "blue", "alpha"]] {
        if let (Some(r), Some(g), Some(b)) = (find(set[0]), find(set[1]), find(set[2])) {
            colour = vec![r, g, b];
            colour.extend(find(set[3]));
            out.push((format!("{kind}color"), colour.clone()));
            break;
        }
    }
    // The attribute being read: its prefix, suffix family and columns.
    let mut current: Option<(String, usize, Vec<usize>)> = None;
    let mut seen: Vec<String> = Vec::new();
    let flush = |current: &mut Option<(String, usize, Vec<usize>)>,
                 out: &mut Vec<(String, Vec<usize>)>,
                 seen: &mut Vec<String>| {
        if let Some((prefix, family, cols)) = current.take() {
            if cols.len() == 1 || cols.len() == 3 {
                let colour = if family == 1 { "_color" } else { "" };
                out.push((format!("{kind}{prefix}{colour}"), cols));
                seen.push(prefix);
            }
        }
    };
    for (i, name) in columns.iter().enumerate() {
        if colour.contains(&i) || ["r", "g", "b", "a"].contains(&name.as_str()) {
            continue;
        }
        let Some((prefix, suffix)) = name.rsplit_once('_').filter(|(_, s)| s.len() == 1) else {
            flush(&mut current, &mut out, &mut seen);
            continue;
        };
        if current.as_ref().is_some_and(|c| c.0 != prefix) {
            flush(&mut current, &mut out, &mut seen);
        }
        let c = suffix.as_bytes()[0];
        match &mut current {
            None => {
                if seen.iter().any(|s| s == prefix) {
                    continue;
                }
                if let Some(family) = SUFFIXES[0].iter().position(|&s| s == c) {
                    current = Some((prefix.to_string(), family, vec![i]));
                }
            }
            Some((_, family, cols)) => {
                if cols.len() < 4 && SUFFIXES[cols.len()][*family] == c {
                    cols.push(i);
                } else {
                    // A broken sequence: the attribute is skipped.
                    seen.push(prefix.to_string());
                    current = None;
                }
            }
        }
    }
    flush(&mut current, &mut out, &mut seen);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_ascii_quad_with_normals_and_uvs_loads_as_two_triangles() {
        let dir = std::env::temp_dir().join(format!("nis-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("quad.ply");
        std::fs::write(
            &path,
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
             property float z\nproperty float nx\nproperty float ny\nproperty float nz\n\
             property float u\nproperty float v\nelement face 1\n\
             property list uchar int vertex_indices\nend_header\n\
             0 0 0 0 0 1 0 0\n1 0 0 0 0 1 1 0\n1 1 0 0 0 1 1 1\n0 1 0 0 0 1 0 1\n4 0 1 2 3\n",
        )
        .unwrap();
        let m = load(&path).unwrap();
        assert_eq!(m.indices, vec![[0, 1, 2], [0, 2, 3]]);
        assert_eq!(m.normals.unwrap()[2], Vec3::Z);
        assert_eq!(m.uvs.unwrap()[2], Vec2::ONE);
        std::fs::write(
            &path,
            "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n0\n",
        )
        .unwrap();
        assert!(load(&path)
            .unwrap_err()
            .to_string()
            .contains("no triangles"));
        std::fs::write(&path, "not a ply").unwrap();
        assert!(load(&path).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn other_properties_become_attributes_named_as_mitsuba_names_them() {
        let names = |cols: &[&str]| {
            let cols: Vec<String> = cols.iter().map(|c| c.to_string()).collect();
            attribute_groups("vertex_", &cols)
        };
        assert_eq!(
            names(&["red", "green", "blue", "weight_0", "n_x", "n_y", "n_z", "c_r", "c_g", "c_b"]),
            vec![
                ("vertex_color".to_string(), vec![0, 1, 2]),
                ("vertex_weight".to_string(), vec![3]),
                ("vertex_n".to_string(), vec![4, 5, 6]),
                ("vertex_c_color".to_string(), vec![7, 8, 9]),
            ]
        );
        // Two channels, no one-letter suffix, a broken sequence: skipped, as Mitsuba does.
        assert_eq!(
            names(&["p_x", "p_y", "q", "s_0", "s_2", "t_1"]),
            vec![("vertex_t".to_string(), vec![5])]
        );

        // A quad's face property is each of its triangles'; vertex colours are per vertex.
        let dir = std::env::temp_dir().join(format!("nis-ply-attr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("quad.ply");
        std::fs::write(
            &path,
            "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n\
             property float z\nproperty uchar r\nproperty uchar g\nproperty uchar b\n\
             element face 1\nproperty list uchar int vertex_indices\nproperty float weight_0\n\
             end_header\n0 0 0 1 2 3\n1 0 0 4 5 6\n1 1 0 7 8 9\n0 1 0 10 11 12\n4 0 1 2 3 0.25\n",
        )
        .unwrap();
        let m = load(&path).unwrap();
        std::fs::remove_dir_all(&dir).ok();
        assert_eq!(m.attributes.len(), 2);
        let (colour, weight) = (&m.attributes[0], &m.attributes[1]);
        assert_eq!((colour.name.as_str(), colour.dim), ("vertex_color", 3));
        assert_eq!(colour.texel(2), [7.0, 8.0, 9.0, 0.0]);
        assert_eq!((weight.name.as_str(), weight.dim), ("face_weight", 1));
        assert_eq!(weight.values, vec![0.25, 0.25]);
        assert!(!weight.per_vertex() && colour.per_vertex());
    }
}
