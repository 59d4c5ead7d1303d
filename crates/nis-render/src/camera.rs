//! The camera, with Mitsuba 3's sensor conventions: the pinhole (`perspective`), the thin lens
//! (`thinlens`, depth of field) and parallel rays (`orthographic`).
//!
//! In camera space the camera looks down +z with +y up and +x to the *left* (Mitsuba's
//! `look_at` builds the frame `(up × dir, up, dir)`), so the image's left column sees local +x.
//! `fov` is the full angle along `fov_axis` (`x` by default); the other axis follows from the
//! image's aspect ratio. A pinhole's rays start at the camera's origin. A thin lens's start on
//! its aperture, a disk of `aperture_radius` at the origin, and pass through the pinhole ray's
//! point at depth z = `focus_distance`, which is in focus. An orthographic camera's rays run
//! along +z from the film, which spans x ∈ [−1, 1] and y ∈ [−h/w, h/w] at z = 0 (its `to_world`
//! scales that, as in Mitsuba). The near clip plane is ignored.

use glam::{Mat4, Vec2, Vec3};

use crate::geometry::Ray;
use crate::sampling::square_to_disk_concentric;

/// How the camera maps the film to rays (Mitsuba's sensor plugins).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Projection {
    /// `perspective`: a pinhole.
    Perspective,
    /// `thinlens`: a lens of `aperture_radius` focused at depth `focus_distance`.
    ThinLens {
        /// Radius of the lens's disk (world units).
        aperture_radius: f32,
        /// Depth (along the view axis) of the plane in focus.
        focus_distance: f32,
    },
    /// `orthographic`: parallel rays.
    Orthographic,
}

/// Which image axis `fov` refers to (Mitsuba's `fov_axis`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FovAxis {
    /// Horizontal.
    X,
    /// Vertical.
    Y,
    /// The image diagonal.
    Diagonal,
    /// The shorter image side.
    Smaller,
    /// The longer image side.
    Larger,
}

/// A pinhole camera for an image of a given resolution.
#[derive(Clone, Debug)]
pub struct Camera {
    /// Camera-to-world transform (may scale or mirror).
    pub to_world: Mat4,
    /// Full field of view in degrees along `fov_axis`.
    pub fov: f32,
    /// Axis `fov` refers to.
    pub fov_axis: FovAxis,
    /// Pinhole, thin lens or parallel rays.
    pub projection: Projection,
    width: u32,
    height: u32,
    tan_x: f32,
    tan_y: f32,
}

impl Camera {
    /// A camera for a `width × height` image.
    pub fn new(to_world: Mat4, fov: f32, fov_axis: FovAxis, width: u32, height: u32) -> Self {
        let mut c = Camera {
            to_world,
            fov,
            fov_axis,
            projection: Projection::Perspective,
            width: 0,
            height: 0,
            tan_x: 0.0,
            tan_y: 0.0,
        };
        c.set_resolution(width, height);
        c
    }

    /// The same camera with another projection (a field of view does not apply to parallel
    /// rays).
    pub fn with_projection(mut self, projection: Projection) -> Self {
        self.projection = projection;
        self.set_resolution(self.width, self.height);
        self
    }

    /// Whether its rays need a sample of the lens ([`Camera::ray`]'s `lens`): a thin lens's.
    pub fn needs_lens(&self) -> bool {
        matches!(self.projection, Projection::ThinLens { .. })
    }

    /// Change the image resolution (the field of view stays on its axis).
    pub fn set_resolution(&mut self, width: u32, height: u32) {
        let (w, h) = (width as f32, height as f32);
        if self.projection == Projection::Orthographic {
            (self.tan_x, self.tan_y) = (1.0, h / w);
            (self.width, self.height) = (width, height);
            return;
        }
        (self.tan_x, self.tan_y) = half_tangents(self.fov, self.fov_axis, w, h);
        self.width = width;
        self.height = height;
    }

    /// Image width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Image height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The primary ray through film position `(x, y)` in pixels (origin top left); `lens` is a
    /// uniform point of the unit square that picks the point on a thin lens (unused by the other
    /// projections, [`Camera::needs_lens`]).
    pub fn ray(&self, x: f32, y: f32, lens: Vec2) -> Ray {
        let sx = 1.0 - 2.0 * x / self.width as f32;
        let sy = 1.0 - 2.0 * y / self.height as f32;
        let local = Vec3::new(sx * self.tan_x, sy * self.tan_y, 1.0);
        let (origin, dir) = match self.projection {
            Projection::Perspective => (Vec3::ZERO, local),
            Projection::ThinLens {
                aperture_radius,
                focus_distance,
            } => {
                let a = aperture_radius * square_to_disk_concentric(lens);
                let aperture = Vec3::new(a.x, a.y, 0.0);
                (aperture, local * focus_distance - aperture)
            }
            Projection::Orthographic => (Vec3::new(local.x, local.y, 0.0), Vec3::Z),
        };
        let origin = self.to_world.transform_point3(origin);
        let dir = self.to_world.transform_vector3(dir).normalize();
        Ray::new(origin, dir)
    }
}

