//! A pinhole camera: eye, look-at point, up vector and vertical field of view, with
//! the aspect ratio taken from the image size. Rays go through pixel centres; pixel
//! row 0 is the top row of the image.

use glam::Vec3;

use crate::error::{Error, Result};
use crate::geometry::{Aabb, Ray};

#[derive(Clone, Copy, Debug)]
pub struct Camera {
    pub eye: Vec3,
    /// Direction to the centre of the top-left pixel corner of the image plane at distance 1.
    corner: Vec3,
    /// One pixel step to the right on the image plane.
    step_x: Vec3,
    /// One pixel step down on the image plane.
    step_y: Vec3,
}

impl Camera {
    /// `fov_deg` is the vertical field of view in degrees, in (0, 180).
    /// Errors name the flag a user would have set: `--eye`/`--look` when they
    /// coincide, `--up` when it is parallel to the view direction.
    pub fn new(
        eye: Vec3,
        look: Vec3,
        up: Vec3,
        fov_deg: f32,
        width: u32,
        height: u32,
    ) -> Result<Camera> {
        if !(eye.is_finite() && look.is_finite() && up.is_finite()) {
            return Err(Error::usage("--eye/--look/--up", "values must be finite"));
        }
        if !(fov_deg > 0.0 && fov_deg < 180.0) {
            return Err(Error::usage(
                "--fov",
                format!("{fov_deg} is outside (0, 180) degrees"),
            ));
        }
        if width == 0 || height == 0 {
            return Err(Error::usage(
                "--size",
                "width and height must be at least 1",
            ));
        }
        let narrowest = narrowest_fov_deg(height);
        if fov_deg < narrowest {
            return Err(Error::usage(
                "--fov",
                format!("{fov_deg} degrees is narrower than f32 rays resolve at {height} pixels tall (neighbouring pixels' directions would round together); the narrowest is {narrowest:.4}"),
            ));
        }
        let forward = (look - eye).normalize_or_zero();
        if forward == Vec3::ZERO {
            return Err(Error::usage("--look", "look-at point equals the eye"));
        }
        let right = forward.cross(up).normalize_or_zero();
        if right == Vec3::ZERO {
            return Err(Error::usage(
                "--up",
                "up vector is zero or parallel to the view direction",
            ));
        }
        let true_up = right.cross(forward);
        let half_h = (fov_deg.to_radians() * 0.5).tan();
        let half_w = half_h * width as f32 / height as f32;
        let step_x = right * (2.0 * half_w / width as f32);
        let step_y = -true_up * (2.0 * half_h / height as f32);
        let corner = forward - right * half_w + true_up * half_h;
        Ok(Camera {
            eye,
            corner,
            step_x,
            step_y,
        })
    }

    /// The primary ray through the centre of pixel (`x`, `y`), `y = 0` at the top.
    /// Its direction is normalised, so `t` is a distance.
    #[inline]
    pub fn ray(&self, x: u32, y: u32) -> Ray {
        let d = self.corner + self.step_x * (x as f32 + 0.5) + self.step_y * (y as f32 + 0.5);
        Ray::new(self.eye, d.normalize())
    }
}

/// The smallest step between neighbouring pixels' directions, relative to
/// the forward one (of length 1) they are offsets from: 2^-20, 16 f32 steps
/// of it, so pixels stay apart to a sixteenth of a pixel.
const MIN_PIXEL_STEP: f32 = 1.0 / (1u32 << 20) as f32;

/// The narrowest half-angle the framing of a default view computes with.
const FRAMING_MIN_HALF_ANGLE: f32 = 1e-4;

/// The narrowest vertical field of view, in degrees, an image `height`
/// pixels tall is rendered with: neighbouring pixels' directions apart by at
/// least [`MIN_PIXEL_STEP`] (at `--fov 1e-6` a 48-pixel image was a sliver,
/// its rays rounded onto a few directions), and no narrower than the
/// framing's [`FRAMING_MIN_HALF_ANGLE`] (below it a default view was framed
/// for a wider lens and cropped the scene).
pub fn narrowest_fov_deg(height: u32) -> f32 {
    let half = (height as f32 * 0.5 * MIN_PIXEL_STEP)
        .atan()
        .max(FRAMING_MIN_HALF_ANGLE);
    (2.0 * half).to_degrees()
}

/// The direction, from the scene's centre, of the default view of a scene that
/// is not a built-in box, in the frame of [`crate::scene::light::frame_axes`]:
/// mostly from the front, a little from the right and from above.
pub const FRAMING_DIRECTION: [f32; 3] = [0.5, 0.4, 1.0];

