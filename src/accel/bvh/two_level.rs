//! raylab's two-level BVH over an instanced scene: one tree per mesh (the
//! BLAS, any `--quality` rung and width, as a flat scene's tree), and an
//! 8-wide SAH tree over the instances' world boxes (the TLAS, one instance
//! per lane, its nodes tested as the BLASes' are: AVX2 where the CPU has
//! it; the binary scalar walk it replaced took 1.3-1.6x the time per ray on
//! forest:1000, on this machine). A ray that
//! reaches an instance's leaf moves into the mesh's space (the same `t`
//! there: the transform is affine) and is traced through the mesh's tree.
//!
//! Closest hits follow the flattened scene's tie-break: at equal `t` the
//! lower instance, then the lower triangle wins. An instance's tree is asked
//! for hits up to and including the best `t` so far (its `tmax` one ulp
//! above it), so a tie in a later-visited instance is still found.
//!
//! Packets (`--query packet8|packet16`) walk the TLAS together (the BLAS
//! packets' node tests, one shared stack), and an instance the packet
//! reaches is traced for the rays that reached it: as one packet through the
//! mesh's tree where the whole packet did ([`whole_packet`]), else one by
//! one.
//! Each ray's box tests are its single-ray tests, so it reaches every
//! instance its single walk would before its answer, and gets the same one.

use std::sync::Arc;

use glam::Vec3;
use rayon::prelude::*;

use super::backend::BvhBackend;
use super::builder::build;
use super::in_pool;
use super::leaf::bits;
use super::params::{BuildParams, BuilderKind, Quality};
use super::params::{CULL_SLACK, DEEP_STACK};
use super::tree::Tree;
use super::wide::{Bvh8, TraversalCosts};
use crate::accel::{Backend, Query};
use crate::error::Error;
use crate::geometry::{Aabb, Hit, Intersector, Ray};
use crate::scene::instancing::{Instance, Instancing};
use crate::scene::{MeshRef, Scene};

/// Instances per TLAS leaf: one, so that every instance's own box is
/// tested (eight at once) before its tree is entered.
const TLAS_LEAF: usize = 1;

/// Whether occlusion queries visit instances nearest box first.
const OCCLUSION_NEAREST_FIRST: bool = false;

/// Whether the `count` rays of a packet of `len` that reached an instance
/// are traced through its mesh's tree as one packet: only when all of them
/// (two or more) did; fewer go one at a time, each on its single-ray walk.
/// A packet that only some of its rays carry into a small instance tests
/// every node for all its lanes and culls less than a ray alone does. Single
/// rays past a packet's walk of the TLAS, against a mesh packet from 2 rays
/// on (the threshold before), forest:1000 rays per ray kind: primary 100.6
/// -> 75.0 ns, shadow 196.6 -> 163.9, AO 203.0 -> 161.2 (packets of 16, AMD
/// EPYC); forest:10 and forest:100 faster too, and on the 2CylinderEngine
/// (67 large instances piled up) primary 80.2 -> 75.5, shadow 76.0 -> 81.0,
/// AO 114.3 -> 114.9. Never a mesh packet lost the engine's shadows (107.9).
#[inline]
fn whole_packet(count: usize, len: usize) -> bool {
    count >= 2 && count == len
}

/// The widest packet (raylab's packets hold 8 or 16 rays).
const MAX_PACKET: usize = 16;

/// The two-level tree.
pub struct TwoLevel {
    /// 8-wide tree over the instances; its leaf slots' ids name instances.
    tlas: Bvh8,
    /// One tree per mesh.
    blas: Vec<BvhBackend>,
    instancing: Arc<Instancing>,
    query: Query,
}

impl TwoLevel {
    /// Builds a tree per mesh as `params` say (the meshes one after another,
    /// each on `params.threads`), then the TLAS over the instances' boxes.
    /// Fails for a scene without instances, or for a `query` the meshes'
    /// trees have no path for (packets need 8-wide trees).
    pub fn new(
        scene: &Scene,
        params: &BuildParams,
        intersector: Intersector,
        query: Query,
    ) -> crate::Result<Self> {
        Self::with_tlas_rung(scene, params, Quality::Medium, intersector, query)
    }

