//! Embree's instances: a scene per mesh, and a top scene of instance
//! geometries (`RTC_GEOMETRY_TYPE_INSTANCE`, `rtcSetGeometryInstancedScene`,
//! `rtcSetGeometryTransform`), as Embree's own instancing tutorial builds
//! them. The calls are the same in Embree 3 and 4; the queries go through
//! [`super::api`]. A hit's instance comes from `hit.instID[0]`.

use std::sync::Arc;

use super::api;
use super::ffi;
use super::lanes::embree_takes;
use super::wrapper::{
    embree_ray, intersect_packets, occluded_packets, packet_path, raw_quality, tasking_threads,
    Device, EmbreeScene, EmbreeUpdate,
};
use super::Quality;
use crate::accel::{Backend, Query};
use crate::error::{Error, Result};
use crate::geometry::{Hit, Ray};
use crate::scene::instancing::Instancing;
use crate::scene::Scene;

/// An instanced scene in Embree.
pub struct EmbreeInstanced {
    top: ffi::RTCScene,
    /// The meshes' scenes: the instances hold references, kept here too so
    /// that their memory is counted and their lifetime plain.
    meshes: Vec<EmbreeScene>,
    /// Per instance, the scene index of its mesh's first triangle (Embree
    /// numbers primitives within each mesh's scene).
    first_tri: Vec<u32>,
    bvh_bytes: usize,
    build_threads: usize,
    query: Query,
    /// The device every scene was made on (it must outlive them), whose
    /// error log the updates check.
    device: Arc<Device>,
}

// SAFETY: a committed scene is immutable and Embree allows rtcIntersect1 and
// rtcOccluded1 on it from any number of threads at once.
unsafe impl Send for EmbreeInstanced {}
// SAFETY: as above.
unsafe impl Sync for EmbreeInstanced {}

impl EmbreeInstanced {
    /// Builds a scene per mesh and the top scene at `quality` on a new
    /// device of `threads` threads. Fails for a scene without instances.
    pub fn new(scene: &Scene, quality: Quality, robust: bool, threads: usize) -> Result<Self> {
        let flags = if robust {
            ffi::RTCSceneFlags_RTC_SCENE_FLAG_ROBUST
        } else {
            ffi::RTCSceneFlags_RTC_SCENE_FLAG_NONE
        };
        Self::with_top(
            scene,
            quality,
            robust,
            threads,
            (raw_quality(quality), flags),
        )
    }

    /// A scene whose instances will move ([`EmbreeInstanced::move_instances`]),
    /// the top scene rebuilt on each commit as `update` says. Embree has no
    /// refit of instances: its refit quality applies to meshes. Asked to
    /// refit, the top scene is made as Embree's documentation advises for
    /// scenes that change every frame, `RTC_SCENE_FLAG_DYNAMIC` at
    /// `RTC_BUILD_QUALITY_LOW`, for which it builds the instances with its
    /// dynamic (Morton) builder; the meshes are built once, at medium
    /// quality. `Rebuild(q)`: the top scene and the meshes at `q`.
    pub fn for_updates(scene: &Scene, update: EmbreeUpdate, threads: usize) -> Result<Self> {
        let (meshes, top) = match update {
            EmbreeUpdate::Refit => (
                Quality::Medium,
                (
                    ffi::RTCBuildQuality_RTC_BUILD_QUALITY_LOW,
                    ffi::RTCSceneFlags_RTC_SCENE_FLAG_DYNAMIC,
                ),
            ),
            EmbreeUpdate::Rebuild(q) => {
                (q, (raw_quality(q), ffi::RTCSceneFlags_RTC_SCENE_FLAG_NONE))
            }
        };
        Self::with_top(scene, meshes, false, threads, top)
    }