/// Mitsuba's `look_at(origin, target, up)` camera-to-world matrix.
pub fn look_at(origin: Vec3, target: Vec3, up: Vec3) -> Mat4 {
    let dir = (target - origin).normalize();
    let left = up.cross(dir).normalize();
    let new_up = dir.cross(left);
    Mat4::from_cols(
        left.extend(0.0),
        new_up.extend(0.0),
        dir.extend(0.0),
        origin.extend(1.0),
    )
}

/// Tangents of the half field of view along x and y for a `w × h` image whose `fov` (degrees)
/// is taken along `fov_axis` (Mitsuba's `parse_fov`).
pub fn half_tangents(fov: f32, fov_axis: FovAxis, w: f32, h: f32) -> (f32, f32) {
    let t = (0.5 * fov.to_radians()).tan();
    let axis = match fov_axis {
        FovAxis::Smaller if w <= h => FovAxis::X,
        FovAxis::Smaller => FovAxis::Y,
        FovAxis::Larger if w >= h => FovAxis::X,
        FovAxis::Larger => FovAxis::Y,
        a => a,
    };
    match axis {
        FovAxis::X => (t, t * h / w),
        FovAxis::Y => (t * w / h, t),
        _ => {
            let d = (w * w + h * h).sqrt();
            (t * w / d, t * h / d)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_left_is_world_left_and_fov_spans_the_axis() {
        let m = look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0), Vec3::Y);
        let cam = Camera::new(m, 90.0, FovAxis::X, 200, 100);
        let centre = cam.ray(100.0, 50.0, Vec2::ZERO);
        assert!((centre.dir - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        // Looking down -z with +y up, world left is -x; the left edge is 45° off axis.
        let left = cam.ray(0.0, 50.0, Vec2::ZERO).dir;
        assert!((left - Vec3::new(-1.0, 0.0, -1.0).normalize()).length() < 1e-6);
        let top = cam.ray(100.0, 0.0, Vec2::ZERO).dir;
        assert!(top.y > 0.0 && (top.y / -top.z - 0.5).abs() < 1e-6);
    }

    #[test]
    fn a_thin_lens_focuses_every_ray_of_a_pixel_on_one_point_of_the_focal_plane() {
        let m = look_at(Vec3::new(0.0, 1.0, 3.0), Vec3::new(0.0, 1.0, 0.0), Vec3::Y);
        let pinhole = Camera::new(m, 40.0, FovAxis::X, 64, 48);
        let projection = Projection::ThinLens {
            aperture_radius: 0.2,
            focus_distance: 2.5,
        };
        let lens = pinhole.clone().with_projection(projection);
        assert!(lens.needs_lens() && !pinhole.needs_lens());
        let through = pinhole.ray(13.5, 30.25, Vec2::ZERO);
        // The pinhole ray's point at depth 2.5 along the view axis (0, 0, −1).
        let focus = through.origin + through.dir * (2.5 / -through.dir.z);
        for u in [
            Vec2::new(0.1, 0.9),
            Vec2::new(0.5, 0.5),
            Vec2::new(0.97, 0.02),
        ] {
            let r = lens.ray(13.5, 30.25, u);
            assert!((r.dir.length() - 1.0).abs() < 1e-5);
            assert!((r.origin - lens.ray(0.0, 0.0, u).origin).length() < 1e-6);
            assert!((r.origin - through.origin).length() <= 0.2 + 1e-6);
            assert!(
                r.origin.z == 3.0,
                "the aperture lies in the plane of the lens"
            );
            let at = r.origin + r.dir * ((focus.z - r.origin.z) / r.dir.z);
            assert!((at - focus).length() < 1e-4, "{at} {focus}");
        }
        // The lens's centre gives the pinhole's ray.
        let centre = lens.ray(13.5, 30.25, Vec2::splat(0.5));
        assert!((centre.dir - through.dir).length() < 1e-6);
    }

    #[test]
    fn orthographic_rays_are_parallel_and_the_film_spans_two_units_across() {
        let m = look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0), Vec3::Y);
        let cam =
            Camera::new(m, 40.0, FovAxis::X, 200, 100).with_projection(Projection::Orthographic);
        for (x, y) in [(0.0, 0.0), (100.0, 50.0), (200.0, 100.0), (37.0, 81.0)] {
            assert!((cam.ray(x, y, Vec2::ZERO).dir - Vec3::NEG_Z).length() < 1e-6);
        }
        // Looking down −z, the left edge is world −x at 1, the top edge +y at h/w = 1/2.
        assert!(
            (cam.ray(0.0, 50.0, Vec2::ZERO).origin - Vec3::new(-1.0, 0.0, 0.0)).length() < 1e-6
        );
        assert!(
            (cam.ray(100.0, 0.0, Vec2::ZERO).origin - Vec3::new(0.0, 0.5, 0.0)).length() < 1e-6
        );
        // A scaled to_world scales the film, as in Mitsuba.
        let wide = Camera::new(
            m * Mat4::from_scale(Vec3::splat(3.0)),
            40.0,
            FovAxis::X,
            200,
            100,
        )
        .with_projection(Projection::Orthographic);
        assert!((wide.ray(0.0, 50.0, Vec2::ZERO).origin.x + 3.0).abs() < 1e-5);
        assert!((wide.ray(0.0, 50.0, Vec2::ZERO).dir - Vec3::NEG_Z).length() < 1e-6);
    }
}
