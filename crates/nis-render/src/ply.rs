//! Stanford PLY meshes (ASCII and binary, read with the `ply-rs-bw` crate), as Mitsuba 3's
//! `ply` plugin reads them: the `vertex` element's `x y z`, optional normals `nx ny nz` and
//! texture coordinates (`u v`, `s t` or `texture_u texture_v`, kept as stored, without
//! Mitsuba's OBJ flip), and the `face` element's index lists (`vertex_indices` or
//! `vertex_index`), polygons split into fans. Other elements and properties are skipped.

use std::io::BufReader;
use std::path::Path;

use glam::{Vec2, Vec3};
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{Property, PropertyAccess, PropertyAccessResult};

use crate::shape::TriangleMesh;
use crate::Error;

#[derive(Default)]
struct Vertex {
    p: [f32; 3],
    n: [f32; 3],
    uv: [f32; 2],
    has_n: bool,
    has_uv: bool,
}

#[derive(Default)]
struct Face {
    indices: Vec<i64>,
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
        match name {
            "x" => self.p[0] = v,
            "y" => self.p[1] = v,
            "z" => self.p[2] = v,
            "nx" | "ny" | "nz" => {
                self.n[usize::from(name.as_bytes()[1] - b'x')] = v;
                self.has_n = true;
            }
            "u" | "s" | "texture_u" | "texture_s" => {
                self.uv[0] = v;
                self.has_uv = true;
            }
            "v" | "t" | "texture_v" | "texture_t" => self.uv[1] = v,
            _ => return PropertyAccessResult::Ignored,
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
            return PropertyAccessResult::Ignored;
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
    for f in &faces {
        if let Some(bad) = f.indices.iter().find(|&&i| i < 0 || i as usize >= n) {
            return Err(fail(format!("a face refers to vertex {bad} of {n}")));
        }
        for k in 1..f.indices.len().saturating_sub(1) {
            indices.push([f.indices[0], f.indices[k], f.indices[k + 1]].map(|i| i as u32));
        }
    }
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
    })
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
}