    /// Moves every instance to its transform in `instancing` (the same
    /// instances of the same meshes, moved) and commits the top scene, which
    /// Embree builds anew over the instances' new boxes; the meshes' scenes
    /// are untouched.
    pub fn move_instances(&mut self, instancing: &Instancing) -> Result<()> {
        if instancing.instances.len() != self.first_tri.len() {
            return Err(Error::Other(format!(
                "embree instances: an update of {} instances for a scene of {}",
                instancing.instances.len(),
                self.first_tri.len()
            )));
        }
        for (i, placed) in instancing.instances.iter().enumerate() {
            let cols = column_major(&placed.to_world);
            // SAFETY: `self.top` is live and holds geometry `i` (attached by
            // id in `with_top`, never detached); `&mut self` means no query
            // runs on the scene now; the transform is 12 floats read during
            // the call. Setting the transform, committing the geometry and
            // then the scene is Embree's documented sequence for a changed
            // geometry.
            unsafe {
                let g = ffi::rtcGetGeometry(self.top, i as u32);
                ffi::rtcSetGeometryTransform(
                    g,
                    0,
                    ffi::RTCFormat_RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR,
                    cols.as_ptr() as *const std::ffi::c_void,
                );
                ffi::rtcCommitGeometry(g);
            }
        }
        // SAFETY: a live scene, its geometries committed above.
        unsafe { ffi::rtcCommitScene(self.top) };
        self.device.check("rtcCommitScene (instances moved)")
    }

    /// Traces streams with `query` from now on ([`EmbreeInstanced::with_query`]).
    pub fn set_query(&mut self, query: Query) -> Result<()> {
        Self::check_query(query)?;
        self.query = query;
        Ok(())
    }

    /// [`EmbreeInstanced::new`] with the top scene's build quality and flags
    /// given.
    fn with_top(
        scene: &Scene,
        quality: Quality,
        robust: bool,
        threads: usize,
        (top_quality, flags): (ffi::RTCBuildQuality, ffi::RTCSceneFlags),
    ) -> Result<Self> {
        let Some(inst) = &scene.instancing else {
            return Err(Error::Other(
                "embree instances: the scene has no instances".into(),
            ));
        };
        super::builder::release_device_above(threads);
        let device = Device::new(&format!("threads={threads}"))?;
        let build_threads = tasking_threads();
        let before = device.memory_bytes();
        let mut meshes = Vec::with_capacity(inst.meshes.len());
        for range in &inst.meshes {
            // Each mesh's scene gets its own vertices, numbered afresh.
            let tris = &scene.triangles[range.start as usize..range.end as usize];
            let mut index = std::collections::HashMap::new();
            let mut positions = Vec::new();
            let local: Vec<[u32; 3]> = tris
                .iter()
                .map(|t| {
                    t.map(|v| {
                        *index.entry(v).or_insert_with(|| {
                            positions.push(scene.positions[v as usize]);
                            positions.len() as u32 - 1
                        })
                    })
                })
                .collect();
            meshes.push(EmbreeScene::new(
                &device, &positions, &local, quality, robust,
            )?);
        }
        // SAFETY: a live device.
        let top = unsafe { ffi::rtcNewScene(device.raw()) };
        device.check("rtcNewScene (instances)")?;
        let mut this = EmbreeInstanced {
            top,
            meshes,
            first_tri: Vec::with_capacity(inst.instances.len()),
            bvh_bytes: 0,
            build_threads,
            query: Query::Single,
            device: device.clone(),
        };
        // SAFETY: a live scene; plain setters.
        unsafe {
            ffi::rtcSetSceneBuildQuality(top, top_quality);
            ffi::rtcSetSceneFlags(top, flags);
        }
        for (i, placed) in inst.instances.iter().enumerate() {
            let cols = column_major(&placed.to_world);
            // SAFETY: a live device; the geometry is released after the
            // scene attaches it (the scene then holds its reference); the
            // instanced scene is committed and outlives the top scene
            // (`meshes` is dropped after `top` is released, see Drop); the
            // transform is 12 floats read during the call.
            unsafe {
                let g = ffi::rtcNewGeometry(
                    device.raw(),
                    ffi::RTCGeometryType_RTC_GEOMETRY_TYPE_INSTANCE,
                );
                ffi::rtcSetGeometryInstancedScene(g, this.meshes[placed.mesh as usize].raw());
                ffi::rtcSetGeometryTransform(
                    g,
                    0,
                    ffi::RTCFormat_RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR,
                    cols.as_ptr() as *const std::ffi::c_void,
                );
                ffi::rtcCommitGeometry(g);
                ffi::rtcAttachGeometryByID(top, g, i as u32);
                ffi::rtcReleaseGeometry(g);
            }
            this.first_tri.push(inst.meshes[placed.mesh as usize].start);
        }
        device.check("instance geometries")?;
        // SAFETY: a live scene with its instances attached.
        unsafe { ffi::rtcCommitScene(top) };
        device.check("rtcCommitScene (instances)")?;
        this.bvh_bytes = (device.memory_bytes() - before).max(0) as usize;
        Ok(this)
    }

