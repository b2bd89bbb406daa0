//! obvhs: its PLOC builder at one of its presets, traversed as its compressed
//! 8-wide `CwBvh` or its binary `Bvh2`, with its own Moller-Trumbore test
//! (`Triangle::intersect`) on triangles laid out in the tree's order, as its
//! examples do. Closest hit is `ray_traverse`, any hit `ray_traverse_miss`.
//!
//! obvhs returns only `t`; the barycentrics are computed afterwards with the
//! expression its own test uses (edges v0 - v1 and v2 - v0, Embree's form).

use std::time::Duration;

use glam_obvhs::Vec3A;
use obvhs::bvh2::Bvh2;
use obvhs::cwbvh::CwBvh;
use obvhs::ray::{Ray as ObvhsRay, RayHit};
use obvhs::triangle::Triangle;
use obvhs::BvhBuildParams;

use super::ObvhsLayout;
use crate::accel::bvh::in_pool;
use crate::accel::embree::Quality;
use crate::accel::Backend;
use crate::geometry::{Hit, Ray};
use crate::scene::MeshRef;

enum Tree {
    CwBvh(CwBvh),
    Bvh2(Bvh2),
    Empty,
}

pub struct ObvhsBackend {
    tree: Tree,
    /// The triangles in the tree's order (`primitive_indices`).
    triangles: Vec<Triangle>,
    /// The scene's index of each of `triangles`.
    scene_index: Vec<u32>,
}

/// The obvhs preset for a rung of the quality ladder.
pub const fn preset(quality: Quality) -> BvhBuildParams {
    match quality {
        Quality::Low => BvhBuildParams::fast_build(),
        Quality::Medium => BvhBuildParams::medium_build(),
        Quality::High => BvhBuildParams::slow_build(),
    }
}

fn vec3a(v: glam::Vec3) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z)
}

/// Binary-tree depth past which the CwBvh conversion is refused: obvhs's
/// `bvh2_to_cwbvh` recurses once per level of the binary tree (about 100
/// bytes of stack a level in `calculate_cost_impl`, more in
/// `convert_to_cwbvh_impl`), so 25,000 identical triangles, which its PLOC
/// builder stacks into a chain, overflowed a 2 MiB pool thread's stack and
/// aborted the process. Real scenes' trees are under 100 levels deep.
pub const MAX_CWBVH_DEPTH: usize = 2048;

/// obvhs's `build_cwbvh_from_tris` (cwbvh/builder.rs, 0.4), step for step,
/// with the binary tree's depth checked before its recursive conversion.
fn build_cwbvh(triangles: &[Triangle], config: BvhBuildParams) -> crate::Result<CwBvh> {
    use obvhs::bvh2::reinsertion::ReinsertionOptimizer;
    use obvhs::ploc::PlocBuilder;
    let mut bvh2 = if config.pre_split {
        let mut largest_half_area = 0.0f32;
        let mut avg_area = 0.0;
        let mut aabbs: Vec<_> = triangles
            .iter()
            .map(|tri| {
                let aabb = tri.aabb();
                let half_area = aabb.half_area();
                largest_half_area = half_area.max(largest_half_area);
                avg_area += half_area;
                aabb
            })
            .collect();
        let mut indices: Vec<u32> = (0..triangles.len() as u32).collect();
        avg_area /= triangles.len() as f32;
        obvhs::splits::split_aabbs_preset(
            &mut aabbs,
            &mut indices,
            triangles,
            avg_area,
            largest_half_area,
        );
        PlocBuilder::with_capacity(aabbs.len()).build(
            config.ploc_search_distance,
            &aabbs,
            indices,
            config.sort_precision,
            config.search_depth_threshold,
        )
    } else {
        PlocBuilder::with_capacity(triangles.len()).build(
            config.ploc_search_distance,
            triangles,
            (0..triangles.len() as u32).collect::<Vec<_>>(),
            config.sort_precision,
            config.search_depth_threshold,
        )
    };
    bvh2.uses_spatial_splits = config.pre_split;
    ReinsertionOptimizer::default().run(&mut bvh2, config.reinsertion_batch_ratio, None);
    let depth = bvh2_depth(&bvh2);
    if depth > MAX_CWBVH_DEPTH {
        return Err(crate::Error::Other(format!(
            "obvhs: its binary tree is {depth} levels deep ({} triangles, many of them in one place), past the {MAX_CWBVH_DEPTH} its recursive CwBvh conversion can take without overflowing the stack: use --layout bvh2 or another backend",
            triangles.len()
        )));
    }
    Ok(obvhs::cwbvh::bvh2_to_cwbvh::bvh2_to_cwbvh(
        &bvh2,
        config.max_prims_per_leaf.clamp(1, 3),
        true,
        false,
    ))
}

