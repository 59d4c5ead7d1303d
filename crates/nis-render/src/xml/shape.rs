//! Shapes: `obj`, `ply` and `serialized` meshes, Mitsuba's `rectangle`, `cube`, `disk`,
//! `cylinder` (`p0`, `p1`, `radius`) and `sphere`, each with its BSDF (inline or by reference) and area emitter. A mesh file that is missing
//! is an error, or, with [`LoadOptions::drop_missing_meshes`](super::LoadOptions), a warning
//! and the shape left out (public snapshots of scenes sometimes lack their largest files).

use glam::{Mat3, Vec3};

use super::dom::{err, Element, XmlError};
use super::props::{Props, PROPERTY_TAGS};
use super::{out_of_range, unsupported, LoadError, LoadResult, Loader};
use crate::bsdf::{Bsdf, Material};
use crate::geometry::Rgb;
use crate::shape::{Geometry, Shape, Sphere, TriangleMesh};
use crate::spectrum::Role;

impl Loader {
    pub(super) fn shape(&mut self, el: &Element) -> LoadResult<()> {
        let Some(geometry) = self.geometry(el)? else {
            return Ok(());
        };
        let (material, emission) = self.shape_children(el)?;
        let material = match material {
            Some(m) => m,
            None => {
                // Mitsuba's default BSDF: diffuse with reflectance 0.5, black on an emitter.
                let reflectance = if emission.is_some() { 0.0 } else { 0.5 };
                self.materials.push(Material::new(Bsdf::Diffuse {
                    reflectance: Rgb::splat(reflectance),
                }));
                self.materials.len() - 1
            }
        };
        self.shapes.push(Shape {
            geometry,
            material,
            emission,
        });
        Ok(())
    }

