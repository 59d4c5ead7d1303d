//! Mitsuba's `serialized` meshes (format versions 3 and 4, as Mitsuba 0.x wrote them and
//! Mitsuba 3 reads them; its `serialized` plugin documents the layout): a file of
//! zlib-compressed meshes, each after a little-endian header `0x041C` and the version, with a
//! table of their offsets at the end. A mesh is a flag word (`0x1` normals, `0x2` texture
//! coordinates, `0x8` vertex colours, `0x2000` double precision), its name (version 4), the
//! vertex and triangle counts (`u64`), positions, normals, texture coordinates, colours and
//! `u32` vertex indices. Texture coordinates are kept as stored (no flip, unlike OBJ).

use std::io::Read;
use std::path::Path;

use flate2::read::ZlibDecoder;
use glam::{Mat4, Vec2, Vec3};

use crate::shape::TriangleMesh;
use crate::Error;

const FORMAT: u16 = 0x041C;
const HAS_NORMALS: u32 = 0x0001;
const HAS_TEXCOORDS: u32 = 0x0002;
const HAS_COLORS: u32 = 0x0008;
const DOUBLE_PRECISION: u32 = 0x2000;
/// Most vertices or triangles one mesh may declare (a hostile count must not allocate).
pub const MAX_ELEMENTS: u64 = 1 << 28;

fn mesh_error(path: &Path, message: impl Into<String>) -> Error {
    Error::Mesh {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// The mesh `shape_index` of the file at `path`, placed by `to_world`, with vertex normals
/// unless `face_normals`.
pub fn load(
    path: &Path,
    shape_index: u32,
    to_world: &Mat4,
    face_normals: bool,
) -> Result<TriangleMesh, Error> {
    if !path.is_file() {
        return Err(Error::MissingMesh {
            path: path.display().to_string(),
        });
    }
    let bytes = std::fs::read(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    let mut mesh = parse(&bytes, shape_index).map_err(|m| mesh_error(path, m))?;
    mesh.finish(to_world, face_normals);
    Ok(mesh)
}

fn u16_at(b: &[u8], at: usize) -> Option<u16> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?))
}

fn u32_at(b: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?))
}

fn u64_at(b: &[u8], at: usize) -> Option<u64> {
    Some(u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?))
}

/// The mesh `shape_index` of a serialized file's bytes, in its own coordinates.
pub fn parse(bytes: &[u8], shape_index: u32) -> Result<TriangleMesh, String> {
    let short = || "the file is too short to be a serialized mesh".to_string();
    if u16_at(bytes, 0).ok_or_else(short)? != FORMAT {
        return Err("not a serialized mesh (no 0x041C header)".into());
    }
    let version = u16_at(bytes, 2).ok_or_else(short)?;
    if version != 3 && version != 4 {
        return Err(format!(
            "serialized format version {version} is not supported (3 and 4 are)"
        ));
    }
    let start = if shape_index == 0 {
        0
    } else {
        let n = bytes.len();
        let count = u32_at(bytes, n.checked_sub(4).ok_or_else(short)?).ok_or_else(short)?;
        if shape_index >= count {
            return Err(format!(
                "shape_index {shape_index} is out of range (the file has {count} meshes)"
            ));
        }
        let back = u64::from(count - shape_index);
        let offset = if version == 4 {
            let at = (n as u64).checked_sub(8 * back + 4).ok_or_else(short)?;
            u64_at(bytes, at as usize).ok_or_else(short)?
        } else {
            let at = (n as u64).checked_sub(4 * (back + 1)).ok_or_else(short)?;
            u64::from(u32_at(bytes, at as usize).ok_or_else(short)?)
        };
        let offset = usize::try_from(offset).map_err(|_| short())?;
        if u16_at(bytes, offset) != Some(FORMAT) {
            return Err(format!(
                "mesh {shape_index} does not start with the 0x041C header"
            ));
        }
        offset
    };
    let data = bytes.get(start + 4..).ok_or_else(short)?;
    let mut z = ZlibDecoder::new(data);
    let mut r = Reader { z: &mut z };
    let flags = r.u32()?;
    if version == 4 {
        // The shape's name, null-terminated.
        let mut len = 0;
        while r.u8()? != 0 {
            len += 1;
            if len > 1 << 16 {
                return Err("the mesh's name never ends".into());
            }
        }
    }
    let vertices = r.u64()?;
    let triangles = r.u64()?;
    if vertices > MAX_ELEMENTS || triangles > MAX_ELEMENTS {
        return Err(format!(
            "{vertices} vertices and {triangles} triangles: more than {MAX_ELEMENTS}"
        ));
    }
    let double = flags & DOUBLE_PRECISION != 0;
    let positions = r.vectors(vertices, double)?;
    let normals = if flags & HAS_NORMALS != 0 {
        Some(r.vectors(vertices, double)?)
    } else {
        None
    };
    let uvs = if flags & HAS_TEXCOORDS != 0 {
        let mut uvs = Vec::with_capacity(vertices.min(1 << 20) as usize);
        for _ in 0..vertices {
            uvs.push(Vec2::new(r.real(double)?, r.real(double)?));
        }
        Some(uvs)
    } else {
        None
    };
    if flags & HAS_COLORS != 0 {
        r.vectors(vertices, double)?;
    }
    let mut indices = Vec::with_capacity(triangles.min(1 << 20) as usize);
    for _ in 0..triangles {
        let f = [r.u32()?, r.u32()?, r.u32()?];
        if let Some(bad) = f.iter().find(|&&i| u64::from(i) >= vertices) {
            return Err(format!("a triangle refers to vertex {bad} of {vertices}"));
        }
        indices.push(f);
    }
    if indices.is_empty() {
        return Err("the mesh has no triangles".into());
    }
    Ok(TriangleMesh {
        positions,
        normals,
        indices,
        uvs,
        attributes: Vec::new(),
    })
}

