//! Orthographic (the paper's case) and perspective cameras, in world coordinates.
//!
//! The JSON form (`--camera-out` / `--camera`) is a contract shared with other renderers:
//! `projection`, `position`, `focal_point`, `view_up`, `parallel_scale` (half the image
//! height in world units), `view_angle` (vertical, degrees), `width`, `height`.
//! Pixel `(i, j)` covers `[i, i+1) × [j, j+1)` with row 0 at the top; its ray goes through
//! the pixel centre.

use std::path::Path;

use glam::DVec3;
use serde::{Deserialize, Serialize};

use crate::volume::Volume;

/// Projection kind.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Projection {
    /// Parallel rays (the paper's case).
    Orthographic,
    /// Rays from the eye.
    Perspective,
}

impl std::str::FromStr for Projection {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "orthographic" | "ortho" => Ok(Projection::Orthographic),
            "perspective" | "persp" => Ok(Projection::Perspective),
            other => Err(format!(
                "unknown projection {other:?}, expected orthographic or perspective"
            )),
        }
    }
}

/// A camera, exactly as written by `--camera-out`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Projection kind.
    pub projection: Projection,
    /// Eye position (orthographic: a point on the image plane's centre line).
    pub position: [f64; 3],
    /// The point looked at.
    pub focal_point: [f64; 3],
    /// Up direction (need not be orthogonal to the view direction).
    pub view_up: [f64; 3],
    /// Half the image height in world units (orthographic).
    pub parallel_scale: f64,
    /// Vertical field of view in degrees (perspective).
    pub view_angle: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
}

/// Errors reading or validating a camera.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CameraError {
    /// The file could not be read.
    #[error("{file}: {err}")]
    Io {
        /// The file.
        file: String,
        /// The error.
        #[source]
        err: std::io::Error,
    },
    /// Not a valid camera JSON.
    #[error("{file}: {err}")]
    Json {
        /// The file.
        file: String,
        /// The parse error.
        #[source]
        err: serde_json::Error,
    },
    /// An orbit angle that is not a finite number of degrees.
    #[error("{what}: got {got}, expected a finite angle in degrees")]
    Angle {
        /// `azimuth` or `elevation`.
        what: &'static str,
        /// The angle given.
        got: f64,
    },
    /// A field is out of range.
    #[error("{file}: {field}: {why}")]
    Field {
        /// The file.
        file: String,
        /// The field.
        field: &'static str,
        /// What is wrong.
        why: String,
    },
}

/// The source that [`CameraError::Field`] names for a camera built by
/// [`Camera::try_orbit`].
pub const ORBIT: &str = "the orbit camera";

/// The source that [`CameraError::Field`] names for a camera handed to a render call rather
/// than read from a file.
pub const GIVEN_CAMERA: &str = "the camera given";

/// An orthonormal view frame.
#[derive(Clone, Copy, Debug)]
pub struct ViewFrame {
    /// Unit view direction (from the eye towards the focal point).
    pub forward: DVec3,
    /// Unit screen x direction.
    pub right: DVec3,
    /// Unit screen y direction (up).
    pub up: DVec3,
}

/// A ray in world space; `dir` has unit length.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Origin.
    pub origin: DVec3,
    /// Unit direction.
    pub dir: DVec3,
}

impl Camera {
    /// A camera orbiting the volume's centre: azimuth about +y from +z, elevation towards
    /// +y, both in degrees, the whole volume fitted in the image.
    #[must_use]
    pub fn orbit(
        volume: &Volume,
        azimuth: f64,
        elevation: f64,
        width: u32,
        height: u32,
        projection: Projection,
    ) -> Self {
        let ext = volume.world_extent().map(f64::from);
        Self::orbit_box(ext, azimuth, elevation, width, height, projection)
    }

    /// As [`Camera::orbit`], with the angles and image size checked first: a non-finite
    /// angle would put every ray at NaN.
    ///
    /// # Errors
    /// [`CameraError::Angle`] for a non-finite azimuth or elevation, [`CameraError::Field`]
    /// (source [`ORBIT`]) for an image size outside 1..=16384 or a volume whose extent makes
    /// no usable view.
    pub fn try_orbit(
        volume: &Volume,
        azimuth: f64,
        elevation: f64,
        width: u32,
        height: u32,
        projection: Projection,
    ) -> Result<Self, CameraError> {
        for (what, got) in [("azimuth", azimuth), ("elevation", elevation)] {
            if !got.is_finite() {
                return Err(CameraError::Angle { what, got });
            }
        }
        let cam = Self::orbit(volume, azimuth, elevation, width, height, projection);
        cam.validate(ORBIT)?;
        Ok(cam)
    }