    /// A shape's geometry: its `type` with its properties, transformed to world space, its
    /// normals flipped when asked.
    fn geometry(&mut self, el: &Element) -> LoadResult<Option<Geometry>> {
        let kind = el.required("type")?;
        let p = Props::new(el)?;
        let to_world = p.transform("to_world")?;
        let flip = p.boolean("flip_normals", false)?;
        let geometry = match kind {
            "rectangle" => Geometry::Mesh(TriangleMesh::rectangle(&to_world)),
            "cube" => Geometry::Mesh(TriangleMesh::cube(&to_world)),
            "disk" => Geometry::Mesh(TriangleMesh::disk(&to_world)),
            "obj" => {
                let file = p.string("filename")?.ok_or_else(|| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: "<shape type=\"obj\"> needs <string name=\"filename\">".into(),
                    })
                })?;
                let face_normals = p.boolean("face_normals", false)?;
                p.ignore(&["flip_tex_coords"]);
                let path = self.resolve(file);
                if self.drop_if_missing(el, &path) {
                    return Ok(None);
                }
                let mesh = TriangleMesh::load_obj(&path, &to_world, face_normals).map_err(|e| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: e.to_string(),
                    })
                })?;
                Geometry::Mesh(mesh)
            }
            "ply" => {
                let file = p.string("filename")?.ok_or_else(|| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: "<shape type=\"ply\"> needs <string name=\"filename\">".into(),
                    })
                })?;
                let face_normals = p.boolean("face_normals", false)?;
                let path = self.resolve(file);
                if self.drop_if_missing(el, &path) {
                    return Ok(None);
                }
                let mut mesh = crate::ply::load(&path).map_err(|e| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: e.to_string(),
                    })
                })?;
                mesh.finish(&to_world, face_normals);
                Geometry::Mesh(mesh)
            }
            "serialized" => {
                let file = p.string("filename")?.ok_or_else(|| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: "<shape type=\"serialized\"> needs <string name=\"filename\">"
                            .into(),
                    })
                })?;
                let index = p.int("shape_index", 0)?;
                let index = u32::try_from(index)
                    .map_err(|_| out_of_range(el, "shape_index", index, "0..=2^32-1"))?;
                let face_normals = p.boolean("face_normals", false)?;
                p.ignore(&["max_smooth_angle"]);
                let path = self.resolve(file);
                if self.drop_if_missing(el, &path) {
                    return Ok(None);
                }
                let mesh = crate::serialized::load(&path, index, &to_world, face_normals).map_err(
                    |e| {
                        LoadError::Xml(XmlError {
                            line: el.line,
                            message: e.to_string(),
                        })
                    },
                )?;
                Geometry::Mesh(mesh)
            }
            "cylinder" => {
                let radius = p.float("radius", 1.0)?;
                let p0 = p.point("p0", Vec3::ZERO)?;
                let p1 = p.point("p1", Vec3::Z)?;
                if !(radius > 0.0 && radius.is_finite()) {
                    return Err(err::<()>(
                        el.line,
                        format!("a cylinder's radius = {radius} must be positive"),
                    )
                    .unwrap_err()
                    .into());
                }
                if !((p1 - p0).length() > 0.0 && (p1 - p0).is_finite()) {
                    return Err(err::<()>(
                        el.line,
                        "a cylinder's p0 and p1 must be distinct points",
                    )
                    .unwrap_err()
                    .into());
                }
                Geometry::Mesh(TriangleMesh::cylinder(p0, p1, radius, &to_world))
            }
            "sphere" => {
                let center = p.point("center", Vec3::ZERO)?;
                let radius = p.float("radius", 1.0)?;
                let m3 = Mat3::from_mat4(to_world);
                let scale = m3.x_axis.length();
                if (m3.y_axis.length() - scale).abs() > 1e-4 * scale
                    || (m3.z_axis.length() - scale).abs() > 1e-4 * scale
                {
                    return Err(
                        err::<()>(el.line, "a sphere's to_world must scale uniformly")
                            .unwrap_err()
                            .into(),
                    );
                }
                Geometry::Sphere(Sphere {
                    center: to_world.transform_point3(center),
                    radius: radius * scale,
                    inward: false,
                })
            }
            _ => {
                return unsupported(
                    el,
                    "obj, ply, serialized, rectangle, cube, disk, cylinder, sphere",
                )
            }
        };
        p.finish()?;
        let geometry = match geometry {
            Geometry::Mesh(mut m) if flip => {
                m.flip();
                Geometry::Mesh(m)
            }
            Geometry::Sphere(mut s) if flip => {
                s.inward = true;
                Geometry::Sphere(s)
            }
            g => g,
        };
        Ok(Some(geometry))
    }

    /// With `drop_missing_meshes`, whether the mesh file at `path` is missing (said in a
    /// warning): the shape is then left out.
    fn drop_if_missing(&mut self, el: &Element, path: &std::path::Path) -> bool {
        if !self.options.drop_missing_meshes || path.is_file() {
            return false;
        }
        self.warnings.push((
            el.line,
            format!(
                "mesh file {} is missing: the shape is left out",
                path.display()
            ),
        ));
        true
    }

    /// A shape's material (its own `<bsdf>`, or a `<ref>` to one defined before; `None`: the
    /// default) and the radiance of its area `<emitter>`, if any.
    fn shape_children(&mut self, el: &Element) -> LoadResult<(Option<usize>, Option<Rgb>)> {
        let mut material = None;
        let mut emission = None;
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            match c.name.as_str() {
                "bsdf" | "ref" if material.is_some() => {
                    return Err(err::<()>(c.line, "a shape can have only one bsdf")
                        .unwrap_err()
                        .into())
                }
                "bsdf" => {
                    let m = self.bsdf(c)?;
                    self.materials.push(m);
                    material = Some(self.materials.len() - 1);
                }
                "ref" => {
                    let id = c.required("id")?;
                    let Some(&i) = self.bsdf_ids.get(id) else {
                        return Err(err::<()>(
                            c.line,
                            format!("no bsdf with id '{id}' is defined before this point"),
                        )
                        .unwrap_err()
                        .into());
                    };
                    material = Some(i);
                }
                "emitter" => {
                    if c.required("type")? != "area" {
                        return unsupported(c, "area (inside a shape)");
                    }
                    let e = Props::new(c)?;
                    emission = Some(e.spectrum("radiance", Rgb::ONE, Role::Emission)?);
                    e.finish()?;
                }
                _ => return unsupported(c, "bsdf, ref, emitter inside a shape"),
            }
        }
        Ok((material, emission))
    }
}
