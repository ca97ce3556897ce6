//! Pinhole orbit camera looking at the volume's box centre, with a 45° vertical view angle.
//!
//! Orbit parameters follow the paper (Appendix A): yaw around the up axis, pitch (elevation)
//! away from the plane perpendicular to it, and distance as a multiple of the box's bounding
//! radius. The default up axis is **z**: medical scans (the main use) are stored as stacks of
//! axial slices, so z runs head to feet and an orbit around z shows the patient upright; for
//! simulation fields any axis is as good. `--up x|y|-x|-y|-z` is there for volumes stored
//! otherwise (`-z` when the slices run from the top of the head down).
//!
//! The same camera is ParaView's CameraPosition / FocalPoint / ViewUp / ViewAngle
//! ([`Camera::paraview`]); ParaView's view angle is vertical, as ours.

use std::f64::consts::{PI, TAU};
use std::fmt;
use std::str::FromStr;

use glam::DVec3;
use rand::Rng;

use t2tf_volume::Geometry;

/// Vertical field of view in degrees (docs/DESIGN.md "Camera"; written into pvpython scripts).
pub(crate) const VIEW_ANGLE_DEG: f64 = 45.0;

/// The paper's random-view ranges (Appendix A).
pub const PITCH_RANGE: f64 = PI / 14.0;
/// The camera distances of the paper's random views, in bounding radii.
pub const DISTANCE_RANGE: [f64; 2] = [2.0, 4.0];

#[derive(Debug, thiserror::Error)]
/// Why a camera could not be made.
pub enum CameraError {
    #[error("unknown up axis `{0}`: expected x, y, z, -x, -y or -z")]
    /// The up axis is not one of x, y, z, -x, -y, -z.
    UpAxis(String),
    #[error("camera {what} {value} is not allowed: {why}")]
    /// A camera parameter is out of range.
    Param {
        /// Which parameter.
        what: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        why: &'static str,
    },
}

impl CameraError {
    /// What a front end needs to word its advice.
    pub fn hint(&self) -> t2tf_core::error::Hint {
        match self {
            CameraError::UpAxis(_) => t2tf_core::error::Hint::invalid("up"),
            CameraError::Param { .. } => t2tf_core::error::Hint::other(),
        }
    }
}

/// World axis that points up on screen; the orbit turns around it. The negative axes are for
/// data stored upside down (e.g. a CT stacked from the top of the head down, like the shared
/// `cthead`, shows the head upright with `-z`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum UpAxis {
    /// +x is up.
    X,
    /// +y is up.
    Y,
    #[default]
    /// +z is up.
    Z,
    /// −x is up.
    NegX,
    /// −y is up.
    NegY,
    /// −z is up.
    NegZ,
}

impl UpAxis {
    /// (up, e1, e2): a right-handed frame with `e1 × e2 = up`; yaw 0 looks from `+e1`.
    fn frame(self) -> (DVec3, DVec3, DVec3) {
        match self {
            UpAxis::X => (DVec3::X, DVec3::Y, DVec3::Z),
            UpAxis::Y => (DVec3::Y, DVec3::Z, DVec3::X),
            UpAxis::Z => (DVec3::Z, DVec3::X, DVec3::Y),
            UpAxis::NegX => (DVec3::NEG_X, DVec3::Z, DVec3::Y),
            UpAxis::NegY => (DVec3::NEG_Y, DVec3::X, DVec3::Z),
            UpAxis::NegZ => (DVec3::NEG_Z, DVec3::Y, DVec3::X),
        }
    }
}

impl FromStr for UpAxis {
    type Err = CameraError;
    fn from_str(s: &str) -> Result<Self, CameraError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "x" | "+x" => Ok(UpAxis::X),
            "y" | "+y" => Ok(UpAxis::Y),
            "z" | "+z" => Ok(UpAxis::Z),
            "-x" => Ok(UpAxis::NegX),
            "-y" => Ok(UpAxis::NegY),
            "-z" => Ok(UpAxis::NegZ),
            _ => Err(CameraError::UpAxis(s.to_string())),
        }
    }
}