    /// As [`Camera::orbit`] for a box `[0, extent]`.
    #[must_use]
    pub fn orbit_box(
        extent: [f64; 3],
        azimuth: f64,
        elevation: f64,
        width: u32,
        height: u32,
        projection: Projection,
    ) -> Self {
        let centre = DVec3::from(extent) * 0.5;
        // The bounding sphere fits the volume from every direction, so the framing does not
        // jump while orbiting.
        let radius = (DVec3::from(extent).length() * 0.5).max(1e-3) * 1.02;
        let (az, el) = (
            azimuth.to_radians(),
            elevation.clamp(-90.0, 90.0).to_radians(),
        );
        let dir_to_eye = DVec3::new(el.cos() * az.sin(), el.sin(), el.cos() * az.cos());
        let view_up = if el.cos() < 1e-6 {
            DVec3::new(-az.sin(), 0.0, -az.cos()) * el.sin().signum()
        } else {
            DVec3::Y
        };
        let aspect = f64::from(width.max(1)) / f64::from(height.max(1));
        let view_angle = 30.0_f64;
        let half = (view_angle * 0.5).to_radians();
        let fit = if aspect < 1.0 {
            radius / aspect
        } else {
            radius
        };
        let distance = match projection {
            Projection::Orthographic => 2.0 * radius,
            Projection::Perspective => fit / half.sin(),
        };
        Camera {
            projection,
            position: (centre + dir_to_eye * distance).to_array(),
            focal_point: centre.to_array(),
            view_up: view_up.to_array(),
            parallel_scale: fit,
            view_angle,
            width,
            height,
        }
    }

