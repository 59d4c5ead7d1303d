//! A scene ready to render: geometry in a BVH (plus analytic spheres), materials, lights, the
//! camera, and the film, sampler and integrator settings it was described with.
//!
//! Scenes come from [`crate::xml`] (Mitsuba 3 XML) or from [`crate::scenes`] (built-in XML);
//! [`Scene::new`] turns a list of [`Shape`]s into the structures the integrator queries:
//! closest-hit and shadow-ray tests, and per-hit shading data.

use glam::{Vec2, Vec3};

use crate::bsdf::Material;
use crate::bvh::{Bvh, Triangle};
use crate::camera::Camera;
use crate::filter::Filter;
use crate::geometry::{Ray, Rgb};
use crate::light::{AreaLight, LightPrimitive, Lights};
use crate::shape::{Geometry, Shape, Sphere};
use crate::texture::{AttributeHit, Texture};
use crate::Error;

/// Settings a scene file carries for the film, sampler and integrator; command-line flags
/// override them.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderSettings {
    /// Samples per pixel (Mitsuba sampler `sample_count`).
    pub spp: u32,
    /// Longest path in segments, camera segment included; `-1` is unbounded (Mitsuba `max_depth`).
    pub max_depth: i32,
    /// Depth from which Russian roulette may end paths (Mitsuba `rr_depth`).
    pub rr_depth: u32,
    /// Hide directly visible emitters (Mitsuba `hide_emitters`).
    pub hide_emitters: bool,
    /// The film's reconstruction filter (Mitsuba `rfilter`).
    pub filter: Filter,
}

impl Default for RenderSettings {
    fn default() -> Self {
        RenderSettings {
            spp: 4,
            max_depth: -1,
            rr_depth: 5,
            hide_emitters: false,
            filter: Filter::default(),
        }
    }
}

/// Where a ray hit a surface, with what is needed to shade there.
#[derive(Clone, Copy, Debug)]
pub struct SurfaceHit {
    /// Hit point.
    pub p: Vec3,
    /// Ray distance.
    pub t: f32,
    /// Unit geometric normal.
    pub ng: Vec3,
    /// Unit shading normal (the BSDF's +z).
    pub ns: Vec3,
    /// Index into [`Scene::materials`].
    pub material: u32,
    /// Index into the scene's area lights, or [`NO_LIGHT`].
    pub light: u32,
    /// Texture coordinates (Mitsuba's conventions per shape; `(0, 0)` on a mesh without them).
    pub uv: Vec2,
    /// The triangle hit (in the BVH's order), or [`NO_TRIANGLE`] for a sphere.
    pub triangle: u32,
    /// Barycentric coordinates of the hit on the triangle (the weights of its second and
    /// third vertices); zero on a sphere.
    pub bary: Vec2,
}

/// [`SurfaceHit::triangle`] of a sphere.
pub const NO_TRIANGLE: u32 = u32::MAX;

/// [`SurfaceHit::light`] of a surface that does not emit.
pub const NO_LIGHT: u32 = u32::MAX;

#[derive(Clone, Copy, Debug)]
struct TriangleInfo {
    ng: Vec3,
    /// Index of the vertex normals in `Scene::vertex_normals`, or `u32::MAX` (flat).
    smooth: u32,
    /// Index of the vertex texture coordinates in `Scene::vertex_uvs`, or `u32::MAX` (none).
    uv: u32,
    material: u32,
    light: u32,
    /// Index of the triangle's first entry in `Scene::attribute_corners`, or `u32::MAX`.
    attributes: u32,
}

#[derive(Clone, Copy, Debug)]
struct SphereInfo {
    sphere: Sphere,
    material: u32,
    light: u32,
}

/// A renderable scene.
#[derive(Clone, Debug)]
pub struct Scene {
    /// The camera (its resolution is the film's).
    pub camera: Camera,
    /// Film, sampler and integrator settings from the scene description.
    pub settings: RenderSettings,
    /// Materials referenced by shapes.
    pub materials: Vec<Material>,
    /// All lights.
    pub lights: Lights,
    /// What the scene file asked for that is read differently (file:line: message).
    pub warnings: Vec<String>,
    bvh: Bvh,
    triangles: Vec<TriangleInfo>,
    vertex_normals: Vec<[Vec3; 3]>,
    vertex_uvs: Vec<[Vec2; 3]>,
    /// The mesh attributes the materials' `mesh_attribute` textures read.
    attribute_names: Vec<String>,
    /// For each triangle whose material reads them, each attribute's value at its corners.
    attribute_corners: Vec<[[f32; 4]; 3]>,
    spheres: Vec<SphereInfo>,
}