struct Reader<'a, R: Read> {
    z: &'a mut R,
}

impl<R: Read> Reader<'_, R> {
    fn bytes<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut b = [0u8; N];
        self.z
            .read_exact(&mut b)
            .map_err(|e| format!("the compressed mesh data ends early or is corrupt: {e}"))?;
        Ok(b)
    }
    fn u8(&mut self) -> Result<u8, String> {
        Ok(self.bytes::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.bytes()?))
    }
    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.bytes()?))
    }
    fn real(&mut self, double: bool) -> Result<f32, String> {
        let v = if double {
            f64::from_le_bytes(self.bytes()?) as f32
        } else {
            f32::from_le_bytes(self.bytes()?)
        };
        if v.is_finite() {
            Ok(v)
        } else {
            Err("a vertex attribute is not finite".into())
        }
    }
    fn vectors(&mut self, n: u64, double: bool) -> Result<Vec<Vec3>, String> {
        let mut out = Vec::with_capacity(n.min(1 << 20) as usize);
        for _ in 0..n {
            out.push(Vec3::new(
                self.real(double)?,
                self.real(double)?,
                self.real(double)?,
            ));
        }
        Ok(out)
    }
}

/// Write one mesh as a version-4 serialized file's bytes (single precision), for tests and
/// for turning meshes into test data.
pub fn write(meshes: &[TriangleMesh]) -> Vec<u8> {
    use flate2::write::ZlibEncoder;
    use std::io::Write;
    let mut out = Vec::new();
    let mut offsets = Vec::new();
    for m in meshes {
        offsets.push(out.len() as u64);
        out.extend_from_slice(&FORMAT.to_le_bytes());
        out.extend_from_slice(&4u16.to_le_bytes());
        let mut z = ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        let mut flags: u32 = 0x1000;
        if m.normals.is_some() {
            flags |= HAS_NORMALS;
        }
        if m.uvs.is_some() {
            flags |= HAS_TEXCOORDS;
        }
        let mut w = |b: &[u8]| z.write_all(b).expect("writing to memory");
        w(&flags.to_le_bytes());
        w(b"mesh\0");
        w(&(m.positions.len() as u64).to_le_bytes());
        w(&(m.indices.len() as u64).to_le_bytes());
        for p in &m.positions {
            p.to_array().iter().for_each(|c| w(&c.to_le_bytes()));
        }
        for n in m.normals.iter().flatten() {
            n.to_array().iter().for_each(|c| w(&c.to_le_bytes()));
        }
        for t in m.uvs.iter().flatten() {
            t.to_array().iter().for_each(|c| w(&c.to_le_bytes()));
        }
        for f in &m.indices {
            f.iter().for_each(|i| w(&i.to_le_bytes()));
        }
        out.extend(z.finish().expect("writing to memory"));
    }
    for o in &offsets {
        out.extend_from_slice(&o.to_le_bytes());
    }
    out.extend_from_slice(&(meshes.len() as u32).to_le_bytes());
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad(z: f32) -> TriangleMesh {
        TriangleMesh {
            positions: vec![
                Vec3::new(0.0, 0.0, z),
                Vec3::new(1.0, 0.0, z),
                Vec3::new(1.0, 1.0, z),
                Vec3::new(0.0, 1.0, z),
            ],
            normals: Some(vec![Vec3::Z; 4]),
            indices: vec![[0, 1, 2], [2, 3, 0]],
            uvs: Some(vec![Vec2::ZERO, Vec2::X, Vec2::ONE, Vec2::Y]),
            attributes: Vec::new(),
        }
    }

    #[test]
    fn meshes_round_trip_by_index() {
        let bytes = write(&[quad(0.0), quad(5.0)]);
        let m = parse(&bytes, 1).unwrap();
        assert_eq!(m.positions[2], Vec3::new(1.0, 1.0, 5.0));
        assert_eq!(m.indices, vec![[0, 1, 2], [2, 3, 0]]);
        assert_eq!(m.uvs.unwrap()[2], Vec2::ONE);
        assert_eq!(parse(&bytes, 0).unwrap().positions[0].z, 0.0);
        assert!(parse(&bytes, 2).unwrap_err().contains("out of range"));
    }

    #[test]
    fn truncated_and_foreign_files_are_errors() {
        let bytes = write(&[quad(0.0)]);
        for n in [0, 3, 10, bytes.len() / 2] {
            assert!(parse(&bytes[..n], 0).is_err(), "{n} bytes");
        }
        assert!(parse(b"ply\nformat ascii", 0)
            .unwrap_err()
            .contains("0x041C"));
    }
}
