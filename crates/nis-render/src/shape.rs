//! Shapes as they enter a scene: triangle meshes (built-in rectangle, cube, disk and cylinder, or OBJ, PLY and serialized files) and analytic
//! spheres, each placed by a `to_world` transform.
//!
//! The built-in shapes reproduce Mitsuba 3's definitions exactly: `rectangle` is `[-1,1]²` in
//! the z = 0 plane facing +z, `cube` is `[-1,1]³` with outward faces, `sphere` is a center and a
//! radius; the `disk` and the `cylinder` are tessellated finely (their areas short by 0.01 %). Normals follow Mitsuba too: a rectangle's normal is its transformed +z (even under a
//! mirroring transform), `flip_normals` turns a shape inside out, and an OBJ mesh without
//! normals gets angle-weighted vertex normals (Thürmer & Wüthrich 1998) unless `face_normals`.

use std::path::Path;

use glam::{Mat3, Mat4, Vec2, Vec3, Vec4};

use crate::Error;

/// An indexed triangle mesh in world space.
#[derive(Clone, Debug, Default)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex shading normals (`None`: flat shading with the face normal).
    pub normals: Option<Vec<Vec3>>,
    /// Vertex indices of each triangle, counter-clockwise around the face normal.
    pub indices: Vec<[u32; 3]>,
    /// Per-vertex texture coordinates (`None`: the mesh has none, textures see `(0, 0)`).
    pub uvs: Option<Vec<Vec2>>,
    /// Named per-vertex or per-triangle values (a PLY file's other properties), which
    /// Mitsuba 3's `mesh_attribute` texture reads.
    pub attributes: Vec<MeshAttribute>,
}

/// A mesh attribute as Mitsuba 3 names and stores it.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshAttribute {
    /// `vertex_…` (one value per vertex, interpolated over a triangle) or `face_…` (one per
    /// triangle).
    pub name: String,
    /// Channels per value: 1 or 3 are read; Mitsuba reads a 4-channel colour as zero.
    pub dim: usize,
    /// `dim` values per vertex or per triangle.
    pub values: Vec<f32>,
}

impl MeshAttribute {
    /// Whether the attribute has a value per vertex (else per triangle).
    pub fn per_vertex(&self) -> bool {
        self.name.starts_with("vertex_")
    }

    /// Value `i` as a colour and a number, as a texture reads it: a number in every channel;
    /// a 3-channel value, read as a number, and any other width are zero (Mitsuba 3's
    /// `Mesh::eval_attribute` and `eval_attribute_1`).
    pub fn texel(&self, i: usize) -> [f32; 4] {
        let v = &self.values[i * self.dim..(i + 1) * self.dim];
        match self.dim {
            1 => [v[0]; 4],
            3 => [v[0], v[1], v[2], 0.0],
            _ => [0.0; 4],
        }
    }
}

/// Triangles of a [`TriangleMesh::disk`].
pub const DISK_SEGMENTS: usize = 256;

/// Quads around a [`TriangleMesh::cylinder`].
pub const CYLINDER_SEGMENTS: usize = 256;