/// Part of the image's half-width and half-height left free around the
/// framed bounding box.
pub const FRAMING_MARGIN: f32 = 0.05;

/// The default view of a scene (the rule in docs/reference.md): look at the centre of the
/// bounding box of `points` from [`FRAMING_DIRECTION`] (right, up, front), at
/// the smallest distance where every point lies inside the image with a margin
/// of [`FRAMING_MARGIN`] of its half-size (and the eye outside the bounding
/// sphere). Returns (eye, look); `points` must not be empty.
pub fn framing(
    points: impl Iterator<Item = Vec3> + Clone,
    up: Vec3,
    fov_deg: f32,
    width: u32,
    height: u32,
) -> (Vec3, Vec3) {
    let bounds = points.clone().fold(Aabb::EMPTY, Aabb::grown);
    let (up, front, right) = crate::scene::light::frame_axes(up);
    let [r, u, f] = FRAMING_DIRECTION;
    let dir = (right * r + up * u + front * f).normalize();
    let look = bounds.center();
    // The camera's own basis, as Camera::new makes it.
    let forward = -dir;
    let cam_right = forward.cross(up).normalize();
    let cam_up = cam_right.cross(forward);
    let half_v = (fov_deg.to_radians() * 0.5).clamp(FRAMING_MIN_HALF_ANGLE, 1.55);
    let tan_v = half_v.tan() * (1.0 - FRAMING_MARGIN);
    let tan_h = half_v.tan() * width as f32 / height.max(1) as f32 * (1.0 - FRAMING_MARGIN);
    // A point at offset c from the centre lies at depth dist - c.dir in front of
    // the eye and c.right to its side: inside when |c.right| <= tan_h * depth.
    let mut dist = f32::MIN_POSITIVE;
    for p in points {
        let c = p - look;
        let along = c.dot(dir);
        dist = dist
            .max(along + c.dot(cam_right).abs() / tan_h)
            .max(along + c.dot(cam_up).abs() / tan_v);
    }
    // Never inside the scene, even for a flat one seen edge-on (the diagonal
    // in f64: its square overflows f32 from about 1e19).
    let extent = (bounds.max - bounds.min).max(Vec3::ZERO);
    dist = dist.max((0.5 * extent.as_dvec3().length() * 1.01) as f32);
    (look + dir * dist, look)
}

