//! Lights that are not scene geometry: the default area light of a scene without
//! emissive triangles, and a light placed with `--light`. They illuminate (shadow
//! rays are cast to them) but are never hit by a ray, so they change neither the
//! triangle count nor any backend's work beyond the shadow rays.

use std::str::FromStr;

use glam::Vec3;

use crate::geometry::Aabb;

/// A light outside the scene's triangles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Emitter {
    /// A point light of radiant intensity `intensity` (per steradian).
    Point { position: Vec3, intensity: Vec3 },
    /// A parallelogram `corner + s * edge_u + t * edge_v`, `s, t` in [0, 1], of
    /// uniform radiance, emitting on the side `edge_u x edge_v` points to (both
    /// sides with `--two-sided-lights`).
    Quad {
        corner: Vec3,
        edge_u: Vec3,
        edge_v: Vec3,
        radiance: Vec3,
    },
}

/// Irradiance the default light and a `--light` without a power deliver at the
/// scene's centre: a white (Kd 0.8) surface facing the light then shows about
/// 0.7 of full brightness.
pub const TARGET_IRRADIANCE: f32 = 2.75;

impl Emitter {
    /// A quad's area, None for a point light. In f64: the f32 cross product of
    /// edges above about 1e19 overflows (a scene of size 1e10 has such a light).
    pub fn area(&self) -> Option<f32> {
        match *self {
            Emitter::Point { .. } => None,
            Emitter::Quad { edge_u, edge_v, .. } => {
                Some(edge_u.as_dvec3().cross(edge_v.as_dvec3()).length() as f32)
            }
        }
    }

    /// A quad's unit normal (`edge_u x edge_v`, the side it emits to), None for
    /// a point light; in f64 as [`Emitter::area`].
    pub fn normal(&self) -> Option<Vec3> {
        match *self {
            Emitter::Point { .. } => None,
            Emitter::Quad { edge_u, edge_v, .. } => Some(
                edge_u
                    .as_dvec3()
                    .cross(edge_v.as_dvec3())
                    .normalize_or_zero()
                    .as_vec3(),
            ),
        }
    }

    /// The default light of a scene without emissive triangles (the rule docs/reference.md
    /// documents): a square of side a quarter of the bounding box's diagonal `d`,
    /// facing down the `up` axis towards the box's centre `c`, centred at
    /// `c + up * (h/2 + d/2) + front * d/4` where `h` is the box's extent along
    /// `up` and `front` the axis the default view looks from, with a radiance that
    /// gives [`TARGET_IRRADIANCE`] at `c`.
    pub fn default_for(bounds: &Aabb, up: Vec3) -> Emitter {
        let (up, front, right) = frame_axes(up);
        let c = bounds.center();
        let ext = bounds.max - bounds.min;
        let d = ext.length().max(f32::MIN_POSITIVE);
        let h = ext.dot(up.abs());
        let centre = c + up * (0.5 * h + 0.5 * d) + front * (0.25 * d);
        let side = 0.25 * d;
        Emitter::square(centre, c - centre, right, side)
    }

    /// A square of side `side` centred at `centre`, facing along `facing`, one edge
    /// along `hint` projected into its plane; radiance from [`TARGET_IRRADIANCE`]
    /// at the distance |facing|.
    fn square(centre: Vec3, facing: Vec3, hint: Vec3, side: f32) -> Emitter {
        let n = facing.normalize_or(-Vec3::Y);
        let mut u = (hint - n * hint.dot(n)).normalize_or_zero();
        if u == Vec3::ZERO {
            u = n.any_orthonormal_vector();
        }
        // edge_u x edge_v = n: emits towards `facing`.
        let v = n.cross(u);
        // The ratio in f64: both squares overflow f32 in a scene of size 1e19.
        let r2 = facing
            .as_dvec3()
            .length_squared()
            .max((side as f64).powi(2));
        let radiance = (TARGET_IRRADIANCE as f64 * r2 / (side as f64).powi(2)) as f32;
        Emitter::Quad {
            corner: centre - (u + v) * (0.5 * side),
            edge_u: u * side,
            edge_v: v * side,
            radiance: Vec3::splat(radiance),
        }
    }
}