impl TriangleMesh {
    /// Mitsuba's `rectangle`: `[-1,1]²` at z = 0, normal +z, placed by `to_world`.
    pub fn rectangle(to_world: &Mat4) -> Self {
        let mut mesh = TriangleMesh {
            positions: vec![
                Vec3::new(-1.0, -1.0, 0.0),
                Vec3::new(1.0, -1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
                Vec3::new(-1.0, 1.0, 0.0),
            ],
            normals: None,
            indices: vec![[0, 1, 2], [2, 3, 0]],
            // Mitsuba's: (x, y) ∈ [−1, 1]² maps to ((x + 1)/2, (y + 1)/2).
            uvs: Some(vec![
                Vec2::new(0.0, 0.0),
                Vec2::new(1.0, 0.0),
                Vec2::new(1.0, 1.0),
                Vec2::new(0.0, 1.0),
            ]),
            attributes: Vec::new(),
        };
        mesh.transform(to_world);
        // Mitsuba transforms the rectangle's normal as a normal; keep the winding consistent.
        if Mat3::from_mat4(*to_world).determinant() < 0.0 {
            mesh.flip();
        }
        mesh
    }

    /// Mitsuba's `disk`: the unit disk in the xy-plane facing +z, placed by `to_world`, as a fan
    /// of [`DISK_SEGMENTS`] triangles (its area short of π by 0.01 %).
    pub fn disk(to_world: &Mat4) -> Self {
        let n = DISK_SEGMENTS as u32;
        let mut positions = vec![Vec3::ZERO];
        positions.extend((0..n).map(|i| {
            let phi = 2.0 * std::f32::consts::PI * i as f32 / n as f32;
            Vec3::new(phi.cos(), phi.sin(), 0.0)
        }));
        let indices = (0..n).map(|i| [0, 1 + i, 1 + (i + 1) % n]).collect();
        // Mitsuba's disk coordinates: (radius, angle / 2π).
        let uvs = std::iter::once(Vec2::ZERO)
            .chain((0..n).map(|i| Vec2::new(1.0, i as f32 / n as f32)))
            .collect();
        let mut mesh = TriangleMesh {
            positions,
            normals: None,
            indices,
            uvs: Some(uvs),
            attributes: Vec::new(),
        };
        mesh.transform(to_world);
        if Mat3::from_mat4(*to_world).determinant() < 0.0 {
            mesh.flip();
        }
        mesh
    }

    /// Mitsuba's `cylinder`: the open tube of `radius` around the segment `p0`–`p1` (no caps),
    /// placed by `to_world`, as [`CYLINDER_SEGMENTS`] quads with smooth normals (its area short
    /// of 2πrl by 0.01 %). Mitsuba's frame: `to_world · translate(p0) · to_frame(d̂) ·
    /// scale(r, r, |d|)` over the unit cylinder, `to_frame` by Duff et al.'s orthonormal basis,
    /// uv = (φ / 2π, z); the normal is ∂p/∂u × ∂p/∂v, outward (inward under a mirroring
    /// transform, as in Mitsuba).
    pub fn cylinder(p0: Vec3, p1: Vec3, radius: f32, to_world: &Mat4) -> Self {
        let d = p1 - p0;
        let n = d / d.length();
        let (s, t) = coordinate_system(n);
        let frame = Mat4::from_cols(s.extend(0.0), t.extend(0.0), n.extend(0.0), Vec4::W);
        let m = *to_world
            * Mat4::from_translation(p0)
            * frame
            * Mat4::from_scale(Vec3::new(radius, radius, d.length()));
        let k = CYLINDER_SEGMENTS as u32;
        let mut mesh = TriangleMesh::default();
        let (mut normals, mut uvs) = (Vec::new(), Vec::new());
        // Vertex 2i at z = 0, 2i + 1 at z = 1; the seam's column repeats with u = 1.
        for i in 0..=k {
            let u = i as f32 / k as f32;
            let (sin, cos) = (2.0 * std::f32::consts::PI * u).sin_cos();
            for z in [0.0, 1.0] {
                mesh.positions.push(Vec3::new(cos, sin, z));
                normals.push(Vec3::new(cos, sin, 0.0));
                uvs.push(Vec2::new(u, z));
            }
        }
        mesh.indices = (0..k)
            .flat_map(|i| {
                let (a, b) = (2 * i, 2 * i + 2);
                [[a, b, b + 1], [b + 1, a + 1, a]]
            })
            .collect();
        mesh.normals = Some(normals);
        mesh.uvs = Some(uvs);
        mesh.transform(&m);
        if Mat3::from_mat4(m).determinant() < 0.0 {
            // The winding keeps ∂p/∂u × ∂p/∂v; the shading normals follow it.
            for n in mesh.normals.iter_mut().flatten() {
                *n = -*n;
            }
        }
        mesh
    }

    /// Mitsuba's `cube`: `[-1,1]³` with outward-facing sides, placed by `to_world`.
    pub fn cube(to_world: &Mat4) -> Self {
        let mut mesh = TriangleMesh::default();
        let mut uvs = Vec::new();
        for axis in 0..3 {
            for sign in [-1.0f32, 1.0] {
                let n = Vec3::AXES[axis] * sign;
                let (a, b) = (Vec3::AXES[(axis + 1) % 3], Vec3::AXES[(axis + 2) % 3]);
                let base = mesh.positions.len() as u32;
                for (s, t) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                    mesh.positions.push(n + s * a + t * b);
                    uvs.push(Vec2::new(0.5 * (s + 1.0), 0.5 * (t + 1.0)));
                }
                // a × b = n for the positive side; reverse the winding for the negative one.
                if sign > 0.0 {
                    mesh.indices.push([base, base + 1, base + 2]);
                    mesh.indices.push([base + 2, base + 3, base]);
                } else {
                    mesh.indices.push([base, base + 2, base + 1]);
                    mesh.indices.push([base + 2, base, base + 3]);
                }
            }
        }
        mesh.uvs = Some(uvs);
        mesh.transform(to_world);
        mesh
    }