impl Scene {
    /// Assemble a scene; fails when a shape refers to a missing material.
    pub fn new(
        camera: Camera,
        settings: RenderSettings,
        materials: Vec<Material>,
        shapes: Vec<Shape>,
        environment: Option<Rgb>,
    ) -> Result<Scene, Error> {
        let mut tris = Vec::new();
        let mut infos = Vec::new();
        let mut vertex_normals = Vec::new();
        let mut vertex_uvs = Vec::new();
        let mut emission = Vec::new();
        let mut spheres = Vec::new();
        // The attributes each material reads, by index into `attribute_names`.
        let mut attribute_names: Vec<String> = Vec::new();
        let mut reads: Vec<Vec<usize>> = Vec::new();
        for m in &materials {
            let mut r = Vec::new();
            for (_, t) in &m.textures {
                if let Texture::MeshAttribute { name, .. } = &**t {
                    let k = match attribute_names.iter().position(|n| n == name) {
                        Some(k) => k,
                        None => {
                            attribute_names.push(name.clone());
                            attribute_names.len() - 1
                        }
                    };
                    r.push(k);
                }
            }
            reads.push(r);
        }
        let mut attribute_corners = Vec::new();
        for shape in &shapes {
            if shape.material >= materials.len() {
                return Err(Error::Invalid(format!(
                    "shape refers to material {} of {}",
                    shape.material,
                    materials.len()
                )));
            }
            let read = &reads[shape.material];
            let missing = |name: &str| {
                Error::Invalid(format!(
                    "a mesh_attribute texture reads '{name}', which a shape with its material \
                     does not have"
                ))
            };
            match &shape.geometry {
                Geometry::Mesh(mesh) => {
                    // The mesh's attribute for each name the material reads.
                    let mut found = vec![None; attribute_names.len()];
                    for &k in read {
                        let name = &attribute_names[k];
                        let a = mesh.attributes.iter().find(|a| &a.name == name);
                        found[k] = Some(a.ok_or_else(|| missing(name))?);
                    }
                    for (j, f) in mesh.indices.iter().enumerate() {
                        let p = f.map(|i| mesh.positions[i as usize]);
                        let cross = (p[1] - p[0]).cross(p[2] - p[0]);
                        if cross.length_squared() == 0.0 || !cross.is_finite() {
                            continue; // degenerate: invisible and cannot be sampled
                        }
                        tris.push(Triangle::new(p[0], p[1], p[2]));
                        let smooth = match &mesh.normals {
                            Some(n) => {
                                vertex_normals.push(f.map(|i| n[i as usize]));
                                (vertex_normals.len() - 1) as u32
                            }
                            None => u32::MAX,
                        };
                        let uv = match &mesh.uvs {
                            Some(t) => {
                                vertex_uvs.push(f.map(|i| t[i as usize]));
                                (vertex_uvs.len() - 1) as u32
                            }
                            None => u32::MAX,
                        };
                        let attributes = if read.is_empty() {
                            u32::MAX
                        } else {
                            let start = attribute_corners.len() as u32;
                            for a in &found {
                                attribute_corners.push(match a {
                                    None => [[0.0; 4]; 3],
                                    Some(a) if a.per_vertex() => f.map(|i| a.texel(i as usize)),
                                    Some(a) => [a.texel(j); 3],
                                });
                            }
                            start
                        };
                        infos.push(TriangleInfo {
                            ng: cross.normalize(),
                            smooth,
                            uv,
                            material: shape.material as u32,
                            light: NO_LIGHT,
                            attributes,
                        });
                        emission.push(shape.emission);
                    }
                }
                Geometry::Sphere(s) => {
                    if let Some(&k) = read.first() {
                        return Err(missing(&attribute_names[k]));
                    }
                    spheres.push((*s, shape.material as u32, shape.emission))
                }
            }
        }
        let (bvh, order) = Bvh::build(&tris);
        let mut triangles: Vec<TriangleInfo> = order.iter().map(|&i| infos[i as usize]).collect();
        let mut area_lights = Vec::new();
        for (k, &i) in order.iter().enumerate() {
            if let Some(radiance) = emission[i as usize] {
                let t = &bvh.triangles()[k];
                triangles[k].light = area_lights.len() as u32;
                area_lights.push(AreaLight {
                    primitive: LightPrimitive::Triangle {
                        p0: t.p0,
                        e1: t.e1,
                        e2: t.e2,
                        n: triangles[k].ng,
                    },
                    radiance,
                    area: 0.5 * t.e1.cross(t.e2).length(),
                });
            }
        }
        let spheres = spheres
            .into_iter()
            .map(|(sphere, material, emission)| {
                let light = match emission {
                    Some(radiance) => {
                        area_lights.push(AreaLight {
                            primitive: LightPrimitive::Sphere {
                                center: sphere.center,
                                radius: sphere.radius,
                                inward: sphere.inward,
                            },
                            radiance,
                            area: 4.0 * std::f32::consts::PI * sphere.radius * sphere.radius,
                        });
                        (area_lights.len() - 1) as u32
                    }
                    None => NO_LIGHT,
                };
                SphereInfo {
                    sphere,
                    material,
                    light,
                }
            })
            .collect();
        Ok(Scene {
            camera,
            settings,
            materials,
            lights: Lights::new(area_lights, environment),
            warnings: Vec::new(),
            bvh,
            triangles,
            vertex_normals,
            vertex_uvs,
            attribute_names,
            attribute_corners,
            spheres,
        })
    }