/// The up axis, the axis the default view looks from (its eye lies on that side)
/// and the right axis: +Z is the front for a Y-up scene (as OBJ and glTF files
/// are usually written), -Y for a Z-up one (Blender's front view), and otherwise
/// any axis perpendicular to `up`.
pub fn frame_axes(up: Vec3) -> (Vec3, Vec3, Vec3) {
    let up = up.normalize_or(Vec3::Y);
    let front = if up.y.abs() >= 0.9 {
        Vec3::Z
    } else if up.z.abs() >= 0.9 {
        -Vec3::Y * up.z.signum()
    } else {
        up.any_orthonormal_vector()
    };
    let front = (front - up * front.dot(up)).normalize();
    (up, front, up.cross(front))
}

/// `--light`: `point:X,Y,Z[:INTENSITY]` (a white point light of that radiant
/// intensity) or `quad:X,Y,Z:SIZE[:RADIANCE]` (a white square of side SIZE
/// centred at X,Y,Z, facing down `-up`). Without a power, the light gives
/// [`TARGET_IRRADIANCE`] at the scene's centre, which [`LightArg::emitter`]
/// works out from the scene's bounds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum LightArg {
    Point {
        position: Vec3,
        intensity: Option<f32>,
    },
    Quad {
        centre: Vec3,
        side: f32,
        radiance: Option<f32>,
    },
}

impl LightArg {
    /// The emitter for a scene with bounds `bounds` and up axis `up` (a quad
    /// faces down it, its edges along the view's right and front axes).
    pub fn emitter(&self, bounds: &Aabb, up: Vec3) -> Emitter {
        let c = bounds.center();
        match *self {
            LightArg::Point {
                position,
                intensity,
            } => {
                // E = I / r^2 at the centre, facing the light (r^2 in f64).
                let r2 = (c - position).as_dvec3().length_squared();
                let target = (TARGET_IRRADIANCE as f64 * r2) as f32;
                Emitter::Point {
                    position,
                    intensity: Vec3::splat(intensity.unwrap_or(target.max(f32::MIN_POSITIVE))),
                }
            }
            LightArg::Quad {
                centre,
                side,
                radiance,
            } => {
                let dist = ((c - centre).as_dvec3().length() as f32).max(f32::MIN_POSITIVE);
                let (up, _, right) = frame_axes(up);
                let mut quad = Emitter::square(centre, -up * dist, right, side);
                if let (Some(l), Emitter::Quad { radiance: r, .. }) = (radiance, &mut quad) {
                    *r = Vec3::splat(l);
                }
                quad
            }
        }
    }
}

