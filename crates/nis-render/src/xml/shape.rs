//! Shapes: `obj`, `ply` and `serialized` meshes, Mitsuba's `rectangle`, `cube`, `disk`,
//! `cylinder` (`p0`, `p1`, `radius`) and `sphere`, each with its BSDF (inline or by reference) and area emitter;
//! Mitsuba's `shapegroup` and `instance`, flattened: each instance adds copies of its group's
//! shapes placed by its `to_world` (a sphere only by a similarity). A mesh file that is missing
//! is an error, or, with [`LoadOptions::drop_missing_meshes`](super::LoadOptions), a warning
//! and the shape left out (public snapshots of scenes sometimes lack their largest files).

use glam::{Mat3, Vec3};

use super::dom::{Element, XmlError};
use super::fail;
use super::props::{Props, PROPERTY_TAGS};
use super::{out_of_range, unsupported, LoadError, LoadResult, Loader};
use crate::bsdf::{Bsdf, Material};
use crate::geometry::Rgb;
use crate::shape::{Geometry, Shape, Sphere, TriangleMesh};
use crate::spectrum::Role;

impl Loader {
    pub(super) fn shape(&mut self, el: &Element) -> LoadResult<()> {
        match el.attr("type") {
            Some("shapegroup") => {
                let id = el.required("id")?.to_string();
                let group = self.shape_group(el)?;
                self.shape_groups.insert(id, group);
                Ok(())
            }
            Some("instance") => self.instance(el),
            _ => {
                if let Some(shape) = self.one_shape(el)? {
                    self.shapes.push(shape);
                }
                Ok(())
            }
        }
    }

    /// A `shapegroup`'s shapes, each with its line, read once and placed by each `instance`.
    /// Mitsuba 3 refuses an emitter, a nested `shapegroup` and an `instance` in a group.
    fn shape_group(&mut self, el: &Element) -> LoadResult<Vec<(usize, Shape)>> {
        let mut shapes = Vec::new();
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            if c.name != "shape" {
                return unsupported(c, "shape inside a shapegroup");
            }
            match c.attr("type") {
                Some("shapegroup") => {
                    return fail(
                        c.line,
                        "a shapegroup cannot be nested in a shapegroup (Mitsuba 3 refuses it)",
                    )
                }
                Some("instance") => {
                    return fail(
                        c.line,
                        "an instance cannot be nested in a shapegroup (Mitsuba 3 refuses it)",
                    )
                }
                _ => {}
            }
            if let Some(e) = c.children.iter().find(|e| e.name == "emitter") {
                return fail(e.line,
                    "a shape in a shapegroup cannot be an emitter (Mitsuba 3 does not instance emitters)");
            }
            if let Some(shape) = self.one_shape(c)? {
                shapes.push((c.line, shape));
            }
        }
        Props::new(el)?.finish()?;
        Ok(shapes)
    }

    /// An `instance`: copies of its shapegroup's shapes (a `<ref>` to one defined before, or
    /// one nested in it), each placed by the instance's `to_world` after its own.
    fn instance(&mut self, el: &Element) -> LoadResult<()> {
        let p = Props::new(el)?;
        let to_world = p.transform("to_world")?;
        p.finish()?;
        let mut group: Option<Vec<(usize, Shape)>> = None;
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            if group.is_some() {
                return fail(c.line, "an instance can have only one shapegroup");
            }
            group = Some(match (c.name.as_str(), c.attr("type")) {
                ("ref", _) => {
                    let id = c.required("id")?;
                    let Some(g) = self.shape_groups.get(id) else {
                        return fail(
                            c.line,
                            format!("no shapegroup with id '{id}' is defined before this point"),
                        );
                    };
                    g.clone()
                }
                ("shape", Some("shapegroup")) => self.shape_group(c)?,
                _ => return unsupported(c, "a ref to a shapegroup inside an instance"),
            });
        }
        let Some(group) = group else {
            return fail(
                el.line,
                "an instance needs a <ref id=\"…\"/> to a shapegroup",
            );
        };
        let m3 = Mat3::from_mat4(to_world);
        let scale = similarity_scale(m3);
        let mirrored = m3.determinant() < 0.0;
        for (line, mut shape) in group {
            shape.geometry = match shape.geometry {
                Geometry::Mesh(mut m) => {
                    m.transform(&to_world);
                    // Mitsuba turns an instance's normals as normals (not by the transformed
                    // triangle's winding), so a mirroring instance keeps them pointing out.
                    if mirrored {
                        for f in &mut m.indices {
                            f.swap(1, 2);
                        }
                    }
                    Geometry::Mesh(m)
                }
                Geometry::Sphere(s) => {
                    let Some(scale) = scale else {
                        return fail(
                            el.line,
                            format!(
                                "this instance's to_world does not scale uniformly, so it cannot \
                                 place the sphere of line {line} (an ellipsoid)"
                            ),
                        );
                    };
                    Geometry::Sphere(Sphere {
                        center: to_world.transform_point3(s.center),
                        radius: s.radius * scale,
                        inward: s.inward,
                    })
                }
            };
            self.shapes.push(shape);
        }
        Ok(())
    }

    /// One shape with its material and emission (`None`: a missing mesh left out).
    fn one_shape(&mut self, el: &Element) -> LoadResult<Option<Shape>> {
        let Some(geometry) = self.geometry(el)? else {
            return Ok(None);
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
        Ok(Some(Shape {
            geometry,
            material,
            emission,
        }))
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
                    return fail(
                        el.line,
                        format!("a cylinder's radius = {radius} must be positive"),
                    );
                }
                if !((p1 - p0).length() > 0.0 && (p1 - p0).is_finite()) {
                    return fail(el.line, "a cylinder's p0 and p1 must be distinct points");
                }
                Geometry::Mesh(TriangleMesh::cylinder(p0, p1, radius, &to_world))
            }
            "sphere" => {
                let center = p.point("center", Vec3::ZERO)?;
                let radius = p.float("radius", 1.0)?;
                let Some(scale) = similarity_scale(Mat3::from_mat4(to_world)) else {
                    return fail(el.line, "a sphere's to_world must scale uniformly");
                };
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
                    return fail(c.line, "a shape can have only one bsdf")
                }
                "bsdf" => {
                    let m = self.bsdf(c)?;
                    self.materials.push(m);
                    material = Some(self.materials.len() - 1);
                }
                "ref" => {
                    let id = c.required("id")?;
                    let Some(&i) = self.bsdf_ids.get(id) else {
                        return fail(
                            c.line,
                            format!("no bsdf with id '{id}' is defined before this point"),
                        );
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

/// The scale of a similarity (a rotation, possibly mirrored, times a uniform scale); `None`
/// for any other linear map (a non-uniform scale, a shear), which turns a sphere into an
/// ellipsoid.
fn similarity_scale(m: Mat3) -> Option<f32> {
    let g = m.transpose() * m;
    let s2 = (g.x_axis.x + g.y_axis.y + g.z_axis.z) / 3.0;
    let tol = 2e-4 * s2;
    let off = [g.x_axis.y, g.x_axis.z, g.y_axis.z];
    let diag = [g.x_axis.x, g.y_axis.y, g.z_axis.z];
    let ok = s2 > 0.0
        && s2.is_finite()
        && diag.iter().all(|d| (d - s2).abs() <= tol)
        && off.iter().all(|o| o.abs() <= tol);
    ok.then(|| s2.sqrt())
}