    /// A Wavefront OBJ file (all objects merged), placed by `to_world`.
    pub fn load_obj(path: &Path, to_world: &Mat4, face_normals: bool) -> Result<Self, Error> {
        if !path.is_file() {
            return Err(Error::MissingMesh {
                path: path.display().to_string(),
            });
        }
        let options = tobj::LoadOptions {
            triangulate: true,
            single_index: true,
            ..Default::default()
        };
        let (models, _) = tobj::load_obj(path, &options).map_err(|e| Error::Mesh {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        let mut mesh = TriangleMesh::default();
        let mut normals = Vec::new();
        let mut uvs = Vec::new();
        let mut all_have_normals = true;
        let mut all_have_uvs = true;
        for model in &models {
            let m = &model.mesh;
            let base = mesh.positions.len() as u32;
            let nv = m.positions.len() / 3;
            mesh.positions
                .extend((0..nv).map(|i| Vec3::from_slice(&m.positions[3 * i..3 * i + 3])));
            if m.normals.len() == m.positions.len() {
                normals.extend((0..nv).map(|i| Vec3::from_slice(&m.normals[3 * i..3 * i + 3])));
            } else {
                all_have_normals = false;
            }
            if m.texcoords.len() == 2 * nv {
                // Mitsuba flips an OBJ's v (`flip_tex_coords`), so that v = 0 is the image's top.
                uvs.extend(
                    (0..nv).map(|i| Vec2::new(m.texcoords[2 * i], 1.0 - m.texcoords[2 * i + 1])),
                );
            } else {
                all_have_uvs = false;
            }
            for f in m.indices.chunks_exact(3) {
                mesh.indices.push([base + f[0], base + f[1], base + f[2]]);
            }
        }
        if mesh.indices.is_empty() {
            return Err(Error::Mesh {
                path: path.display().to_string(),
                message: "the file has no faces".into(),
            });
        }
        if let Some(bad) = mesh
            .indices
            .iter()
            .flatten()
            .find(|&&i| i as usize >= mesh.positions.len())
        {
            return Err(Error::Mesh {
                path: path.display().to_string(),
                message: format!("face refers to missing vertex {bad}"),
            });
        }
        if all_have_normals {
            mesh.normals = Some(normals);
        }
        if all_have_uvs {
            mesh.uvs = Some(uvs);
        }
        mesh.finish(to_world, face_normals);
        Ok(mesh)
    }

    /// Place a mesh read from a file: drop its normals for `face_normals`, transform it, and
    /// give it angle-weighted vertex normals where it has none.
    pub fn finish(&mut self, to_world: &Mat4, face_normals: bool) {
        if face_normals {
            self.normals = None;
        }
        self.transform(to_world);
        if !face_normals && self.normals.is_none() {
            self.normals = Some(self.vertex_normals());
        }
    }

    /// Apply `m` to positions (as points) and normals (by the inverse transpose).
    pub fn transform(&mut self, m: &Mat4) {
        for p in &mut self.positions {
            *p = m.transform_point3(*p);
        }
        if let Some(normals) = &mut self.normals {
            let nm = Mat3::from_mat4(*m).inverse().transpose();
            for n in normals {
                *n = (nm * *n).normalize_or_zero();
            }
        }
    }

    /// Turn the mesh inside out (Mitsuba's `flip_normals`).
    pub fn flip(&mut self) {
        for f in &mut self.indices {
            f.swap(1, 2);
        }
        if let Some(normals) = &mut self.normals {
            for n in normals {
                *n = -*n;
            }
        }
    }

    /// Angle-weighted vertex normals.
    fn vertex_normals(&self) -> Vec<Vec3> {
        let mut acc = vec![Vec3::ZERO; self.positions.len()];
        for f in &self.indices {
            let p = f.map(|i| self.positions[i as usize]);
            let n = (p[1] - p[0]).cross(p[2] - p[0]).normalize_or_zero();
            for k in 0..3 {
                let e1 = (p[(k + 1) % 3] - p[k]).normalize_or_zero();
                let e2 = (p[(k + 2) % 3] - p[k]).normalize_or_zero();
                let angle = e1.dot(e2).clamp(-1.0, 1.0).acos();
                acc[f[k] as usize] += angle * n;
            }
        }
        acc.into_iter().map(Vec3::normalize_or_zero).collect()
    }

    /// Total surface area.
    pub fn area(&self) -> f32 {
        self.indices
            .iter()
            .map(|f| {
                let p = f.map(|i| self.positions[i as usize]);
                0.5 * (p[1] - p[0]).cross(p[2] - p[0]).length()
            })
            .sum()
    }
}

/// Mitsuba's `coordinate_system` (Duff et al., "Building an Orthonormal Basis, Revisited",
/// JCGT 6(1), 2017): two unit vectors completing the unit `n` to a right-handed frame.
fn coordinate_system(n: Vec3) -> (Vec3, Vec3) {
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    (
        Vec3::new(sign * n.x * n.x * a + 1.0, sign * b, -sign * n.x),
        Vec3::new(b, sign + n.y * n.y * a, -n.y),
    )
}

/// An analytic sphere; with `inward` its normals point to the center (`flip_normals`).
#[derive(Clone, Copy, Debug)]
pub struct Sphere {
    /// Center.
    pub center: Vec3,
    /// Radius.
    pub radius: f32,
    /// Normals point inwards.
    pub inward: bool,
}

/// The geometry of one shape.
#[derive(Clone, Debug)]
pub enum Geometry {
    /// Triangles.
    Mesh(TriangleMesh),
    /// Analytic sphere.
    Sphere(Sphere),
}

/// A shape with its material and, if it is an area light, its emitted radiance.
#[derive(Clone, Debug)]
pub struct Shape {
    /// Geometry in world space.
    pub geometry: Geometry,
    /// Index into the scene's materials.
    pub material: usize,
    /// Radiance emitted from the front side (Mitsuba `area` emitter), if any.
    pub emission: Option<Vec3>,
}

#[cfg(test)]
mod tests {
    use super::*;

    fn face_normal(m: &TriangleMesh, f: usize) -> Vec3 {
        let p = m.indices[f].map(|i| m.positions[i as usize]);
        (p[1] - p[0]).cross(p[2] - p[0]).normalize()
    }

    #[test]
    fn rectangle_faces_transformed_z_even_when_mirrored() {
        let r = TriangleMesh::rectangle(&Mat4::IDENTITY);
        assert!((face_normal(&r, 0) - Vec3::Z).length() < 1e-6);
        assert!((r.area() - 4.0).abs() < 1e-6);
        let mirror = Mat4::from_scale(Vec3::new(-1.0, 1.0, 1.0));
        let r = TriangleMesh::rectangle(&mirror);
        assert!((face_normal(&r, 1) - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn cube_faces_point_outwards() {
        let c = TriangleMesh::cube(&Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0)));
        assert_eq!(c.indices.len(), 12);
        for f in 0..12 {
            let p = c.indices[f].map(|i| c.positions[i as usize]);
            let centroid = (p[0] + p[1] + p[2]) / 3.0 - Vec3::new(1.0, 2.0, 3.0);
            assert!(face_normal(&c, f).dot(centroid) > 0.9);
        }
        assert!((c.area() - 24.0).abs() < 1e-5);
    }

    /// Points, normals and uvs of Mitsuba 3.9.1's cylinder (p0, p1, radius and a rotated,
    /// scaled to_world) where rays hit it (`si.p`, `si.n`, `si.uv`), and its area: the
    /// tessellation at those uvs agrees to its chord error.
    #[test]
    fn cylinder_is_mitsubas_within_its_tessellation() {
        let to_world = Mat4::from_translation(Vec3::new(1.0, 2.0, 3.0))
            * Mat4::from_axis_angle(Vec3::new(0.6, 0.8, 0.0), 30f32.to_radians())
            * Mat4::from_scale(Vec3::splat(1.5));
        let c = TriangleMesh::cylinder(
            Vec3::new(0.3, -0.2, 0.5),
            Vec3::new(-0.4, 0.9, 0.1),
            0.4,
            &to_world,
        );
        assert!((c.area() / 7.712_212 - 1.0).abs() < 2e-4, "{}", c.area());
        let mitsuba = [
            (
                [1.836532, 1.936628, 2.935657],
                [0.402021, 0.448814, -0.798088],
                [0.032231, 0.088497],
            ),
            (
                [0.537397, 2.435475, 3.272769],
                [-0.720367, -0.324168, -0.613177],
                [0.273589, 0.660509],
            ),
            (
                [1.007299, 1.71447, 3.868942],
                [-0.587009, -0.526115, 0.615324],
                [0.48892, 0.304078],
            ),
            (
                [1.213952, 2.652665, 3.048147],
                [0.205371, 0.348364, -0.914585],
                [0.07207, 0.54979],
            ),
            (
                [1.128979, 2.31967, 4.182775],
                [0.055545, -0.194006, 0.979427],
                [0.62161, 0.54529],
            ),
        ];
        let (pos, nrm) = (&c.positions, c.normals.as_ref().unwrap());
        for (p, n, [u, v]) in mitsuba {
            // The quad column holding u; along it, linear in the column's fraction and in v.
            let x = u * CYLINDER_SEGMENTS as f32;
            let (i, f) = (x.floor() as usize, x.fract());
            let at = |a: &[Vec3], z: usize| a[2 * i + z].lerp(a[2 * i + 2 + z], f);
            let got_p = at(pos, 0).lerp(at(pos, 1), v);
            let got_n = at(nrm, 0).lerp(at(nrm, 1), v).normalize();
            assert!(
                (got_p - Vec3::from_array(p)).length() < 1e-3,
                "{got_p} {p:?}"
            );
            assert!(
                (got_n - Vec3::from_array(n)).length() < 1e-3,
                "{got_n} {n:?}"
            );
        }
        // Faces wind outwards.
        let centre = to_world.transform_point3(Vec3::new(-0.05, 0.35, 0.3));
        let p = c.indices[7].map(|i| c.positions[i as usize]);
        assert!(face_normal(&c, 7).dot((p[0] + p[1] + p[2]) / 3.0 - centre) > 0.0);
    }

    #[test]
    fn missing_obj_is_named() {
        let err = TriangleMesh::load_obj(Path::new("no/such/mesh.obj"), &Mat4::IDENTITY, false)
            .unwrap_err();
        assert!(err.to_string().contains("no/such/mesh.obj"), "{err}");
    }
}