    /// The mesh attributes at a hit, where its material reads any.
    pub fn attributes(&self, hit: &SurfaceHit) -> Option<AttributeHit<'_>> {
        let info = self.triangles.get(hit.triangle as usize)?;
        let start = info.attributes as usize;
        let corners = self
            .attribute_corners
            .get(start..start + self.attribute_names.len())?;
        Some(AttributeHit {
            names: &self.attribute_names,
            corners,
            bary: Vec3::new(1.0 - hit.bary.x - hit.bary.y, hit.bary.x, hit.bary.y),
        })
    }

    /// `∂p/∂u` and `∂p/∂v` of the triangle a hit is on, from its positions and texture
    /// coordinates (pbrt's construction); `None` on spheres and on triangles without texture
    /// coordinates or with degenerate ones.
    pub fn uv_derivatives(&self, hit: &SurfaceHit) -> Option<(Vec3, Vec3)> {
        let info = self.triangles.get(hit.triangle as usize)?;
        let t = self.vertex_uvs.get(info.uv as usize)?;
        let tri = &self.bvh.triangles()[hit.triangle as usize];
        let (p0, p1, p2) = (tri.p0, tri.p0 + tri.e1, tri.p0 + tri.e2);
        let (d02, d12) = (t[0] - t[2], t[1] - t[2]);
        let (dp02, dp12) = (p0 - p2, p1 - p2);
        let det = d02.x * d12.y - d02.y * d12.x;
        if det.abs() < 1e-12 {
            return None;
        }
        let dpdu = (d12.y * dp02 - d02.y * dp12) / det;
        let dpdv = (d02.x * dp12 - d12.x * dp02) / det;
        (dpdu.is_finite() && dpdv.is_finite()).then_some((dpdu, dpdv))
    }

    /// `∂p/∂u` as Mitsuba 3 (3.9) sets a shading frame's tangent, up to its length: from a
    /// triangle's texture coordinates, its first edge where it has none (after `flip_normals`,
    /// which swaps our faces' last two vertices, the other edge: Mitsuba keeps the first),
    /// zero where they are degenerate; `z × n` on a sphere (its `φ` direction, up to sign).
    pub fn dpdu(&self, hit: &SurfaceHit) -> Vec3 {
        let Some(info) = self.triangles.get(hit.triangle as usize) else {
            return Vec3::new(-hit.ng.y, hit.ng.x, 0.0);
        };
        if info.uv == u32::MAX {
            return self.bvh.triangles()[hit.triangle as usize].e1;
        }
        self.uv_derivatives(hit).map_or(Vec3::ZERO, |d| d.0)
    }

    /// Number of triangles in the BVH.
    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Closest surface hit by `ray` before `t_max`.
    pub fn intersect(&self, ray: &Ray, t_max: f32) -> Option<SurfaceHit> {
        let mut best = None;
        let mut t_max = t_max;
        if let Some(h) = self.bvh.intersect(ray, t_max) {
            t_max = h.t;
            let info = &self.triangles[h.prim as usize];
            let ns = if info.smooth == u32::MAX {
                info.ng
            } else {
                let n = &self.vertex_normals[info.smooth as usize];
                let s = (1.0 - h.u - h.v) * n[0] + h.u * n[1] + h.v * n[2];
                s.try_normalize().unwrap_or(info.ng)
            };
            let uv = if info.uv == u32::MAX {
                Vec2::ZERO
            } else {
                let t = &self.vertex_uvs[info.uv as usize];
                (1.0 - h.u - h.v) * t[0] + h.u * t[1] + h.v * t[2]
            };
            best = Some(SurfaceHit {
                p: ray.at(h.t),
                t: h.t,
                ng: info.ng,
                ns,
                material: info.material,
                light: info.light,
                uv,
                triangle: h.prim,
                bary: Vec2::new(h.u, h.v),
            });
        }
        // The nearest sphere, if nearer than any triangle; its shading data once, at the end.
        let mut nearest = None;
        for s in &self.spheres {
            if let Some(t) = intersect_sphere(&s.sphere, ray, t_max) {
                t_max = t;
                nearest = Some((s, t));
            }
        }
        if let Some((s, t)) = nearest {
            // The point re-projected onto the sphere and its unit normal, as Mitsuba 3 does: a
            // path bouncing inside a sphere otherwise drifts off it, its error growing tenfold
            // a bounce, until its rays miss the sphere.
            let off = ray.at(t) - s.sphere.center;
            let d = off.try_normalize().unwrap_or(-ray.dir);
            let p = s.sphere.center + s.sphere.radius * d;
            let n = if s.sphere.inward { -d } else { d };
            // Mitsuba's sphere coordinates (φ/2π, θ/π), here about the world axes.
            let phi = d.y.atan2(d.x).rem_euclid(2.0 * std::f32::consts::PI);
            let uv = Vec2::new(
                phi / (2.0 * std::f32::consts::PI),
                d.z.clamp(-1.0, 1.0).acos() / std::f32::consts::PI,
            );
            best = Some(SurfaceHit {
                p,
                t,
                ng: n,
                ns: n,
                material: s.material,
                light: s.light,
                uv,
                triangle: NO_TRIANGLE,
                bary: Vec2::ZERO,
            });
        }
        best
    }

    /// The bounding box of all geometry (an empty scene gives the unit cube around the
    /// origin, so guides that normalise positions by it still work).
    pub fn bounds(&self) -> crate::bvh::Aabb {
        let mut min = Vec3::splat(f32::INFINITY);
        let mut max = Vec3::splat(f32::NEG_INFINITY);
        for t in self.bvh.triangles() {
            for p in [t.p0, t.p0 + t.e1, t.p0 + t.e2] {
                min = min.min(p);
                max = max.max(p);
            }
        }
        for s in &self.spheres {
            min = min.min(s.sphere.center - Vec3::splat(s.sphere.radius));
            max = max.max(s.sphere.center + Vec3::splat(s.sphere.radius));
        }
        if min.cmpgt(max).any() {
            return crate::bvh::Aabb {
                min: Vec3::splat(-0.5),
                max: Vec3::splat(0.5),
            };
        }
        crate::bvh::Aabb { min, max }
    }

    /// Whether anything blocks `ray` before `t_max`.
    pub fn occluded(&self, ray: &Ray, t_max: f32) -> bool {
        self.spheres
            .iter()
            .any(|s| intersect_sphere(&s.sphere, ray, t_max).is_some())
            || self.bvh.occluded(ray, t_max)
    }
}

