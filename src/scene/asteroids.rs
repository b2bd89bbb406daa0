//! `asteroids:N`: the built-in scene whose instances move. Three rocks (lumpy
//! spheres of 4-6k triangles, stored once) placed N times in a belt above a
//! ground, each orbiting the belt's axis and tumbling about its own. Orbits
//! follow Kepler's third law (angular speed falls as radius^-1.5), so the
//! inner rocks overtake the outer ones and neighbours drift apart: the
//! meshes never change, only the instances' transforms, which is what a
//! refit of the instances' tree alone (the TLAS) is for, and the shear makes
//! its boxes swell as the animation goes on.

use std::f32::consts::TAU;

use glam::{Affine3A, Quat, Vec3};

use super::shapes::{ground, Builder};
use super::{Material, Scene};
use crate::error::Result;
use crate::rng::Rng;

/// Instances `asteroids:N` may have.
pub const INSTANCES: std::ops::RangeInclusive<u64> = 1..=1_000_000;

/// Seconds the animation lasts.
pub const SECONDS: f32 = 2.0;

/// Belt area per rock, square units (a rock is about 1.6 across).
const AREA_PER_ROCK: f32 = 6.0;

/// Radians per second at the belt's inner edge (an inner rock turns 1.6
/// radians in the animation, one at twice the radius 0.57).
const INNER_SPEED: f32 = 0.8;

/// One rock's path: where it is at time `t` is [`Orbit::at`].
#[derive(Clone, Debug)]
pub struct Orbit {
    pub mesh: u32,
    radius: f32,
    height: f32,
    angle: f32,
    speed: f32,
    scale: f32,
    axis: Vec3,
    spin: f32,
    turn: Quat,
}

impl Orbit {
    /// The rock's transform at `t` seconds.
    pub fn at(&self, t: f32) -> Affine3A {
        let a = self.angle + self.speed * t;
        let at = Vec3::new(self.radius * a.cos(), self.height, self.radius * a.sin());
        let spin = Quat::from_axis_angle(self.axis, self.spin * t) * self.turn;
        Affine3A::from_scale_rotation_translation(Vec3::splat(self.scale), spin, at)
    }
}

/// The instances that move: the ground stays instance 0, `orbits[k]` moves
/// instance `k + 1`.
#[derive(Clone, Debug)]
pub struct Belt {
    pub orbits: Vec<Orbit>,
}

impl Belt {
    /// Every instance's transform at `t` seconds (the ground's first).
    pub fn transforms_at(&self, t: f32) -> Vec<Affine3A> {
        let mut out = Vec::with_capacity(self.orbits.len() + 1);
        out.push(Affine3A::IDENTITY);
        out.extend(self.orbits.iter().map(|o| o.at(t)));
        out
    }
}

/// `asteroids:n` at rest, and how its instances move.
pub fn asteroids(name: &str, n: usize) -> Result<(Scene, Belt)> {
    let mut meshes: Vec<Scene> = (0..3).map(rock).collect::<Result<_>>()?;
    // The annulus from `inner` to `outer` holds the rocks at AREA_PER_ROCK.
    let inner = 4.0 + (n as f32).sqrt() * 0.8;
    let outer = (inner * inner + n as f32 * AREA_PER_ROCK / std::f32::consts::PI).sqrt();
    meshes.push(ground(outer + 2.0, Vec3::new(0.30, 0.28, 0.26))?);
    let ground = meshes.len() as u32 - 1;
    let orbits: Vec<Orbit> = (0..n)
        .map(|i| {
            let mut rng = Rng::for_pixel(i as u64, 0xa57e_2017, 0);
            // Uniform over the annulus's area.
            let u = rng.next_f32();
            let radius = (inner * inner + u * (outer * outer - inner * inner)).sqrt();
            let axis = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
            Orbit {
                mesh: (rng.next_u64() % 3) as u32,
                radius,
                height: 1.5 + 2.0 * rng.next_f32(),
                angle: TAU * rng.next_f32(),
                speed: INNER_SPEED * (inner / radius).powf(1.5),
                scale: 0.5 + 0.5 * rng.next_f32(),
                axis: axis.normalize_or(Vec3::Y),
                spin: 0.5 + 2.0 * rng.next_f32(),
                turn: Quat::from_rotation_y(TAU * rng.next_f32()),
            }
        })
        .collect();
    let belt = Belt { orbits };
    let placements = belt
        .transforms_at(0.0)
        .into_iter()
        .enumerate()
        .map(|(i, m)| {
            let mesh = if i == 0 {
                ground
            } else {
                belt.orbits[i - 1].mesh
            };
            (mesh, m)
        })
        .collect();
    Ok((Scene::instanced(name, meshes, placements)?, belt))
}

/// Rock `kind`: a unit sphere made lumpy, 4-6k triangles.
fn rock(kind: usize) -> Result<Scene> {
    let mut b = Builder::default();
    let grey = 0.35 + 0.08 * kind as f32;
    let stone = b.material(Material::diffuse(
        "rock",
        Vec3::new(grey, grey * 0.92, grey * 0.85),
    ));
    b.sphere(Vec3::ZERO, 1.0, 48 + 8 * kind as u32, 48, stone);
    let k = kind as f32;
    for p in b.positions.iter_mut() {
        let lump = 1.0
            + 0.18 * (3.0 * p.x + 1.7 * k).sin() * (2.0 * p.y - k).cos()
            + 0.07 * (9.0 * p.z + k).sin();
        *p *= lump * Vec3::new(1.0, 0.75 + 0.1 * k, 0.9);
    }
    // The normals no longer fit the lumps: shade with the geometric normal.
    b.normals.fill(Vec3::ZERO);
    b.into_scene(&format!("rock {kind}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rocks_shear_apart_and_keep_their_meshes() {
        let (s, belt) = asteroids("asteroids:500", 500).unwrap();
        assert_eq!(s.instance_count(), 501);
        let unique = s.triangle_count();
        assert!((12_000..20_000).contains(&unique), "{unique}");
        let (a, b) = (belt.transforms_at(0.0), belt.transforms_at(SECONDS));
        assert_eq!(a[0], b[0], "the ground stays");
        // Inner rocks turn further than outer ones: the belt shears.
        let turned = |k: usize| {
            let (p, q) = (a[k + 1].translation, b[k + 1].translation);
            (p.x * q.z - p.z * q.x).atan2(p.x * q.x + p.z * q.z)
        };
        let (inner, outer) = (0..500)
            .map(|k| (belt.orbits[k].radius, turned(k)))
            .fold((0.0f32, f32::MAX), |(hi, lo), (_, a)| {
                (hi.max(a), lo.min(a))
            });
        assert!(inner > 1.5 * outer && outer > 0.3, "{inner} {outer}");
        // The same belt every time.
        assert_eq!(asteroids("x", 500).unwrap().0.bounds(), s.bounds());
    }
}