    /// [`TwoLevel::new`] with the TLAS built at `tlas_rung`
    /// ([`tlas_params`]).
    pub fn with_tlas_rung(
        scene: &Scene,
        params: &BuildParams,
        tlas_rung: Quality,
        intersector: Intersector,
        query: Query,
    ) -> crate::Result<Self> {
        let Some(instancing) = scene.instancing.clone() else {
            return Err(Error::Scene {
                name: scene.name.clone(),
                msg: "a two-level tree needs an instanced scene".into(),
            });
        };
        check_query(query)?;
        let mut blas = Vec::with_capacity(instancing.meshes.len());
        for range in &instancing.meshes {
            let mesh = MeshRef {
                positions: &scene.positions,
                triangles: &scene.triangles[range.start as usize..range.end as usize],
            };
            blas.push(
                BvhBackend::new(&mesh, params)?
                    .with_intersector(intersector)
                    .with_query(query)?,
            );
        }
        let tlas = tlas(&instancing, &tlas_params(tlas_rung, params.threads))?;
        Ok(TwoLevel {
            tlas,
            blas,
            instancing,
            query,
        })
    }

    /// Visits the instances whose boxes the ray reaches (nearest box first
    /// when `nearest_first`, else in the any-hit traversal's order) until
    /// `visit` (given an instance and the current `tmax`) returns `true`,
    /// or none is left; `visit` may lower the `tmax` it is handed.
    #[inline]
    fn walk(&self, ray: &Ray, nearest_first: bool, mut visit: impl FnMut(u32, &mut f32) -> bool) {
        self.tlas.walk_ids(ray, nearest_first, &mut visit);
    }

    /// `ray` in instance `inst`'s mesh space, up to `tmax`.
    #[inline]
    fn local_ray(inst: &Instance, ray: &Ray, tmax: f32) -> Ray {
        Ray::segment(
            inst.to_local.transform_point3(ray.origin),
            inst.to_local.transform_vector3(ray.dir),
            ray.tmin,
            tmax,
        )
    }

    /// A hit of mesh `mesh`'s tree (numbered within the mesh) as a hit of
    /// the scene through instance `i`.
    #[inline]
    fn placed(&self, mut hit: Hit, i: u32, mesh: usize) -> Hit {
        hit.tri += self.instancing.meshes[mesh].start;
        hit.inst = i;
        hit
    }

    /// Traces streams with `query` from now on (refused as [`TwoLevel::new`]
    /// refuses it; the tree is unchanged then).
    pub fn set_query(&mut self, query: Query) -> crate::Result<()> {
        check_query(query)?;
        // The meshes' trees have one width: the first refuses what all do.
        for blas in &mut self.blas {
            blas.set_query(query)?;
        }
        self.query = query;
        Ok(())
    }

    /// Follows `frame`, the same meshes with the instances moved: the TLAS's
    /// boxes recomputed bottom-up over its kept topology on `threads`
    /// threads, the meshes' trees untouched. Fails for a frame that is not
    /// the same instances of the same meshes.
    pub fn refit_instances(&mut self, frame: &Scene, threads: usize) -> crate::Result<()> {
        let moved = self.moved(frame)?;
        let boxes = in_pool(threads, || tlas_boxes(&moved, threads > 1));
        self.tlas.refit(&boxes, threads)?;
        self.instancing = moved;
        Ok(())
    }

    /// Follows `frame` as [`TwoLevel::refit_instances`] does, by building
    /// the TLAS anew at `rung` on `threads` threads.
    pub fn rebuild_instances(
        &mut self,
        frame: &Scene,
        rung: Quality,
        threads: usize,
    ) -> crate::Result<()> {
        let moved = self.moved(frame)?;
        self.tlas = tlas(&moved, &tlas_params(rung, threads))?;
        self.instancing = moved;
        Ok(())
    }

    /// `frame`'s instancing, when it places the same meshes by the same
    /// instances as this tree's (each instance the same mesh).
    fn moved(&self, frame: &Scene) -> crate::Result<Arc<Instancing>> {
        let refused = |msg: &str| Error::Scene {
            name: frame.name.clone(),
            msg: format!("cannot update the two-level tree: {msg}"),
        };
        let Some(moved) = frame.instancing.clone() else {
            return Err(refused("the frame has no instances"));
        };
        let (old, new) = (&self.instancing, &moved);
        if old.meshes != new.meshes || old.instances.len() != new.instances.len() {
            return Err(refused("the frame's meshes or instance count differ"));
        }
        if old
            .instances
            .iter()
            .zip(&new.instances)
            .any(|(a, b)| a.mesh != b.mesh)
        {
            return Err(refused("an instance places another mesh"));
        }
        Ok(moved)
    }