/// The eye and look-at point: the given ones, else the study's view for a
/// built-in box, else the framing of the scene's bounds. A `look` given
/// without an `eye` is a target: the camera stays where it would stand and
/// turns towards it (as Embree's tutorials, pbrt and Mitsuba read a look-at
/// point).
pub fn default_view(
    scene: &crate::scene::Scene,
    eye: Option<Vec3>,
    look: Option<Vec3>,
    up: Vec3,
    fov: f32,
    (width, height): (u32, u32),
) -> (Vec3, Vec3) {
    let (framed_eye, framed_look) = if scene.study_frame {
        (Vec3::new(0.0, 1.0, 3.0), Vec3::new(0.0, 1.0, 0.0))
    } else {
        match scene.framed_corners() {
            Some(corners) => framing(corners.into_iter(), up, fov, width, height),
            None => {
                let points = scene
                    .triangles
                    .iter()
                    .flatten()
                    .map(|&i| scene.positions[i as usize]);
                framing(points, up, fov, width, height)
            }
        }
    };
    match (eye, look) {
        (Some(e), Some(l)) => (e, l),
        (Some(e), None) => (e, framed_look),
        (None, Some(l)) => (framed_eye, l),
        (None, None) => (framed_eye, framed_look),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn study_camera(w: u32, h: u32) -> Camera {
        Camera::new(
            Vec3::new(0.0, 1.0, 3.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::Y,
            60.0,
            w,
            h,
        )
        .unwrap()
    }

    #[test]
    fn centre_pixel_looks_at_the_target() {
        // Odd size so a pixel centre lies on the optical axis.
        let c = study_camera(101, 51);
        let r = c.ray(50, 25);
        assert!((r.dir - Vec3::new(0.0, 0.0, -1.0)).length() < 1e-6);
        assert_eq!(r.origin, Vec3::new(0.0, 1.0, 3.0));
    }

    #[test]
    fn top_row_looks_up_and_left_column_looks_left() {
        let c = study_camera(64, 48);
        let top = c.ray(32, 0);
        assert!(top.dir.y > 0.0);
        // The top pixel centre is half a pixel inside the 30-degree half angle.
        let angle = top.dir.y.atan2(-top.dir.z).to_degrees();
        let expected = ((30f32.to_radians().tan()) * (1.0 - 1.0 / 48.0))
            .atan()
            .to_degrees();
        assert!((angle - expected).abs() < 1e-3, "{angle} vs {expected}");
        assert!(c.ray(0, 24).dir.x < 0.0);
        assert!(c.ray(63, 24).dir.x > 0.0);
    }

    #[test]
    fn aspect_comes_from_the_image_size() {
        let c = study_camera(200, 100);
        let right = c.ray(199, 50).dir;
        let half_w = 2.0 * 30f32.to_radians().tan() * (1.0 - 1.0 / 200.0);
        assert!((right.x / -right.z - half_w).abs() < 1e-3);
    }

    #[test]
    fn framing_fits_every_point_into_the_image() {
        let b = Aabb::EMPTY
            .grown(Vec3::new(10.0, -3.0, 100.0))
            .grown(Vec3::new(14.0, 5.0, 101.0));
        let corners: Vec<Vec3> = (0..8)
            .map(|k| {
                Vec3::new(
                    if k & 1 == 0 { b.min.x } else { b.max.x },
                    if k & 2 == 0 { b.min.y } else { b.max.y },
                    if k & 4 == 0 { b.min.z } else { b.max.z },
                )
            })
            .collect();
        for (w, h) in [(64, 48), (48, 64), (100, 100)] {
            let (eye, look) = framing(corners.iter().copied(), Vec3::Y, 60.0, w, h);
            assert_eq!(look, b.center());
            assert!(eye.z > look.z && eye.y > look.y && eye.x > look.x, "{eye}");
            // Project the corners with the camera's own rays' basis: the centre
            // pixel's direction and the corner pixels' spread.
            let forward = (look - eye).normalize();
            let right = forward.cross(Vec3::Y).normalize();
            let up = right.cross(forward);
            let tan_v = 30f32.to_radians().tan();
            let tan_h = tan_v * w as f32 / h as f32;
            let mut widest: f32 = 0.0;
            for (k, corner) in corners.iter().enumerate() {
                let c = *corner - eye;
                let depth = c.dot(forward);
                assert!(depth > 0.0);
                let (x, y) = (c.dot(right) / depth / tan_h, c.dot(up) / depth / tan_v);
                assert!(
                    x.abs() <= 0.951 && y.abs() <= 0.951,
                    "{w}x{h}: corner {k} at ({x}, {y})"
                );
                widest = widest.max(x.abs()).max(y.abs());
            }
            // And as close as that allows: one corner on the margin.
            assert!(widest > 0.94, "{w}x{h}: widest corner at {widest}");
        }
    }

    #[test]
    fn bad_parameters_name_their_flag() {
        let e = Vec3::new(0.0, 1.0, 3.0);
        let l = Vec3::new(0.0, 1.0, 0.0);
        for (fov, height) in [(0.04, 768), (0.01, 48), (1e-6, 48)] {
            let err = Camera::new(e, l, Vec3::Y, fov, height, height).unwrap_err();
            assert!(
                err.to_string().starts_with("--fov") && err.to_string().contains("narrowest"),
                "{err}"
            );
        }
        assert!(Camera::new(e, l, Vec3::Y, 0.05, 1024, 768).is_ok());
        assert!(Camera::new(e, l, Vec3::Y, 0.012, 64, 48).is_ok());
        for fov in [0.0, 180.0, -5.0, f32::NAN] {
            let err = Camera::new(e, l, Vec3::Y, fov, 10, 10).unwrap_err();
            assert!(err.to_string().starts_with("--fov"), "{err}");
        }
        assert!(Camera::new(e, e, Vec3::Y, 60.0, 10, 10)
            .unwrap_err()
            .to_string()
            .starts_with("--look"));
        assert!(Camera::new(e, l, Vec3::Z, 60.0, 10, 10)
            .unwrap_err()
            .to_string()
            .starts_with("--up"));
        assert!(Camera::new(e, l, Vec3::Y, 60.0, 0, 10)
            .unwrap_err()
            .to_string()
            .starts_with("--size"));
    }

    #[test]
    fn a_look_without_an_eye_turns_the_camera_and_keeps_it_in_place() {
        for name in ["cornell-empty", "mesh:200"] {
            let scene = crate::scene::builtin::builtin(name).unwrap();
            let (eye, look) = default_view(&scene, None, None, Vec3::Y, 60.0, (64, 48));
            let target = look + Vec3::new(0.25, -0.5, 0.125);
            let (eye2, look2) = default_view(&scene, None, Some(target), Vec3::Y, 60.0, (64, 48));
            assert_eq!((eye2, look2), (eye, target), "{name}");
        }
    }
}