impl FromStr for LightArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let usage = "expected point:X,Y,Z[:INTENSITY] or quad:X,Y,Z:SIZE[:RADIANCE]";
        let mut parts = s.split(':');
        let quad = match parts.next() {
            Some("point") => false,
            Some("quad") => true,
            _ => return Err(format!("'{s}': {usage}")),
        };
        let pos = parts.next().ok_or_else(|| format!("'{s}': {usage}"))?;
        let xyz: Vec<f32> = pos
            .split(',')
            .map(|w| w.trim().parse::<f32>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("'{pos}': position must be three numbers X,Y,Z"))?;
        if xyz.len() != 3 || xyz.iter().any(|x| !x.is_finite()) {
            return Err(format!(
                "'{pos}': position must be three finite numbers X,Y,Z"
            ));
        }
        let position = Vec3::new(xyz[0], xyz[1], xyz[2]);
        let positive = |w: &str, what: &str| -> Result<f32, String> {
            match w.trim().parse::<f32>() {
                Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
                _ => Err(format!("'{w}': {what} must be a positive number")),
            }
        };
        let side = if quad {
            let w = parts
                .next()
                .ok_or_else(|| format!("'{s}': a quad needs :SIZE"))?;
            Some(positive(w, "SIZE")?)
        } else {
            None
        };
        let power = parts.next().map(|w| positive(w, "the power")).transpose()?;
        if parts.next().is_some() {
            return Err(format!("'{s}': too many fields; {usage}"));
        }
        Ok(match side {
            Some(side) => LightArg::Quad {
                centre: position,
                side,
                radiance: power,
            },
            None => LightArg::Point {
                position,
                intensity: power,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit_box() -> Aabb {
        Aabb::EMPTY.grown(Vec3::ZERO).grown(Vec3::ONE)
    }

    #[test]
    fn default_light_is_above_the_scene_facing_its_centre() {
        let b = unit_box();
        let Emitter::Quad {
            corner,
            edge_u,
            edge_v,
            radiance,
        } = Emitter::default_for(&b, Vec3::Y)
        else {
            panic!("a quad expected")
        };
        let centre = corner + (edge_u + edge_v) * 0.5;
        assert!(centre.y > 1.0, "above the box: {centre}");
        assert!(centre.z > 0.5, "towards the front: {centre}");
        let n = edge_u.cross(edge_v).normalize();
        assert!(n.dot(b.center() - centre) > 0.9 * (b.center() - centre).length());
        let d = 3f32.sqrt();
        assert!((edge_u.length() - 0.25 * d).abs() < 1e-5);
        // Irradiance at the centre about the target (small-source approximation).
        let r2 = (b.center() - centre).length_squared();
        let e = radiance.x * edge_u.cross(edge_v).length() / r2;
        assert!((e / TARGET_IRRADIANCE - 1.0).abs() < 1e-3, "{e}");
    }

    #[test]
    fn z_up_scenes_get_the_light_above_on_z() {
        let Emitter::Quad { corner, .. } = Emitter::default_for(&unit_box(), Vec3::Z) else {
            panic!()
        };
        assert!(corner.z > 1.0, "{corner}");
    }

    #[test]
    fn light_flags_parse_and_bad_ones_say_why() {
        let l: LightArg = "point:1,2,3".parse().unwrap();
        assert_eq!(
            l,
            LightArg::Point {
                position: Vec3::new(1.0, 2.0, 3.0),
                intensity: None
            }
        );
        let q: LightArg = "quad:0,5,0:2:10".parse().unwrap();
        assert_eq!(
            q,
            LightArg::Quad {
                centre: Vec3::new(0.0, 5.0, 0.0),
                side: 2.0,
                radiance: Some(10.0)
            }
        );
        // Without a power: the target irradiance at the scene's centre.
        let Emitter::Point { intensity, .. } = l.emitter(&unit_box(), Vec3::Y) else {
            panic!()
        };
        let r2 = (Vec3::new(1.0, 2.0, 3.0) - Vec3::splat(0.5)).length_squared();
        assert!((intensity.x / r2 / TARGET_IRRADIANCE - 1.0).abs() < 1e-5);
        let Emitter::Quad {
            radiance,
            edge_u,
            edge_v,
            ..
        } = q.emitter(&unit_box(), Vec3::Y)
        else {
            panic!()
        };
        assert_eq!(radiance, Vec3::splat(10.0));
        assert!(
            edge_u.cross(edge_v).normalize().dot(-Vec3::Y) > 0.999,
            "faces down"
        );
        // Down is -up: a Z-up scene's quad faces -Z, with edges of SIZE.
        let Emitter::Quad { edge_u, edge_v, .. } = q.emitter(&unit_box(), Vec3::Z) else {
            panic!()
        };
        assert!(
            edge_u.cross(edge_v).normalize().dot(-Vec3::Z) > 0.999,
            "faces down -Z"
        );
        assert_eq!((edge_u.length(), edge_v.length()), (2.0, 2.0));
        for bad in [
            "",
            "spot:1,2,3",
            "point:1,2",
            "point:a,b,c",
            "quad:0,1,0",
            "quad:0,1,0:-1",
            "point:1,2,3:0",
            "point:1,2,3:1:2",
        ] {
            assert!(bad.parse::<LightArg>().is_err(), "{bad}");
        }
    }
}