impl fmt::Display for UpAxis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            UpAxis::X => "x",
            UpAxis::Y => "y",
            UpAxis::Z => "z",
            UpAxis::NegX => "-x",
            UpAxis::NegY => "-y",
            UpAxis::NegZ => "-z",
        })
    }
}

/// Orbit parameters: angles in radians, distance in bounding radii.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// Angle around the up axis, radians.
    pub yaw: f64,
    /// Angle above the horizontal plane, radians.
    pub pitch: f64,
    /// Distance from the box centre, in bounding radii.
    pub distance: f64,
    /// Which world axis is up.
    pub up: UpAxis,
}

impl Orbit {
    /// The paper's random view: yaw in [0, 2π), pitch in [−π/14, π/14], distance in [2, 4].
    pub fn random<R: Rng + ?Sized>(up: UpAxis, rng: &mut R) -> Orbit {
        Orbit {
            yaw: rng.random_range(0.0..TAU),
            pitch: rng.random_range(-PITCH_RANGE..=PITCH_RANGE),
            distance: rng.random_range(DISTANCE_RANGE[0]..=DISTANCE_RANGE[1]),
            up,
        }
    }
}

/// A pinhole camera in world space. `view_up` is unit length and orthogonal to the view
/// direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// The eye, in world coordinates.
    pub position: DVec3,
    /// The point looked at.
    pub focal_point: DVec3,
    /// The up direction of the image.
    pub view_up: DVec3,
    /// Vertical field of view, degrees.
    pub view_angle_deg: f64,
}

/// ParaView's four camera properties (what a pvpython script sets).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParaViewCamera {
    /// The eye, in world coordinates.
    pub position: [f64; 3],
    /// The point looked at.
    pub focal_point: [f64; 3],
    /// The up direction of the image.
    pub view_up: [f64; 3],
    /// Vertical view angle, degrees.
    pub view_angle: f64,
}

impl ParaViewCamera {
    /// Looking at the box's centre along −y from `distance` bounding radii, z up, 45°: the
    /// view the generated scripts open with when no orbit view is given.
    pub fn front(geometry: &t2tf_volume::Geometry, distance: f64) -> ParaViewCamera {
        let c = geometry.center();
        let r = geometry.bounding_radius();
        ParaViewCamera {
            position: [c[0], c[1] - distance * r, c[2]],
            focal_point: c,
            view_up: [0.0, 0.0, 1.0],
            view_angle: VIEW_ANGLE_DEG,
        }
    }
}

/// Per-image ray set-up: a pixel's ray is `origin + t * dir(px, py)`, `t` in world units.
#[derive(Clone, Copy, Debug)]
pub struct RayFrame {
    /// The eye, in world coordinates.
    pub origin: DVec3,
    forward: DVec3,
    right: DVec3,
    up: DVec3,
    /// tan(fov/2) * 2 / height: world width of a pixel at unit distance.
    pixel: f64,
    half_w: f64,
    half_h: f64,
}

impl RayFrame {
    /// Unit direction through the centre of pixel (px, py); py = 0 is the top row.
    #[inline]
    pub fn dir(&self, px: usize, py: usize) -> DVec3 {
        let u = (px as f64 + 0.5 - self.half_w) * self.pixel;
        let v = (self.half_h - (py as f64 + 0.5)) * self.pixel;
        (self.forward + u * self.right + v * self.up).normalize()
    }
}