    /// The TLAS's SAH cost under `costs` (what the refit-or-rebuild policy
    /// compares: the meshes' trees never change as instances move).
    pub fn tlas_cost(&self, costs: &TraversalCosts) -> f64 {
        self.tlas.sah_cost(costs)
    }

    /// Closest hits of one packet (at most [`MAX_PACKET`] rays, the
    /// query's width `n`) into `out`: the packet walks the TLAS together,
    /// and each instance it reaches is traced for the rays that reached it.
    fn closest_packet(&self, n: usize, rays: &[Ray], out: &mut [Option<Hit>]) {
        debug_assert!(rays.len() <= MAX_PACKET && out.len() == rays.len());
        let mut best = [None::<Hit>; MAX_PACKET];
        let mut tmax = [0.0f32; MAX_PACKET];
        for (t, ray) in tmax.iter_mut().zip(rays) {
            *t = ray.tmax;
        }
        let mut scratch = Scratch::new();
        self.tlas
            .walk_ids_packet_with(n, rays, true, &mut |i, reached, cut| {
                // Up to and including each ray's best t so far, as `intersect`.
                let reach = |q: usize| {
                    if best[q].is_some() {
                        tmax[q].next_up()
                    } else {
                        tmax[q]
                    }
                };
                let (mesh, count) = scratch.gather(self, i, reached, rays, reach);
                let blas = &self.blas[mesh];
                let (local, lanes) = (&scratch.local[..count], &scratch.lanes);
                let hits = &mut scratch.hits[..count];
                if whole_packet(count, rays.len()) {
                    blas.intersect_stream(local, hits);
                } else {
                    for (hit, ray) in hits.iter_mut().zip(local) {
                        *hit = blas.intersect(ray);
                    }
                }
                for (k, hit) in hits.iter().enumerate() {
                    if let Some(hit) = *hit {
                        let q = lanes[k] as usize;
                        let hit = self.placed(hit, i, mesh);
                        if best[q].is_none_or(|b| hit.is_closer_than(&b)) {
                            best[q] = Some(hit);
                            tmax[q] = hit.t;
                            cut[q] = hit.t * (1.0 + CULL_SLACK);
                        }
                    }
                }
                0
            });
        out.copy_from_slice(&best[..rays.len()]);
    }

    /// Occlusion of one packet into `out`, as [`Self::closest_packet`]: a
    /// ray is done when any instance's tree says it is occluded.
    fn any_packet(&self, n: usize, rays: &[Ray], out: &mut [bool]) {
        debug_assert!(rays.len() <= MAX_PACKET && out.len() == rays.len());
        let mut occluded = 0u32;
        let mut scratch = Scratch::new();
        self.tlas
            .walk_ids_packet_with(n, rays, OCCLUSION_NEAREST_FIRST, &mut |i, reached, _| {
                let (mesh, count) = scratch.gather(self, i, reached, rays, |q| rays[q].tmax);
                let blas = &self.blas[mesh];
                let local = &scratch.local[..count];
                let answers = &mut scratch.occluded[..count];
                if whole_packet(count, rays.len()) {
                    blas.occluded_stream(local, answers);
                } else {
                    for (o, ray) in answers.iter_mut().zip(local) {
                        *o = blas.occluded(ray);
                    }
                }
                let mut done = 0;
                for (k, &o) in answers.iter().enumerate() {
                    done |= u32::from(o) << scratch.lanes[k];
                }
                occluded |= done;
                done
            });
        for (r, o) in out.iter_mut().enumerate() {
            *o = occluded >> r & 1 == 1;
        }
    }
}

/// Refuses the query paths the two-level tree has none of.
fn check_query(query: Query) -> crate::Result<()> {
    if !matches!(query, Query::Single | Query::Packet(_)) {
        return Err(Error::usage(
            "--query",
            format!("the two-level tree over an instanced scene traces single rays or packets, not {query}"),
        ));
    }
    Ok(())
}

/// The rays of a packet that reached one instance, moved into its mesh's
/// space, and what its tree answered them.
struct Scratch {
    local: [Ray; MAX_PACKET],
    lanes: [u8; MAX_PACKET],
    hits: [Option<Hit>; MAX_PACKET],
    occluded: [bool; MAX_PACKET],
}

impl Scratch {
    fn new() -> Self {
        Scratch {
            local: [Ray::segment(Vec3::ZERO, Vec3::X, 0.0, 0.0); MAX_PACKET],
            lanes: [0; MAX_PACKET],
            hits: [None; MAX_PACKET],
            occluded: [false; MAX_PACKET],
        }
    }