    /// The threads its build ran on.
    pub fn build_threads(&self) -> usize {
        self.build_threads
    }

    /// Traces streams with `query`: single rays or packets of 4, 8 or 16,
    /// coherent or incoherent (`rtcIntersect{N}` and `rtcOccluded{N}` on the
    /// top scene; Embree takes the packet through the instances). Occlusion
    /// packets are marked incoherent on both packet paths (`api::Coherence`:
    /// Embree 3's coherent `rtcOccluded16` through instances never
    /// returned). Embree 3's stream API is not wired for instances.
    pub fn with_query(mut self, query: Query) -> Result<Self> {
        self.set_query(query)?;
        Ok(self)
    }

    fn check_query(query: Query) -> Result<()> {
        if !matches!(
            query,
            Query::Single | Query::Packet(4 | 8 | 16) | Query::IncoherentPacket(4 | 8 | 16)
        ) {
            return Err(Error::usage(
                "--query",
                format!("Embree's instanced scene is traced as single rays or packets of 4, 8 or 16 here, not {query}"),
            ));
        }
        Ok(())
    }
}

/// `m` as Embree's column-major 3x4: the three axes, then the translation.
fn column_major(m: &glam::Affine3A) -> [f32; 12] {
    [
        m.matrix3.x_axis.x,
        m.matrix3.x_axis.y,
        m.matrix3.x_axis.z,
        m.matrix3.y_axis.x,
        m.matrix3.y_axis.y,
        m.matrix3.y_axis.z,
        m.matrix3.z_axis.x,
        m.matrix3.z_axis.y,
        m.matrix3.z_axis.z,
        m.translation.x,
        m.translation.y,
        m.translation.z,
    ]
}

impl Drop for EmbreeInstanced {
    fn drop(&mut self) {
        // SAFETY: releases our reference to the top scene we created; the
        // meshes' scenes are released after it, when `meshes` drops.
        unsafe { ffi::rtcReleaseScene(self.top) };
    }
}

impl Backend for EmbreeInstanced {
    fn memory_bytes(&self) -> Option<usize> {
        Some(self.bvh_bytes)
    }

    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !embree_takes(ray) {
            return None;
        }
        let mut rh = ffi::RTCRayHit {
            ray: embree_ray(ray),
            hit: ffi::RTCHit {
                geomID: api::INVALID_ID,
                primID: api::INVALID_ID,
                instID: [api::INVALID_ID; 1],
                ..Default::default()
            },
        };
        // SAFETY: `self.top` is a committed scene kept alive by `self`.
        unsafe { api::intersect1(self.top, &mut rh) };
        let inst = rh.hit.instID[0];
        (rh.hit.geomID != api::INVALID_ID && inst != api::INVALID_ID).then(|| Hit {
            t: rh.ray.tfar,
            u: rh.hit.u,
            v: rh.hit.v,
            tri: self.first_tri[inst as usize] + rh.hit.primID,
            inst,
        })
    }

    fn occluded(&self, ray: &Ray) -> bool {
        if !embree_takes(ray) {
            return false;
        }
        let mut r = embree_ray(ray);
        // SAFETY: as in `intersect`.
        unsafe { api::occluded1(self.top, &mut r) };
        r.tfar == f32::NEG_INFINITY
    }

    fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        match packet_path(self.query) {
            // SAFETY: `self.top` is a committed scene kept alive by `self`.
            Some((n, hint)) => unsafe {
                intersect_packets(self.top, n, rays, hits, Some(&self.first_tri), hint)
            },
            None => {
                for (ray, hit) in rays.iter().zip(hits) {
                    *hit = self.intersect(ray);
                }
            }
        }
    }

    fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        match packet_path(self.query) {
            // SAFETY: `self.top` is a committed scene kept alive by `self`.
            // Incoherent on both packet paths: see `api::Coherence`.
            Some((n, _)) => unsafe {
                occluded_packets(self.top, n, rays, occluded, api::Coherence::Incoherent)
            },
            None => {
                for (ray, o) in rays.iter().zip(occluded) {
                    *o = self.occluded(ray);
                }
            }
        }
    }

    fn flushes_denormals(&self) -> bool {
        true
    }
}