impl Camera {
    /// Camera on an orbit around the box centre of `geometry`.
    pub fn orbit(geometry: &Geometry, orbit: Orbit) -> Result<Camera, CameraError> {
        let param = |what, value: f64, why| CameraError::Param { what, value, why };
        if !orbit.yaw.is_finite() {
            return Err(param("yaw", orbit.yaw, "must be finite"));
        }
        if orbit.pitch.is_nan() || orbit.pitch.abs() >= 0.5 * PI - 1e-6 {
            return Err(param(
                "pitch",
                orbit.pitch,
                "must lie strictly between -90° and 90° (the view up would be undefined)",
            ));
        }
        if !(orbit.distance.is_finite() && orbit.distance > 0.0) {
            return Err(param("distance", orbit.distance, "must be positive"));
        }
        let (up, e1, e2) = orbit.up.frame();
        let centre = DVec3::from_array(geometry.center());
        let horizontal = orbit.yaw.cos() * e1 + orbit.yaw.sin() * e2;
        let dir = orbit.pitch.cos() * horizontal + orbit.pitch.sin() * up;
        let position = centre + orbit.distance * geometry.bounding_radius() * dir;
        // Orthogonalize the up axis against the view direction (ParaView does the same).
        let view_up = (up - up.dot(dir) * dir).normalize();
        Ok(Camera {
            position,
            focal_point: centre,
            view_up,
            view_angle_deg: VIEW_ANGLE_DEG,
        })
    }

    /// The paper's random view for `geometry`.
    pub fn random<R: Rng + ?Sized>(geometry: &Geometry, up: UpAxis, rng: &mut R) -> Camera {
        Camera::orbit(geometry, Orbit::random(up, rng))
            .expect("random orbit parameters are always valid")
    }

    /// `n` views evenly spaced in yaw at the given pitch and distance (an orbit sheet).
    pub fn ring(
        geometry: &Geometry,
        n: usize,
        pitch: f64,
        distance: f64,
        up: UpAxis,
    ) -> Result<Vec<Camera>, CameraError> {
        (0..n)
            .map(|i| {
                let yaw = TAU * i as f64 / n as f64;
                Camera::orbit(
                    geometry,
                    Orbit {
                        yaw,
                        pitch,
                        distance,
                        up,
                    },
                )
            })
            .collect()
    }

    /// The same camera in ParaView's terms.
    pub fn paraview(&self) -> ParaViewCamera {
        ParaViewCamera {
            position: self.position.to_array(),
            focal_point: self.focal_point.to_array(),
            view_up: self.view_up.to_array(),
            view_angle: self.view_angle_deg,
        }
    }

    /// Distance from the eye to the focal point.
    pub fn distance(&self) -> f64 {
        (self.focal_point - self.position).length()
    }

    /// World size of one pixel at the focal point for an image `height` pixels tall.
    pub fn pixel_footprint(&self, height: usize) -> f64 {
        2.0 * self.distance() * (0.5 * self.view_angle_deg.to_radians()).tan()
            / height.max(1) as f64
    }

