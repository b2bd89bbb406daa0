//! The one place where Embree 3 and Embree 4 differ for raylab: the single-ray
//! queries take an intersect context in 3 (`rtcInitIntersectContext`, an inline
//! function that bindgen cannot bind, is reproduced here) and optional argument
//! structs in 4 (passed as null). Everything else raylab uses is the same in both.

use super::ffi;

/// The Embree major version the crate was built against.
#[cfg(embree4)]
pub const MAJOR: u32 = 4;
#[cfg(embree3)]
pub const MAJOR: u32 = 3;

/// `RTC_INVALID_GEOMETRY_ID`, a cast macro that bindgen does not translate.
pub const INVALID_ID: u32 = u32::MAX;

/// What `rtcInitIntersectContext` does in Embree 3: incoherent rays, no filter,
/// no instance on the stack (zero-initialised fields cover the optional ones).
#[cfg(embree3)]
fn context() -> ffi::RTCIntersectContext {
    let mut ctx = ffi::RTCIntersectContext {
        flags: ffi::RTCIntersectContextFlags_RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT,
        filter: None,
        ..Default::default()
    };
    for id in ctx.instID.iter_mut() {
        *id = INVALID_ID;
    }
    ctx
}

/// `rtcIntersect1` on a committed scene.
///
/// # Safety
/// `scene` must be a valid, committed scene that outlives the call.
#[inline]
pub unsafe fn intersect1(scene: ffi::RTCScene, rayhit: &mut ffi::RTCRayHit) {
    #[cfg(embree3)]
    {
        let mut ctx = context();
        // SAFETY: the caller guarantees `scene`; `ctx` and `rayhit` are live locals.
        unsafe { ffi::rtcIntersect1(scene, &mut ctx, rayhit) }
    }
    #[cfg(embree4)]
    {
        // SAFETY: the caller guarantees `scene`; null arguments select the defaults.
        unsafe { ffi::rtcIntersect1(scene, rayhit, std::ptr::null_mut()) }
    }
}

/// `rtcOccluded1` on a committed scene; sets `ray.tfar` to -inf when occluded.
///
/// # Safety
/// `scene` must be a valid, committed scene that outlives the call.
#[inline]
pub unsafe fn occluded1(scene: ffi::RTCScene, ray: &mut ffi::RTCRay) {
    #[cfg(embree3)]
    {
        let mut ctx = context();
        // SAFETY: as in `intersect1`.
        unsafe { ffi::rtcOccluded1(scene, &mut ctx, ray) }
    }
    #[cfg(embree4)]
    {
        // SAFETY: as in `intersect1`.
        unsafe { ffi::rtcOccluded1(scene, ray, std::ptr::null_mut()) }
    }
}
