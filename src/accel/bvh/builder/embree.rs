//! Embree's BVH builder (`rtcBuildBVH`) as a raylab builder: the tree Embree
//! builds at low, medium or high quality, in raylab's layout, so its quality
//! can be measured with raylab's own traversal. The FFI side lives in
//! [`crate::accel::embree::builder`].

use crate::accel::bvh::node::Skeleton;
use crate::accel::bvh::BuildParams;
use glam::Vec3;

#[cfg(feature = "embree")]
pub(super) fn build_with_embree(
    triangles: &[[Vec3; 3]],
    params: &BuildParams,
    quality: crate::accel::embree::Quality,
) -> crate::Result<Skeleton> {
    // Kept between builds, one thread count at a time (see there).
    let device = crate::accel::embree::builder::device(params.threads)?;
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
