//! The one place where Embree 3 and Embree 4 differ for raylab: the queries
//! take an intersect context in 3 (`rtcInitIntersectContext`, an inline
//! function that bindgen cannot bind, is reproduced here) and optional argument
//! structs in 4 (passed as null); Embree 3 has a stream API
//! (`rtcIntersect1M`/`rtcOccluded1M`) that Embree 4 removed ([`HAS_STREAMS`]).
//! Everything else raylab uses is the same in both.

use super::ffi;

/// The Embree major version the crate was built against.
#[cfg(embree4)]
pub const MAJOR: u32 = 4;
#[cfg(embree3)]
pub const MAJOR: u32 = 3;

/// `RTC_INVALID_GEOMETRY_ID`, a cast macro that bindgen does not translate.
pub const INVALID_ID: u32 = u32::MAX;

/// Whether this Embree has the stream API (`rtcIntersect1M`): Embree 3 only.
pub const HAS_STREAMS: bool = cfg!(embree3);

/// What `rtcInitIntersectContext` does in Embree 3: incoherent rays, no filter,
/// no instance on the stack (zero-initialised fields cover the optional ones).
#[cfg(embree3)]
fn context() -> ffi::RTCIntersectContext {
    context_with(ffi::RTCIntersectContextFlags_RTC_INTERSECT_CONTEXT_FLAG_INCOHERENT)
}

/// The context for packets and streams of neighbouring rays, which raylab's
/// renderer issues: Embree's hint that the rays are coherent.
#[cfg(embree3)]
fn coherent() -> ffi::RTCIntersectContext {
    context_with(ffi::RTCIntersectContextFlags_RTC_INTERSECT_CONTEXT_FLAG_COHERENT)
}

/// The context a packet query's `hint` asks for.
#[cfg(embree3)]
fn hinted(hint: Coherence) -> ffi::RTCIntersectContext {
    match hint {
        Coherence::Coherent => coherent(),
        Coherence::Incoherent => context(),
    }
}

#[cfg(embree3)]
fn context_with(flags: ffi::RTCIntersectContextFlags) -> ffi::RTCIntersectContext {
    let mut ctx = ffi::RTCIntersectContext {
        flags,
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

/// What a packet query tells Embree 3 of its rays (`--query packetN` or
/// `packetN-incoherent`). Neither is always faster: on cornell-water,
/// Wuson, the engine and Sponza incoherent packets took 0.45-0.89x the
/// coherent ones' time for shadow, diffuse and most AO rays, and 0.68-1.38x
/// for primary rays (docs/results.md), so the bench times both. Occlusion
/// through instances is always incoherent: there Embree 3.13.5's coherent
/// `rtcOccluded16` never returned (forest:10's shadow packets in `bench
/// --parts instances`, every run, stuck inside Embree).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Coherence {
    Coherent,
    Incoherent,
}

/// `rtcIntersect{N}` and `rtcOccluded{N}` for one packet width.
macro_rules! packet_queries {
    ($intersect:ident, $occluded:ident, $rtc_intersect:ident, $rtc_occluded:ident, $ray_hit:ident, $ray:ident) => {
        #[doc = concat!("`", stringify!($rtc_intersect), "` on a committed scene; `hint` as for occlusion.")]
        ///
        /// # Safety
        /// `scene` must be a valid, committed scene that outlives the call;
        /// `valid` must point to one `i32` per lane (-1 valid, 0 not), aligned
        /// as the packet is.
        #[inline]
        pub unsafe fn $intersect(
            valid: *const i32,
            scene: ffi::RTCScene,
            rays: &mut ffi::$ray_hit,
            hint: Coherence,
        ) {
            #[cfg(embree3)]
            {
                let mut ctx = hinted(hint);
                // SAFETY: the caller guarantees `scene` and `valid`; `ctx` and
                // `rays` are live.
                unsafe { ffi::$rtc_intersect(valid, scene, &mut ctx, rays) }
            }
            #[cfg(embree4)]
            {
                let _ = hint;
                // SAFETY: as above; null arguments select the defaults.
                unsafe { ffi::$rtc_intersect(valid, scene, rays, std::ptr::null_mut()) }
            }
        }

        #[doc = concat!("`", stringify!($rtc_occluded), "` on a committed scene; sets an occluded lane's `tfar` to -inf. `hint` is Embree 3's coherence flag (Embree 4's default is incoherent).")]
        ///
        /// # Safety
        /// As for the closest-hit query.
        #[inline]
        pub unsafe fn $occluded(
            valid: *const i32,
            scene: ffi::RTCScene,
            rays: &mut ffi::$ray,
            hint: Coherence,
        ) {
            #[cfg(embree3)]
            {
                let mut ctx = hinted(hint);
                // SAFETY: as above.
                unsafe { ffi::$rtc_occluded(valid, scene, &mut ctx, rays) }
            }
            #[cfg(embree4)]
            {
                let _ = hint;
                // SAFETY: as above.
                unsafe { ffi::$rtc_occluded(valid, scene, rays, std::ptr::null_mut()) }
            }
        }
    };
}

packet_queries!(
    intersect4,
    occluded4,
    rtcIntersect4,
    rtcOccluded4,
    RTCRayHit4,
    RTCRay4
);
packet_queries!(
    intersect8,
    occluded8,
    rtcIntersect8,
    rtcOccluded8,
    RTCRayHit8,
    RTCRay8
);
packet_queries!(
    intersect16,
    occluded16,
    rtcIntersect16,
    rtcOccluded16,
    RTCRayHit16,
    RTCRay16
);

/// `rtcIntersect1M` over `rays` (Embree 3's stream API, coherent rays).
///
/// # Safety
/// `scene` must be a valid, committed scene that outlives the call.
#[cfg(embree3)]
#[inline]
pub unsafe fn intersect_stream(scene: ffi::RTCScene, rays: &mut [ffi::RTCRayHit]) {
    let mut ctx = coherent();
    let stride = std::mem::size_of::<ffi::RTCRayHit>();
    // SAFETY: the caller guarantees `scene`; `rays` is `len` live, contiguous
    // ray-hit records of `stride` bytes.
    unsafe {
        ffi::rtcIntersect1M(
            scene,
            &mut ctx,
            rays.as_mut_ptr(),
            rays.len() as u32,
            stride,
        )
    }
}

/// `rtcOccluded1M` over `rays` (Embree 3's stream API, coherent rays).
///
/// # Safety
/// As for [`intersect_stream`].
#[cfg(embree3)]
#[inline]
pub unsafe fn occluded_stream(scene: ffi::RTCScene, rays: &mut [ffi::RTCRay]) {
    let mut ctx = coherent();
    let stride = std::mem::size_of::<ffi::RTCRay>();
    // SAFETY: as above.
    unsafe {
        ffi::rtcOccluded1M(
            scene,
            &mut ctx,
            rays.as_mut_ptr(),
            rays.len() as u32,
            stride,
        )
    }
}