    /// Reads and validates a camera JSON file.
    ///
    /// # Errors
    /// [`CameraError`] naming the file and field.
    pub fn from_file(path: &Path) -> Result<Self, CameraError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|err| CameraError::Io {
            file: file.clone(),
            err,
        })?;
        Self::from_json(&text, &file)
    }

    /// Parses and validates camera JSON text; `file` names it in errors.
    ///
    /// # Errors
    /// [`CameraError::Json`] or [`CameraError::Field`] naming `file`.
    pub fn from_json(text: &str, file: &str) -> Result<Self, CameraError> {
        let cam: Camera = serde_json::from_str(text).map_err(|err| CameraError::Json {
            file: file.to_string(),
            err,
        })?;
        cam.validate(file)?;
        Ok(cam)
    }

    /// Checks that the camera defines a usable view.
    ///
    /// # Errors
    /// [`CameraError::Field`] for a non-finite number in any field, zero image size,
    /// coincident eye and focal point, a zero up vector or one parallel to the view, a
    /// non-positive scale or an angle outside (0, 180).
    pub fn validate(&self, file: &str) -> Result<(), CameraError> {
        let bad = |field, why: &str| {
            Err(CameraError::Field {
                file: file.to_string(),
                field,
                why: why.to_string(),
            })
        };
        if self.width == 0 || self.height == 0 || self.width > 16384 || self.height > 16384 {
            return bad("width", "image size must be 1..=16384 on each side");
        }
        for (field, v) in [
            ("position", self.position),
            ("focal_point", self.focal_point),
            ("view_up", self.view_up),
        ] {
            if v.iter().any(|x| !x.is_finite()) {
                return bad(field, "must be three finite numbers");
            }
        }
        for (field, x) in [
            ("parallel_scale", self.parallel_scale),
            ("view_angle", self.view_angle),
        ] {
            if !x.is_finite() {
                return bad(field, "must be a finite number");
            }
        }
        let f = DVec3::from(self.focal_point) - DVec3::from(self.position);
        // The difference of two finite points can still overflow to infinity.
        if !(f.is_finite() && f.length().is_finite()) {
            return bad("position", "is too far from focal_point");
        }
        if f.length() < 1e-9 {
            return bad("position", "must differ from focal_point");
        }
        let up = DVec3::from(self.view_up);
        if !up.is_finite() || up.length() < 1e-12 {
            return bad("view_up", "must not be zero");
        }
        if f.normalize().cross(up.normalize()).length() < 1e-9 {
            return bad("view_up", "must not be parallel to the view direction");
        }
        if self.projection == Projection::Orthographic && self.parallel_scale <= 0.0 {
            return bad("parallel_scale", "must be > 0");
        }
        if self.projection == Projection::Perspective
            && !(self.view_angle > 0.0 && self.view_angle < 180.0)
        {
            return bad("view_angle", "must be in (0, 180) degrees");
        }
        Ok(())
    }

    /// Serialises as pretty JSON.
    #[must_use]
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a camera always serialises")
    }

    /// The orthonormal frame of the view.
    #[must_use]
    pub fn frame(&self) -> ViewFrame {
        let forward = (DVec3::from(self.focal_point) - DVec3::from(self.position)).normalize();
        let right = forward.cross(DVec3::from(self.view_up)).normalize();
        let up = right.cross(forward);
        ViewFrame { forward, right, up }
    }

    fn aspect(&self) -> f64 {
        f64::from(self.width) / f64::from(self.height)
    }

    fn half_height(&self) -> f64 {
        match self.projection {
            Projection::Orthographic => self.parallel_scale,
            Projection::Perspective => (self.view_angle * 0.5).to_radians().tan(),
        }
    }

    /// The ray through continuous pixel position `(x, y)`; pixel centres are at `i + 0.5`.
    #[must_use]
    pub fn ray(&self, frame: &ViewFrame, x: f64, y: f64) -> Ray {
        let h = self.half_height();
        let u = (x / f64::from(self.width) * 2.0 - 1.0) * h * self.aspect();
        let v = (1.0 - y / f64::from(self.height) * 2.0) * h;
        let eye = DVec3::from(self.position);
        match self.projection {
            Projection::Orthographic => Ray {
                origin: eye + frame.right * u + frame.up * v,
                dir: frame.forward,
            },
            Projection::Perspective => Ray {
                origin: eye,
                dir: (frame.forward + frame.right * u + frame.up * v).normalize(),
            },
        }
    }

    /// Projects world point `p` to continuous pixel coordinates and its depth along the
    /// view; `None` when it is at or behind a perspective eye.
    #[must_use]
    pub fn project(&self, frame: &ViewFrame, p: DVec3) -> Option<(f64, f64, f64)> {
        let d = p - DVec3::from(self.position);
        let depth = d.dot(frame.forward);
        let (mut u, mut v) = (d.dot(frame.right), d.dot(frame.up));
        if self.projection == Projection::Perspective {
            if depth <= 1e-9 {
                return None;
            }
            u /= depth;
            v /= depth;
        }
        let h = self.half_height();
        let x = (u / (h * self.aspect()) + 1.0) * 0.5 * f64::from(self.width);
        let y = (1.0 - v / h) * 0.5 * f64::from(self.height);
        Some((x, y, depth))
    }

    /// Pixel rectangle `[x0, x1) × [y0, y1)` whose centres may see the world box
    /// `[lo, hi]`, clipped to the image; `None` when it is off-screen. Conservative: it
    /// contains every pixel whose ray meets the box.
    #[must_use]
    pub fn footprint(&self, frame: &ViewFrame, lo: DVec3, hi: DVec3) -> Option<PixelRect> {
        let (mut x0, mut y0, mut x1, mut y1) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for c in 0..8 {
            let p = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            let Some((x, y, _)) = self.project(frame, p) else {
                // A corner behind the eye: the box may cover any part of the image.
                return Some(PixelRect {
                    x0: 0,
                    y0: 0,
                    x1: self.width,
                    y1: self.height,
                });
            };
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x);
            y1 = y1.max(y);
        }
        PixelRect::covering(x0, y0, x1, y1, self.width, self.height)
    }
}

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct PixelRect {
    /// First column.
    pub x0: u32,
    /// First row.
    pub y0: u32,
    /// One past the last column.
    pub x1: u32,
    /// One past the last row.
    pub y1: u32,
}

impl PixelRect {
    /// The pixels whose centres lie in the continuous rectangle, widened by a hair so that
    /// centres on the edge are kept; `None` when empty.
    #[must_use]
    pub fn covering(x0: f64, y0: f64, x1: f64, y1: f64, width: u32, height: u32) -> Option<Self> {
        let eps = 1e-3;
        let fx0 = (x0 - 0.5 - eps).ceil().max(0.0);
        let fy0 = (y0 - 0.5 - eps).ceil().max(0.0);
        let fx1 = (x1 - 0.5 + eps).floor() + 1.0;
        let fy1 = (y1 - 0.5 + eps).floor() + 1.0;
        let r = PixelRect {
            x0: fx0.min(f64::from(width)) as u32,
            y0: fy0.min(f64::from(height)) as u32,
            x1: fx1.clamp(0.0, f64::from(width)) as u32,
            y1: fy1.clamp(0.0, f64::from(height)) as u32,
        };
        (r.x0 < r.x1 && r.y0 < r.y1).then_some(r)
    }

    /// Width in pixels.
    #[must_use]
    pub fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    /// Height in pixels.
    #[must_use]
    pub fn height(&self) -> u32 {
        self.y1 - self.y0
    }

