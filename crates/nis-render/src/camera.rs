//! The pinhole (perspective) camera, with Mitsuba 3's `perspective` sensor conventions.
//!
//! In camera space the camera looks down +z with +y up and +x to the *left* (Mitsuba's
//! `look_at` builds the frame `(up × dir, up, dir)`), so the image's left column sees local +x.
//! `fov` is the full angle along `fov_axis` (`x` by default); the other axis follows from the
//! image's aspect ratio. Rays start at the camera's origin; the near clip plane is ignored.

use glam::{Mat4, Vec3};

use crate::geometry::Ray;

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
            width: 0,
            height: 0,
            tan_x: 0.0,
            tan_y: 0.0,
        };
        c.set_resolution(width, height);
        c
    }

    /// Change the image resolution (the field of view stays on its axis).
    pub fn set_resolution(&mut self, width: u32, height: u32) {
        let (w, h) = (width as f32, height as f32);
        let t = (0.5 * self.fov.to_radians()).tan();
        let axis = match self.fov_axis {
            FovAxis::Smaller if w <= h => FovAxis::X,
            FovAxis::Smaller => FovAxis::Y,
            FovAxis::Larger if w >= h => FovAxis::X,
            FovAxis::Larger => FovAxis::Y,
            a => a,
        };
        (self.tan_x, self.tan_y) = match axis {
            FovAxis::X => (t, t * h / w),
            FovAxis::Y => (t * w / h, t),
            _ => {
                let d = (w * w + h * h).sqrt();
                (t * w / d, t * h / d)
            }
        };
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

    /// The primary ray through film position `(x, y)` in pixels (origin top left).
    pub fn ray(&self, x: f32, y: f32) -> Ray {
        let sx = 1.0 - 2.0 * x / self.width as f32;
        let sy = 1.0 - 2.0 * y / self.height as f32;
        let local = Vec3::new(sx * self.tan_x, sy * self.tan_y, 1.0);
        let origin = self.to_world.transform_point3(Vec3::ZERO);
        let dir = self.to_world.transform_vector3(local).normalize();
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_left_is_world_left_and_fov_spans_the_axis() {
        let m = look_at(Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0), Vec3::Y);
        let cam = Camera::new(m, 90.0, FovAxis::X, 200, 100);
        let centre = cam.ray(100.0, 50.0);
        assert!((centre.dir - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        // Looking down -z with +y up, world left is -x; the left edge is 45° off axis.
        let left = cam.ray(0.0, 50.0).dir;
        assert!((left - Vec3::new(-1.0, 0.0, -1.0).normalize()).length() < 1e-6);
        let top = cam.ray(100.0, 0.0).dir;
        assert!(top.y > 0.0 && (top.y / -top.z - 0.5).abs() < 1e-6);
    }
}