    /// Ray set-up for a `width` × `height` image.
    pub fn rays(&self, width: usize, height: usize) -> RayFrame {
        let forward = (self.focal_point - self.position).normalize();
        let right = forward.cross(self.view_up).normalize();
        let up = right.cross(forward);
        RayFrame {
            origin: self.position,
            forward,
            right,
            up,
            pixel: 2.0 * (0.5 * self.view_angle_deg.to_radians()).tan() / height.max(1) as f64,
            half_w: 0.5 * width as f64,
            half_h: 0.5 * height as f64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    fn geom() -> Geometry {
        Geometry {
            dims: [11, 21, 5],
            spacing: [1.0, 0.5, 2.0],
            origin: [1.0, -2.0, 3.0],
        }
    }

    #[test]
    fn orbit_looks_at_centre_from_the_right_side() {
        let g = geom();
        let c = DVec3::from_array(g.center());
        let cam = Camera::orbit(
            &g,
            Orbit {
                yaw: 0.0,
                pitch: 0.0,
                distance: 3.0,
                up: UpAxis::Z,
            },
        )
        .unwrap();
        let r = g.bounding_radius();
        assert!((cam.position - (c + DVec3::new(3.0 * r, 0.0, 0.0))).length() < 1e-12);
        assert_eq!(cam.view_up, DVec3::Z);
        // The centre pixel ray of an odd-sized image hits the focal point.
        let rays = cam.rays(5, 5);
        let d = rays.dir(2, 2);
        assert!((d - (c - cam.position).normalize()).length() < 1e-12);
        // Row 0 is the top: its ray points up (+z); column 0 is the left.
        assert!(rays.dir(2, 0).z > 0.0);
        // Looking along -x with z up, screen right is -y... right = forward × up = (-x) × z = +y.
        assert!(rays.dir(4, 2).y > 0.0);
        // The top-row ray leaves at half the view angle.
        let top = rays.dir(2, 0).angle_between(d).to_degrees();
        assert!((top - 22.5 * 4.0 / 5.0).abs() < 0.5, "{top}");
    }

    #[test]
    fn up_axes_frame_is_right_handed_and_view_up_orthogonal() {
        for up in [
            UpAxis::X,
            UpAxis::Y,
            UpAxis::Z,
            UpAxis::NegX,
            UpAxis::NegY,
            UpAxis::NegZ,
        ] {
            let (u, e1, e2) = up.frame();
            assert!((e1.cross(e2) - u).length() < 1e-15);
            let cam = Camera::orbit(
                &geom(),
                Orbit {
                    yaw: 1.0,
                    pitch: 0.3,
                    distance: 2.0,
                    up,
                },
            )
            .unwrap();
            let f = (cam.focal_point - cam.position).normalize();
            assert!(cam.view_up.dot(f).abs() < 1e-12);
            assert!(cam.view_up.dot(u) > 0.9);
        }
        assert_eq!("Y".parse::<UpAxis>().unwrap(), UpAxis::Y);
        assert_eq!("-z".parse::<UpAxis>().unwrap(), UpAxis::NegZ);
        assert_eq!(
            UpAxis::NegZ.to_string().parse::<UpAxis>().unwrap(),
            UpAxis::NegZ
        );
        assert!("w".parse::<UpAxis>().is_err());
    }

    #[test]
    fn random_views_stay_in_the_papers_ranges() {
        let g = geom();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let r = g.bounding_radius();
        for _ in 0..200 {
            let o = Orbit::random(UpAxis::Z, &mut rng);
            assert!((0.0..TAU).contains(&o.yaw));
            assert!(o.pitch.abs() <= PITCH_RANGE);
            assert!((2.0..=4.0).contains(&o.distance));
            let cam = Camera::orbit(&g, o).unwrap();
            assert!((cam.distance() / r - o.distance).abs() < 1e-9);
        }
        // Same seed, same views.
        let a = Camera::random(
            &g,
            UpAxis::Z,
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(3),
        );
        let b = Camera::random(
            &g,
            UpAxis::Z,
            &mut rand_chacha::ChaCha8Rng::seed_from_u64(3),
        );
        assert_eq!(a, b);
    }

    #[test]
    fn bad_parameters_are_errors() {
        let o = Orbit {
            yaw: 0.0,
            pitch: 0.5 * PI,
            distance: 2.0,
            up: UpAxis::Z,
        };
        assert!(Camera::orbit(&geom(), o).is_err());
        let o = Orbit {
            pitch: 0.0,
            distance: f64::NAN,
            ..o
        };
        let e = Camera::orbit(&geom(), o).unwrap_err();
        assert!(e.to_string().contains("distance"), "{e}");
    }

    #[test]
    fn paraview_camera_and_footprint() {
        let cam = Camera::orbit(
            &geom(),
            Orbit {
                yaw: 0.5,
                pitch: -0.1,
                distance: 2.5,
                up: UpAxis::Y,
            },
        )
        .unwrap();
        let pv = cam.paraview();
        assert_eq!(pv.view_angle, 45.0);
        assert_eq!(pv.focal_point, geom().center());
        let h = 200;
        let expect = 2.0 * cam.distance() * (22.5f64).to_radians().tan() / h as f64;
        assert!((cam.pixel_footprint(h) - expect).abs() < 1e-12);
    }
}