    /// Number of pixels.
    #[must_use]
    pub fn area(&self) -> usize {
        self.width() as usize * self.height() as usize
    }

    /// The overlap with `other`, if any.
    #[must_use]
    pub fn intersect(&self, other: &PixelRect) -> Option<PixelRect> {
        let r = PixelRect {
            x0: self.x0.max(other.x0),
            y0: self.y0.max(other.y0),
            x1: self.x1.min(other.x1),
            y1: self.y1.min(other.y1),
        };
        (r.x0 < r.x1 && r.y0 < r.y1).then_some(r)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn projection_inverts_the_ray_through_a_pixel_centre() {
        for projection in [Projection::Orthographic, Projection::Perspective] {
            let cam = Camera::orbit_box([63.0, 40.0, 92.0], 33.0, -21.0, 120, 80, projection);
            let f = cam.frame();
            let r = cam.ray(&f, 17.5, 61.5);
            let p = r.origin + r.dir * (cam.position[0] - cam.focal_point[0]).abs().max(50.0);
            let (x, y, _) = cam.project(&f, p).unwrap();
            assert!(
                (x - 17.5).abs() < 1e-6 && (y - 61.5).abs() < 1e-6,
                "{projection:?}: {x} {y}"
            );
        }
    }

    #[test]
    fn whole_volume_is_in_view_from_any_angle() {
        for projection in [Projection::Orthographic, Projection::Perspective] {
            for (az, el) in [(0.0, 0.0), (45.0, 30.0), (190.0, -89.0), (0.0, 90.0)] {
                let cam = Camera::orbit_box([100.0, 50.0, 70.0], az, el, 64, 48, projection);
                cam.validate("t").unwrap();
                let f = cam.frame();
                for c in 0..8 {
                    let p = DVec3::new(
                        if c & 1 == 0 { 0.0 } else { 100.0 },
                        if c & 2 == 0 { 0.0 } else { 50.0 },
                        if c & 4 == 0 { 0.0 } else { 70.0 },
                    );
                    let (x, y, d) = cam.project(&f, p).unwrap();
                    assert!(
                        d > 0.0 && (0.0..=64.0).contains(&x) && (0.0..=48.0).contains(&y),
                        "{az},{el}: {x},{y}"
                    );
                }
            }
        }
    }

    #[test]
    fn json_round_trip_uses_the_contract_field_names() {
        let cam = Camera::orbit_box(
            [10.0, 10.0, 10.0],
            10.0,
            20.0,
            32,
            16,
            Projection::Perspective,
        );
        let j = cam.to_json();
        for key in [
            "projection",
            "position",
            "focal_point",
            "view_up",
            "parallel_scale",
            "view_angle",
            "width",
            "height",
        ] {
            assert!(j.contains(&format!("\"{key}\"")), "{key} missing in {j}");
        }
        assert!(j.contains("\"perspective\""));
        let back: Camera = serde_json::from_str(&j).unwrap();
        assert_eq!(back, cam);
    }

    #[test]
    fn non_finite_angles_and_fields_are_rejected_naming_them() {
        let vol = crate::volume::phantom::Phantom::SheppLogan.generate(8);
        for (az, el, what) in [
            (f64::NAN, 0.0, "azimuth"),
            (0.0, f64::INFINITY, "elevation"),
        ] {
            let e = Camera::try_orbit(&vol, az, el, 8, 8, Projection::Orthographic).unwrap_err();
            assert!(
                matches!(e, CameraError::Angle { what: w, .. } if w == what),
                "{e}"
            );
            assert!(!e.to_string().contains("--"), "{e}");
        }
        let good = Camera::try_orbit(&vol, 10.0, 95.0, 8, 8, Projection::Orthographic).unwrap();
        let field_of = |c: &Camera| match c.validate("f") {
            Err(CameraError::Field { field, .. }) => field,
            other => panic!("{other:?}"),
        };
        let mut c = good.clone();
        c.position[1] = f64::NAN;
        assert_eq!(field_of(&c), "position");
        let mut c = good.clone();
        c.view_up = [0.0; 3];
        assert_eq!(field_of(&c), "view_up");
        let mut c = good.clone();
        c.view_up = (DVec3::from(good.focal_point) - DVec3::from(good.position)).to_array();
        assert_eq!(field_of(&c), "view_up");
        let mut c = good.clone();
        c.parallel_scale = f64::INFINITY;
        assert_eq!(field_of(&c), "parallel_scale");
        let mut c = good.clone();
        c.view_angle = f64::NAN;
        assert_eq!(field_of(&c), "view_angle");
        let mut c = good;
        c.parallel_scale = -1.0;
        assert_eq!(field_of(&c), "parallel_scale");
    }
}