    /// Gathers the rays of `reached` (a bit per ray of `rays`) into `local`,
    /// each moved into instance `i`'s mesh space with `tmax` its `reach`.
    /// Returns the mesh and the number gathered.
    fn gather(
        &mut self,
        two: &TwoLevel,
        i: u32,
        reached: u32,
        rays: &[Ray],
        reach: impl Fn(usize) -> f32,
    ) -> (usize, usize) {
        let inst = &two.instancing.instances[i as usize];
        let mut count = 0;
        for q in bits(reached) {
            self.local[count] = TwoLevel::local_ray(inst, &rays[q], reach(q));
            self.lanes[count] = q as u8;
            count += 1;
        }
        (inst.mesh as usize, count)
    }
}

/// The instances' world boxes as the builders and the refit read them
/// (triangles): an instance's box is the triangle from its box's minimum to
/// its maximum corner, whose box (and so centre) it is. Each box is padded
/// so that rounding never culls an instance its mesh's tree would hit: it
/// grows by 2^-20 of its largest coordinate, far above the transform's
/// rounding (a few ulps) and far below any scene's detail.
/// In parallel on the current pool when `parallel`.
fn tlas_boxes(instancing: &Instancing, parallel: bool) -> Vec<[Vec3; 3]> {
    let instance_box = |i: usize| {
        let b = instancing.world_box(i);
        let pad = Vec3::splat(b.min.abs().max(b.max.abs()).max_element() * (1.0 / 1_048_576.0));
        let b = Aabb {
            min: b.min - pad,
            max: b.max + pad,
        };
        [b.min, b.max, b.min]
    };
    let count = instancing.instances.len();
    if parallel {
        (0..count).into_par_iter().map(instance_box).collect()
    } else {
        (0..count).map(instance_box).collect()
    }
}

/// How the TLAS is built at a rung: one instance per leaf, 8 wide; the low
/// rung's LBVH, the medium rung's binned SAH, and at the high rung the SAH
/// with reinsertion. Never spatial splits: an instance's box is no triangle
/// to clip.
pub fn tlas_params(rung: Quality, threads: usize) -> BuildParams {
    let builder = match rung {
        Quality::Low => BuilderKind::Lbvh,
        Quality::Medium | Quality::High => BuilderKind::Sah,
    };
    BuildParams {
        max_leaf_size: TLAS_LEAF,
        ..BuildParams::for_builder(builder)
    }
    .with_optimize(rung == Quality::High)
    .with_width(8)
    .with_threads(threads)
}

/// The SAH cost under `costs` of a TLAS built afresh at `rung` over
/// `frame`'s instances (what a refitted TLAS's cost is set against).
pub fn fresh_tlas_cost(
    frame: &Scene,
    rung: Quality,
    threads: usize,
    costs: &TraversalCosts,
) -> crate::Result<f64> {
    let Some(instancing) = &frame.instancing else {
        return Err(Error::Other(format!("{} has no instances", frame.name)));
    };
    Ok(tlas(instancing, &tlas_params(rung, threads))?.sah_cost(costs))
}

/// The 8-wide tree over the instances' boxes ([`tlas_boxes`]), built as
/// `params` say ([`tlas_params`]).
fn tlas(instancing: &Instancing, params: &BuildParams) -> crate::Result<Bvh8> {
    let Tree::Wide8(bvh) = build(&tlas_boxes(instancing, params.threads > 1), params)? else {
        unreachable!("a width-8 build is 8-wide")
    };
    if bvh.stack_need > DEEP_STACK {
        return Err(crate::Error::Other(format!(
            "the instances' tree is {} levels deep, past the traversal's stack",
            bvh.stack_need
        )));
    }
    Ok(bvh)
}