/// The depth of an obvhs binary tree, counted without recursion (obvhs's own
/// `Bvh2::depth` recurses, and would overflow on the trees this guards).
fn bvh2_depth(bvh2: &Bvh2) -> usize {
    let mut deepest = 0;
    let mut stack = vec![(0usize, 1usize)];
    while let Some((i, d)) = stack.pop() {
        let Some(node) = bvh2.nodes.get(i) else {
            continue;
        };
        deepest = deepest.max(d);
        if !node.is_leaf() {
            let first = node.first_index as usize;
            stack.push((first, d + 1));
            stack.push((first + 1, d + 1));
        }
    }
    deepest
}

impl ObvhsBackend {
    pub fn new(
        mesh: &MeshRef,
        layout: ObvhsLayout,
        quality: Quality,
        threads: usize,
    ) -> crate::Result<Self> {
        let input: Vec<Triangle> = (0..mesh.triangle_count())
            .map(|i| {
                let [v0, v1, v2] = mesh.triangle(i);
                Triangle {
                    v0: vec3a(v0),
                    v1: vec3a(v1),
                    v2: vec3a(v2),
                }
            })
            .collect();
        if input.is_empty() {
            return Ok(ObvhsBackend {
                tree: Tree::Empty,
                triangles: Vec::new(),
                scene_index: Vec::new(),
            });
        }
        let params = preset(quality);
        let mut core_time = Duration::default();
        // obvhs's parallel parts run on the rayon pool they are called in.
        let (tree, order) = in_pool(threads, || -> crate::Result<_> {
            Ok(match layout {
                ObvhsLayout::CwBvh => {
                    let tree = build_cwbvh(&input, params)?;
                    let order = tree.primitive_indices.clone();
                    (Tree::CwBvh(tree), order)
                }
                ObvhsLayout::Bvh2 => {
                    let tree =
                        obvhs::bvh2::builder::build_bvh2_from_tris(&input, params, &mut core_time);
                    let order = tree.primitive_indices.clone();
                    (Tree::Bvh2(tree), order)
                }
            })
        })?;
        let triangles = order.iter().map(|&i| input[i as usize]).collect();
        Ok(ObvhsBackend {
            tree,
            triangles,
            scene_index: order,
        })
    }

    fn ray(ray: &Ray) -> ObvhsRay {
        ObvhsRay::new(vec3a(ray.origin), vec3a(ray.dir), ray.tmin, ray.tmax)
    }
}

impl Backend for ObvhsBackend {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let r = Self::ray(ray);
        let mut hit = RayHit::none();
        let test = |r: &ObvhsRay, id: usize| self.triangles[id].intersect(r);
        let found = match &self.tree {
            Tree::CwBvh(tree) => tree.ray_traverse(r, &mut hit, test),
            Tree::Bvh2(tree) => tree.ray_traverse(r, &mut hit, test),
            Tree::Empty => false,
        };
        if !found {
            return None;
        }
        let id = hit.primitive_id as usize;
        let tri = &self.triangles[id];
        let (e1, e2) = (tri.v0 - tri.v1, tri.v2 - tri.v0);
        let r_vec = r.direction.cross(tri.v0 - r.origin);
        let inv_det = 1.0 / e1.cross(e2).dot(r.direction);
        Some(Hit {
            t: hit.t,
            u: r_vec.dot(e2) * inv_det,
            v: r_vec.dot(e1) * inv_det,
            tri: self.scene_index[id],
            inst: 0,
        })
    }

    fn occluded(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let r = Self::ray(ray);
        let test = |r: &ObvhsRay, id: usize| self.triangles[id].intersect(r);
        let missed = match &self.tree {
            Tree::CwBvh(tree) => tree.ray_traverse_miss(r, test),
            Tree::Bvh2(tree) => tree.ray_traverse_miss(r, test),
            Tree::Empty => true,
        };
        !missed
    }

    fn memory_bytes(&self) -> Option<usize> {
        let nodes = match &self.tree {
            Tree::CwBvh(tree) => std::mem::size_of_val(tree.nodes.as_slice()),
            Tree::Bvh2(tree) => std::mem::size_of_val(tree.nodes.as_slice()),
            Tree::Empty => 0,
        };
        Some(
            nodes
                + std::mem::size_of_val(self.triangles.as_slice())
                + std::mem::size_of_val(self.scene_index.as_slice()),
        )
    }
}