/// Nearest root of `|o + t d - c|² = r²` in `(0, t_max)`, computed in the cancellation-free
/// form (Haines et al., *Ray Tracing Gems*, ch. 7).
fn intersect_sphere(s: &Sphere, ray: &Ray, t_max: f32) -> Option<f32> {
    let f = ray.origin - s.center;
    let b = -f.dot(ray.dir);
    let perp = f + b * ray.dir;
    let disc = s.radius * s.radius - perp.length_squared();
    if disc < 0.0 {
        return None;
    }
    let c = f.length_squared() - s.radius * s.radius;
    let q = b + b.signum() * disc.sqrt();
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
    let (t0, t1) = (t0.min(t1), t0.max(t1));
    if t0 > 0.0 && t0 < t_max {
        Some(t0)
    } else if t1 > 0.0 && t1 < t_max {
        Some(t1)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounds_enclose_the_cornell_room() {
        // The room spans x ∈ [−1, 1], y ∈ [0, 2], z ∈ [−1, 1] (see the scene file).
        let b = crate::scenes::load("cornell-box").unwrap().bounds();
        let (lo, hi) = (Vec3::new(-1.0, 0.0, -1.0), Vec3::new(1.0, 2.0, 1.0));
        assert!((b.min - lo).abs().max_element() < 1e-4, "{:?}", b.min);
        assert!((b.max - hi).abs().max_element() < 1e-4, "{:?}", b.max);
    }

    #[test]
    fn sphere_roots_from_outside_and_inside() {
        let s = Sphere {
            center: Vec3::new(0.0, 0.0, 5.0),
            radius: 1.0,
            inward: false,
        };
        let ray = Ray::new(Vec3::ZERO, Vec3::Z);
        assert!((intersect_sphere(&s, &ray, f32::INFINITY).unwrap() - 4.0).abs() < 1e-5);
        let inside = Ray::new(Vec3::new(0.0, 0.0, 5.0), Vec3::Z);
        assert!((intersect_sphere(&s, &inside, f32::INFINITY).unwrap() - 1.0).abs() < 1e-5);
        assert!(intersect_sphere(&s, &ray, 3.0).is_none());
    }
}
