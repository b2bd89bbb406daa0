//! `forest:N`: the built-in instanced scene. Three trees of about 10^4
//! triangles each (a crown and a trunk: tessellated spheres, squashed and
//! stretched), stored once, and N instances of them (turned, scaled and
//! jittered on a square grid three units apart) on one ground quad. A
//! million instances place 10^10 triangles, which no flattened list holds in
//! this machine's memory; the meshes are 30k.

use glam::{Affine3A, Quat, Vec3};

use super::shapes::{ground, Builder};
use super::{Material, Scene};
use crate::error::Result;
use crate::rng::Rng;

/// Instances `forest:N` may have.
pub const INSTANCES: std::ops::RangeInclusive<u64> = 1..=10_000_000;

/// Grid spacing of the trees, in units (a tree's crown is about 2.4 across).
const SPACING: f32 = 3.0;

/// `forest:n`.
pub fn forest(name: &str, n: usize) -> Result<Scene> {
    let kinds = [
        // (crown radius x/z, crown height scale, crown centre height, green)
        (1.0, 1.4, 2.6, Vec3::new(0.12, 0.40, 0.10)),
        (0.8, 2.2, 3.0, Vec3::new(0.08, 0.30, 0.12)),
        (1.25, 0.9, 2.3, Vec3::new(0.25, 0.45, 0.08)),
    ];
    let mut meshes: Vec<Scene> = kinds
        .iter()
        .enumerate()
        .map(|(k, &(r, h, y, green))| tree(k, r, h, y, green))
        .collect::<Result<_>>()?;
    let side = (n as f64).sqrt().ceil() as usize;
    let half = side as f32 * SPACING * 0.5 + SPACING;
    meshes.push(ground(half, Vec3::new(0.35, 0.30, 0.22))?);
    let ground = meshes.len() as u32 - 1;
    let mut placements = Vec::with_capacity(n + 1);
    placements.push((ground, Affine3A::IDENTITY));
    for i in 0..n {
        let mut rng = Rng::for_pixel(i as u64, 0x0f02e57, 0);
        let (gx, gz) = ((i % side) as f32, (i / side) as f32);
        let at = Vec3::new(
            (gx + 0.5 + 0.6 * (rng.next_f32() - 0.5)) * SPACING - half + SPACING,
            0.0,
            (gz + 0.5 + 0.6 * (rng.next_f32() - 0.5)) * SPACING - half + SPACING,
        );
        let kind = (rng.next_u64() % kinds.len() as u64) as u32;
        let turn = Quat::from_rotation_y(std::f32::consts::TAU * rng.next_f32());
        let scale = 0.7 + 0.6 * rng.next_f32();
        placements.push((
            kind,
            Affine3A::from_scale_rotation_translation(Vec3::splat(scale), turn, at),
        ));
    }
    Scene::instanced(name, meshes, placements)
}

/// One tree: a trunk (a sphere stretched into a spindle) under a crown
/// (a sphere squashed or stretched), 9,700-10,100 triangles.
fn tree(kind: usize, radius: f32, height: f32, centre: f32, green: Vec3) -> Result<Scene> {
    let mut b = Builder::default();
    let bark = b.material(Material::diffuse("bark", Vec3::new(0.30, 0.20, 0.12)));
    let leaves = b.material(Material::diffuse("leaves", green));
    // The unit spheres are shaped afterwards; their normals would no longer
    // fit, so the shader uses the geometric normals.
    b.sphere(Vec3::ZERO, 1.0, 24, 40, bark);
    let trunk_end = b.positions.len();
    b.sphere(Vec3::ZERO, 1.0, 64 + 4 * kind as u32, 64, leaves);
    for (i, p) in b.positions.iter_mut().enumerate() {
        *p = if i < trunk_end {
            Vec3::new(p.x * 0.18, (p.y + 1.0) * 1.1, p.z * 0.18)
        } else {
            // A little lumpiness so the three kinds differ in outline.
            let lump = 1.0 + 0.08 * (5.0 * p.x + kind as f32).sin() * (4.0 * p.z).cos();
            Vec3::new(
                p.x * radius * lump,
                p.y * height * lump + centre,
                p.z * radius * lump,
            )
        };
    }
    b.normals.fill(Vec3::ZERO);
    b.into_scene(&format!("tree {kind}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn forests_store_each_mesh_once() {
        let s = forest("forest:1000", 1000).unwrap();
        assert_eq!(s.instance_count(), 1001);
        let unique = s.triangle_count() as u64;
        assert!((29_000..31_500).contains(&unique), "{unique}");
        let placed = s.placed_triangle_count();
        assert!(placed > 1000 * 9_900 && placed < 1000 * 11_000, "{placed}");
        let b = s.bounds();
        assert!(b.max.x - b.min.x > 90.0 && b.min.y == 0.0, "{b:?}");
        // The same forest every time.
        assert_eq!(forest("f", 1000).unwrap().bounds(), b);
    }
}