impl Backend for TwoLevel {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let mut best: Option<Hit> = None;
        self.walk(ray, true, |i, tmax| {
            let inst = &self.instancing.instances[i as usize];
            // Up to and including the best t so far: a tie there may belong
            // to a lower instance, which the tie-break prefers.
            let reach = if best.is_some() {
                tmax.next_up()
            } else {
                *tmax
            };
            let local = Self::local_ray(inst, ray, reach);
            if let Some(hit) = self.blas[inst.mesh as usize].intersect(&local) {
                let hit = self.placed(hit, i, inst.mesh as usize);
                if best.is_none_or(|b| hit.is_closer_than(&b)) {
                    best = Some(hit);
                    *tmax = hit.t;
                }
            }
            false
        });
        best
    }

    fn occluded(&self, ray: &Ray) -> bool {
        if !ray.is_valid() {
            return false;
        }
        let mut found = false;
        self.walk(ray, OCCLUSION_NEAREST_FIRST, |i, tmax| {
            let inst = &self.instancing.instances[i as usize];
            found = self.blas[inst.mesh as usize].occluded(&Self::local_ray(inst, ray, *tmax));
            found
        });
        found
    }

    fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        match self.query {
            Query::Packet(n) => {
                for (rays, hits) in rays.chunks(n).zip(hits.chunks_mut(n)) {
                    self.closest_packet(n, rays, hits);
                }
            }
            _ => {
                for (ray, hit) in rays.iter().zip(hits) {
                    *hit = self.intersect(ray);
                }
            }
        }
    }

    fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        match self.query {
            Query::Packet(n) => {
                for (rays, out) in rays.chunks(n).zip(occluded.chunks_mut(n)) {
                    self.any_packet(n, rays, out);
                }
            }
            _ => {
                for (ray, o) in rays.iter().zip(occluded) {
                    *o = self.occluded(ray);
                }
            }
        }
    }

    fn memory_bytes(&self) -> Option<usize> {
        let blas: usize = self.blas.iter().filter_map(|b| b.memory_bytes()).sum();
        Some(
            blas + self.tlas.memory_bytes()
                + self.instancing.instances.len() * std::mem::size_of::<Instance>(),
        )
    }
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Quat};

    use super::*;
    use crate::accel::naive::Naive;
    use crate::rng::Rng;
    use crate::scene::builtin::builtin;

    /// Three meshes placed 60 times, rotated, scaled and overlapping.
    fn scene() -> Scene {
        let meshes = vec![
            builtin("mesh:300").unwrap(),
            builtin("cornell-sphere").unwrap(),
            builtin("cornell-empty").unwrap(),
        ];
        let mut rng = Rng::for_pixel(3, 9, 0);
        let placements = (0..60)
            .map(|i| {
                let m = Affine3A::from_scale_rotation_translation(
                    Vec3::splat(0.3 + rng.next_f32()),
                    Quat::from_rotation_y(7.0 * rng.next_f32())
                        * Quat::from_rotation_x(rng.next_f32()),
                    Vec3::new(
                        6.0 * rng.next_f32(),
                        3.0 * rng.next_f32(),
                        -6.0 * rng.next_f32(),
                    ),
                );
                (i % 3, m)
            })
            .collect();
        Scene::instanced("t", meshes, placements).unwrap()
    }

    #[test]
    fn hits_are_the_flattened_scenes_up_to_rounding() {
        let s = scene();
        let flat = s.flattened().unwrap();
        let naive = Naive::from_triangles(flat.triangle_vertices());
        let b = s.bounds();
        let mut rng = Rng::for_pixel(5, 9, 0);
        for width in [2, 8] {
            let two = TwoLevel::new(
                &s,
                &BuildParams::sah().with_width(width),
                Intersector::Mt,
                Query::Single,
            )
            .unwrap();
            let (mut same, mut total) = (0, 0);
            for _ in 0..3000 {
                let p = |rng: &mut Rng| {
                    b.min
                        + (b.max - b.min)
                            * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32())
                };
                let o = p(&mut rng) * 1.3 - (b.max - b.min) * 0.15;
                let ray = Ray::new(o, p(&mut rng) - o);
                let (want, got) = (naive.intersect(&ray), two.intersect(&ray));
                assert_eq!(
                    want.is_some(),
                    two.occluded(&ray),
                    "occluded must agree with naive"
                );
                total += 1;
                match (want, got) {
                    (None, None) => same += 1,
                    (Some(w), Some(g)) => {
                        assert!((w.t - g.t).abs() <= 1e-4 * w.t.max(1.0), "{w:?} {g:?}");
                        if u64::from(w.tri) == s.flat_index(&g) {
                            same += 1;
                        }
                    }
                    (w, g) => panic!("naive {w:?}, two-level {g:?}"),
                }
            }
            // Different triangles only where two lie at the same t (shared
            // edges, coplanar instances), rounding apart.
            assert!(same * 1000 >= total * 998, "{same} of {total}");
        }
    }

    #[test]
    fn packets_answer_as_single_rays_do() {
        let s = scene();
        let b = s.bounds();
        let mut rng = Rng::for_pixel(11, 4, 0);
        // Coherent bundles (neighbouring origins and directions, as a
        // render's packets), scattered rays, and rays from inside the
        // instances' boxes with short and long reaches.
        let mut rays = Vec::new();
        for bundle in 0..120 {
            let o = b.min
                + (b.max - b.min) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) * 1.4
                - (b.max - b.min) * 0.2;
            let target =
                b.min + (b.max - b.min) * Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32());
            let spread = if bundle % 3 == 0 { 2.0 } else { 0.05 };
            for _ in 0..16 {
                let jitter = Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5;
                let tmax = if bundle % 4 == 1 {
                    0.5 + rng.next_f32()
                } else {
                    f32::INFINITY
                };
                rays.push(Ray::segment(o, target - o + jitter * spread, 1e-4, tmax));
            }
        }
        // Invalid rays keep their lanes empty.
        rays[5] = Ray::segment(Vec3::ZERO, Vec3::ZERO, 0.0, 1.0);
        rays[40].dir.x = f32::NAN;
        for n in [8, 16] {
            let single = TwoLevel::new(
                &s,
                &BuildParams::sah().with_width(8),
                Intersector::Mt,
                Query::Single,
            )
            .unwrap();
            let packets = TwoLevel::new(
                &s,
                &BuildParams::sah().with_width(8),
                Intersector::Mt,
                Query::Packet(n),
            );
            let Ok(packets) = packets else {
                // packet16 needs AVX-512.
                assert_eq!(n, 16);
                continue;
            };
            let mut hits = vec![None; rays.len()];
            let mut occluded = vec![false; rays.len()];
            packets.intersect_stream(&rays, &mut hits);
            packets.occluded_stream(&rays, &mut occluded);
            let mut hit_count = 0;
            for (k, ray) in rays.iter().enumerate() {
                let want = single.intersect(ray);
                assert_eq!(hits[k], want, "packet{n}, ray {k}");
                assert_eq!(occluded[k], single.occluded(ray), "packet{n}, ray {k}");
                hit_count += usize::from(want.is_some());
            }
            assert!(hit_count > rays.len() / 4, "{hit_count} hits");
        }
    }

    #[test]
    fn a_tlas_refitted_back_to_rest_is_the_built_one_and_other_scenes_are_refused() {
        let animation = crate::scene::motion::Animation::parse("asteroids:200")
            .unwrap()
            .unwrap();
        let rest = animation.rest();
        let params = BuildParams::sah().with_width(8);
        let mut two = TwoLevel::new(rest, &params, Intersector::Mt, Query::Single).unwrap();
        let built = (two.tlas.nodes.clone(), two.tlas.blocks.clone());
        let cost = two.tlas_cost(&crate::accel::bvh::params::REFIT_POLICY_COSTS);
        two.refit_instances(&animation.frame(2.0).unwrap(), 1)
            .unwrap();
        assert_ne!(two.tlas.nodes, built.0, "the boxes moved");
        two.refit_instances(rest, 1).unwrap();
        assert_eq!(two.tlas.nodes, built.0, "node for node");
        assert_eq!(two.tlas.blocks, built.1);
        assert_eq!(
            two.tlas_cost(&crate::accel::bvh::params::REFIT_POLICY_COSTS),
            cost
        );
        // Another scene, or the same one with fewer instances, is refused
        // and leaves the tree as it was.
        for other in ["asteroids:199", "forest:200"] {
            let other = builtin(other).unwrap();
            let err = two.refit_instances(&other, 1).unwrap_err().to_string();
            assert!(err.contains("cannot update the two-level tree"), "{err}");
            assert!(two.rebuild_instances(&other, Quality::Low, 1).is_err());
        }
        let flat = builtin("cornell-sphere").unwrap();
        assert!(two.refit_instances(&flat, 1).is_err());
        assert_eq!(two.tlas.nodes, built.0);
    }

    #[test]
    fn binary_trees_refuse_packets_and_flat_scenes_are_refused() {
        let s = scene();
        let err = TwoLevel::new(
            &s,
            &BuildParams::sah().with_width(2),
            Intersector::Mt,
            Query::Packet(8),
        )
        .err()
        .unwrap();
        assert!(err.to_string().contains("--query"), "{err}");
        let flat = builtin("cornell-sphere").unwrap();
        assert!(TwoLevel::new(&flat, &BuildParams::sah(), Intersector::Mt, Query::Single).is_err());
    }
}
