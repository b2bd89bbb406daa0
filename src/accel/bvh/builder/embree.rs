//! Embree's BVH builder (`rtcBuildBVH`) as a raylab builder: the tree Embree
//! builds at low, medium or high quality, in raylab's layout, so its quality
//! can be measured with raylab's own traversal. The FFI side lives in
//! [`crate::accel::embree::builder`].

#[cfg(feature = "embree")]
use super::pool::KeptPerThreads;
use crate::accel::bvh::node::Skeleton;
use crate::accel::bvh::BuildParams;
use glam::Vec3;

#[cfg(feature = "embree")]
pub(super) fn build_with_embree(
    triangles: &[[Vec3; 3]],
    params: &BuildParams,
    quality: crate::accel::embree::Quality,
) -> crate::Result<Skeleton> {
    use crate::accel::embree::Device;
    // One device per thread count, made once: device start-up (thread pool) is
    // not part of a build.
    static DEVICES: KeptPerThreads<Device> = KeptPerThreads::new();
    let device = DEVICES.get(params.threads, || {
        Device::new(&format!("threads={}", params.threads.max(1)))
    })?;
    crate::accel::embree::builder::build(
        &device,
        triangles,
        quality,
        params.max_leaf_size,
        params.sah_block,
    )
}

#[cfg(not(feature = "embree"))]
pub(super) fn build_with_embree(
    _triangles: &[[Vec3; 3]],
    _params: &BuildParams,
    _quality: crate::accel::embree::Quality,
) -> crate::Result<Skeleton> {
    Err(crate::accel::embree::unavailable())
}
