//! Safe ownership of Embree objects: a [`Device`] whose errors become Rust
//! errors, an [`EmbreeScene`] with one triangle geometry fed from raylab's arrays,
//! and the [`EmbreeBackend`] that renders through the shared loop.

use std::ffi::{c_char, c_void, CStr, CString};
use std::sync::atomic::{AtomicI64, Ordering};
use std::sync::{Arc, Mutex};

use glam::Vec3;

use super::lanes::{self, embree_takes};
use super::{api, ffi, Quality};
use crate::accel::bvh::params::embree_split_replications;
use crate::accel::{Backend, Query};
use crate::error::{Error, Result};
use crate::geometry::{Hit, Ray};
use crate::scene::Scene;

/// Messages passed to the device's error callback, oldest first.
type ErrorLog = Mutex<Vec<String>>;

/// The `threads=` of every live device (`usize::MAX` where the config sets
/// none or 0: Embree then takes every hardware thread), one entry per device.
///
/// Embree runs the builds of all devices on one tasking system, sized to the
/// most threads any live device asked for (`getMaxNumThreads` in its
/// device.cpp, Embree 3 and 4): a build on a one-thread device runs on two
/// threads while a two-thread device lives. The bench once timed Embree's
/// "one-thread" builds that way (as fast as its two-thread builds) while it
/// held two-thread scenes; [`tasking_threads`] lets a timed build say what it
/// really ran on.
static LIVE_THREADS: Mutex<Vec<usize>> = Mutex::new(Vec::new());

/// The threads Embree's builds run on now: the most any live device asked for
/// (0 with no device alive).
pub fn tasking_threads() -> usize {
    LIVE_THREADS
        .lock()
        .map_or(0, |live| live.iter().copied().max().unwrap_or(0))
}

/// The build threads a device config asks for, as Embree reads it.
fn config_threads(config: &str) -> usize {
    config
        .split(',')
        .find_map(|kv| kv.trim().strip_prefix("threads="))
        .and_then(|n| n.trim().parse::<usize>().ok())
        .filter(|&n| n > 0)
        .unwrap_or(usize::MAX)
}

/// An Embree device. Dropping the last handle releases it.
pub struct Device {
    raw: ffi::RTCDevice,
    /// Its `threads=` ([`config_threads`]), registered in [`LIVE_THREADS`]
    /// while it lives.
    threads: usize,
    /// Boxed so its address, given to Embree as the callback's user pointer,
    /// stays fixed; it outlives the device because `Drop` releases the device first.
    errors: Box<ErrorLog>,
    /// Bytes Embree holds for this device, as its memory monitor reports them
    /// (boxed for a fixed address, as `errors`).
    memory: Box<AtomicI64>,
}

// SAFETY: Embree devices are thread-safe (its API may be called on one device
// from several threads); the error log is behind a Mutex.
unsafe impl Send for Device {}
// SAFETY: as above.
unsafe impl Sync for Device {}

unsafe extern "C" fn record_error(user: *mut c_void, code: ffi::RTCError, message: *const c_char) {
    let text = if message.is_null() {
        String::new()
    } else {
        // SAFETY: Embree passes a NUL-terminated string valid for this call.
        unsafe { CStr::from_ptr(message) }
            .to_string_lossy()
            .into_owned()
    };
    // SAFETY: `user` is the `ErrorLog` boxed in the `Device`, alive while the device is.
    let log = unsafe { &*(user as *const ErrorLog) };
    if let Ok(mut log) = log.lock() {
        log.push(format!("{} (code {code})", text.trim()));
    }
}

unsafe extern "C" fn record_memory(user: *mut c_void, bytes: isize, _post: bool) -> bool {
    // SAFETY: `user` is the counter boxed in the `Device`, alive while the device is.
    let memory = unsafe { &*(user as *const AtomicI64) };
    memory.fetch_add(bytes as i64, Ordering::Relaxed);
    // Never refuse an allocation.
    true
}

impl Device {
    /// A device with Embree's `config` string (e.g. `"threads=2"`).
    pub fn new(config: &str) -> Result<Arc<Device>> {
        let c =
            CString::new(config).map_err(|_| Error::Other("embree: config contains NUL".into()))?;
        // SAFETY: `c` is a valid NUL-terminated string for the duration of the call.
        let raw = unsafe { ffi::rtcNewDevice(c.as_ptr()) };
        if raw.is_null() {
            // SAFETY: a null device asks for the error of the failed rtcNewDevice.
            let code = unsafe { ffi::rtcGetDeviceError(std::ptr::null_mut()) };
            return Err(Error::Other(format!(
                "embree: cannot create a device with config '{config}' (error code {code})"
            )));
        }
        let threads = config_threads(config);
        if let Ok(mut live) = LIVE_THREADS.lock() {
            live.push(threads);
        }
        let device = Device {
            raw,
            threads,
            errors: Box::new(Mutex::new(Vec::new())),
            memory: Box::new(AtomicI64::new(0)),
        };
        let user = &*device.errors as *const ErrorLog as *mut c_void;
        let counter = &*device.memory as *const AtomicI64 as *mut c_void;
        // SAFETY: `raw` is a live device; `user` and `counter` point to boxed
        // values that live until after the device is released (see `Drop`).
        unsafe {
            ffi::rtcSetDeviceErrorFunction(raw, Some(record_error), user);
            ffi::rtcSetDeviceMemoryMonitorFunction(raw, Some(record_memory), counter);
        }
        Ok(Arc::new(device))
    }

    /// Bytes Embree holds for this device now (its memory monitor's sum of
    /// allocations and frees since the device was made).
    pub fn memory_bytes(&self) -> i64 {
        self.memory.load(Ordering::Relaxed)
    }

    /// Turns the device's pending error, if any, into an `Err` naming `what`.
    pub fn check(&self, what: &str) -> Result<()> {
        // SAFETY: `raw` is a live device.
        let code = unsafe { ffi::rtcGetDeviceError(self.raw) };
        let mut log = self
            .errors
            .lock()
            .map(|mut l| std::mem::take(&mut *l))
            .unwrap_or_default();
        if code == ffi::RTCError_RTC_ERROR_NONE && log.is_empty() {
            return Ok(());
        }
        let message = log.pop().unwrap_or_else(|| format!("error code {code}"));
        Err(Error::Other(format!("embree: {what}: {message}")))
    }

    pub(super) fn raw(&self) -> ffi::RTCDevice {
        self.raw
    }

    /// Packet widths (of 4, 8, 16) this device traces natively, as its
    /// `NATIVE_RAY{N}_SUPPORTED` properties say; other widths Embree emulates.
    pub fn native_packets(&self) -> Vec<usize> {
        [
            (
                4,
                ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED,
            ),
            (
                8,
                ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED,
            ),
            (
                16,
                ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED,
            ),
        ]
        .into_iter()
        // SAFETY: a live device and valid property ids.
        .filter(|&(_, p)| unsafe { ffi::rtcGetDeviceProperty(self.raw, p) } != 0)
        .map(|(n, _)| n)
        .collect()
    }
}

impl Drop for Device {
    fn drop(&mut self) {
        // SAFETY: releases our reference; no callback can run after the device is
        // gone, and `errors` is dropped after this body.
        unsafe { ffi::rtcReleaseDevice(self.raw) };
        if let Ok(mut live) = LIVE_THREADS.lock() {
            if let Some(i) = live.iter().position(|&t| t == self.threads) {
                live.swap_remove(i);
            }
        }
    }
}

/// Embree's version string, e.g. "3.13.5", from the linked library.
pub fn version() -> String {
    let device = match Device::new("verbose=0") {
        Ok(d) => d,
        Err(_) => return format!("{}.x", api::MAJOR),
    };
    let get = |p| {
        // SAFETY: a live device and a valid property id.
        unsafe { ffi::rtcGetDeviceProperty(device.raw, p) }
    };
    format!(
        "{}.{}.{}",
        get(ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_VERSION_MAJOR),
        get(ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_VERSION_MINOR),
        get(ffi::RTCDeviceProperty_RTC_DEVICE_PROPERTY_VERSION_PATCH)
    )
}

/// Packet widths the linked Embree traces natively on this CPU (empty when
/// no device can be made).
pub fn native_packets() -> Vec<usize> {
    Device::new("verbose=0").map_or(Vec::new(), |d| d.native_packets())
}

/// How a scene whose vertices move is brought up to date on each commit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EmbreeUpdate {
    /// Embree's refit (`RTC_BUILD_QUALITY_REFIT`, dynamic scene).
    Refit,
    /// A full build at this quality.
    Rebuild(Quality),
}

pub(super) fn raw_quality(quality: Quality) -> ffi::RTCBuildQuality {
    match quality {
        Quality::Low => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_LOW,
        Quality::Medium => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_MEDIUM,
        Quality::High => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_HIGH,
    }
}

/// A committed Embree scene holding one triangle mesh.
pub struct EmbreeScene {
    raw: ffi::RTCScene,
    /// The scene's one geometry (the scene holds its reference) and its
    /// vertex buffer (the geometry owns it), for [`EmbreeScene::update_positions`].
    geometry: ffi::RTCGeometry,
    vertices: *mut f32,
    vertex_count: usize,
    /// What the scene build (rtcCommitScene) left allocated: the BVH with its
    /// leaf primitives, as Embree's memory monitor counts it.
    bvh_bytes: usize,
    /// Held, never read: the device (and the error log its callback writes to)
    /// must outlive every scene made on it.
    device: Arc<Device>,
}

// SAFETY: a committed scene is immutable and Embree allows rtcIntersect1 and
// rtcOccluded1 on it from any number of threads at once.
unsafe impl Send for EmbreeScene {}
// SAFETY: as above.
unsafe impl Sync for EmbreeScene {}

impl EmbreeScene {
    /// Builds a scene over `positions` and index triples (triangle `i` of the
    /// scene becomes Embree primitive `i`). `robust` sets `RTC_SCENE_FLAG_ROBUST`.
    pub fn new(
        device: &Arc<Device>,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        quality: Quality,
        robust: bool,
    ) -> Result<EmbreeScene> {
        let q = raw_quality(quality);
        let flags = if robust {
            ffi::RTCSceneFlags_RTC_SCENE_FLAG_ROBUST
        } else {
            ffi::RTCSceneFlags_RTC_SCENE_FLAG_NONE
        };
        Self::with_settings(device, positions, triangles, (q, q), flags)
    }

    /// A scene whose vertices will move ([`EmbreeScene::update_positions`]),
    /// updated as `update` says: refitted (the geometry at
    /// `RTC_BUILD_QUALITY_REFIT` in a `RTC_SCENE_FLAG_DYNAMIC` scene, which
    /// Embree builds with its two-level builder and refits on each commit,
    /// as its documentation advises for deforming meshes), or rebuilt at a
    /// quality on each commit (the scene and geometry at that quality, as
    /// [`EmbreeScene::new`] builds them).
    pub fn for_updates(
        device: &Arc<Device>,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        update: EmbreeUpdate,
    ) -> Result<EmbreeScene> {
        match update {
            EmbreeUpdate::Refit => Self::with_settings(
                device,
                positions,
                triangles,
                (
                    ffi::RTCBuildQuality_RTC_BUILD_QUALITY_LOW,
                    ffi::RTCBuildQuality_RTC_BUILD_QUALITY_REFIT,
                ),
                ffi::RTCSceneFlags_RTC_SCENE_FLAG_DYNAMIC,
            ),
            EmbreeUpdate::Rebuild(q) => Self::new(device, positions, triangles, q, false),
        }
    }

    /// Moves the scene's vertices to `positions` (as many as it was made
    /// with) and commits it: Embree refits or rebuilds, as the scene was
    /// made for.
    pub fn update_positions(&mut self, positions: &[Vec3]) -> Result<()> {
        if positions.len() != self.vertex_count {
            return Err(Error::Other(format!(
                "embree: an update of {} vertices for a scene of {}",
                positions.len(),
                self.vertex_count
            )));
        }
        // SAFETY: `vertices` is the geometry's own buffer of `vertex_count`
        // float3s (12-byte stride), alive while the scene holds the
        // geometry, and `&mut self` means no query runs on the scene now.
        // The geometry and scene are live; the update, geometry commit and
        // scene commit are Embree's documented sequence for changed buffers.
        unsafe {
            std::ptr::copy_nonoverlapping(
                positions.as_ptr() as *const f32,
                self.vertices,
                positions.len() * 3,
            );
            ffi::rtcUpdateGeometryBuffer(
                self.geometry,
                ffi::RTCBufferType_RTC_BUFFER_TYPE_VERTEX,
                0,
            );
            ffi::rtcCommitGeometry(self.geometry);
            ffi::rtcCommitScene(self.raw);
        }
        self.device.check("rtcCommitScene (update)")
    }

    /// [`EmbreeScene::new`] with the scene's and the geometry's build
    /// qualities and the scene flags given.
    fn with_settings(
        device: &Arc<Device>,
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        (quality, geometry_quality): (ffi::RTCBuildQuality, ffi::RTCBuildQuality),
        flags: ffi::RTCSceneFlags,
    ) -> Result<EmbreeScene> {
        if let Some(t) = triangles
            .iter()
            .find(|t| t.iter().any(|&i| i as usize >= positions.len()))
        {
            return Err(Error::Other(format!(
                "embree: triangle {t:?} indexes past {} vertices",
                positions.len()
            )));
        }
        let raw_device = device.raw();
        // SAFETY: a live device.
        let scene = unsafe { ffi::rtcNewScene(raw_device) };
        let mut this = EmbreeScene {
            raw: scene,
            geometry: std::ptr::null_mut(),
            vertices: std::ptr::null_mut(),
            vertex_count: positions.len(),
            bvh_bytes: 0,
            device: device.clone(),
        };
        device.check("rtcNewScene")?;
        // SAFETY: a live scene; plain setters.
        unsafe {
            ffi::rtcSetSceneBuildQuality(scene, quality);
            ffi::rtcSetSceneFlags(scene, flags);
        }
        // SAFETY: a live device; the geometry is released below after attaching.
        let geometry = unsafe {
            ffi::rtcNewGeometry(raw_device, ffi::RTCGeometryType_RTC_GEOMETRY_TYPE_TRIANGLE)
        };
        device.check("rtcNewGeometry")?;
        // The geometry's quality too: a scene at LOW is built by Embree's
        // two-level builder, which builds each mesh at the mesh's own quality
        // (MEDIUM unless set), so without this "LOW" was a binned SAH build
        // (Embree 3.13's bvh_builder_twolevel_internal.h, `MeshBuilder`), not
        // its Morton builder.
        // SAFETY: a live geometry; a plain setter.
        unsafe { ffi::rtcSetGeometryBuildQuality(geometry, geometry_quality) };
        // Embree allocates both buffers itself, which takes care of its alignment
        // and of the padding it reads past the last vertex.
        // SAFETY: a live geometry; Embree returns a buffer of `count` items of
        // `stride` bytes (or null on error, checked before use).
        let vertices = unsafe {
            ffi::rtcSetNewGeometryBuffer(
                geometry,
                ffi::RTCBufferType_RTC_BUFFER_TYPE_VERTEX,
                0,
                ffi::RTCFormat_RTC_FORMAT_FLOAT3,
                12,
                positions.len(),
            )
        } as *mut f32;
        // SAFETY: as above.
        let indices = unsafe {
            ffi::rtcSetNewGeometryBuffer(
                geometry,
                ffi::RTCBufferType_RTC_BUFFER_TYPE_INDEX,
                0,
                ffi::RTCFormat_RTC_FORMAT_UINT3,
                12,
                triangles.len(),
            )
        } as *mut u32;
        if let Err(e) = device.check("rtcSetNewGeometryBuffer") {
            // SAFETY: releases the geometry we own.
            unsafe { ffi::rtcReleaseGeometry(geometry) };
            return Err(e);
        }
        if vertices.is_null() || indices.is_null() {
            // SAFETY: as above.
            unsafe { ffi::rtcReleaseGeometry(geometry) };
            return Err(Error::Other(
                "embree: could not allocate geometry buffers".into(),
            ));
        }
        // SAFETY: the buffers hold exactly positions.len() * 3 floats and
        // triangles.len() * 3 indices (12-byte stride, tightly packed), and do not
        // overlap our slices.
        unsafe {
            std::ptr::copy_nonoverlapping(
                positions.as_ptr() as *const f32,
                vertices,
                positions.len() * 3,
            );
            std::ptr::copy_nonoverlapping(
                triangles.as_ptr() as *const u32,
                indices,
                triangles.len() * 3,
            );
            ffi::rtcCommitGeometry(geometry);
            ffi::rtcAttachGeometry(scene, geometry);
            ffi::rtcReleaseGeometry(geometry);
        }
        // The scene's reference keeps both alive as long as it lives.
        this.geometry = geometry;
        this.vertices = vertices;
        let before = device.memory_bytes();
        // SAFETY: a live scene with its geometry attached.
        unsafe { ffi::rtcCommitScene(scene) };
        device.check("rtcCommitScene")?;
        this.bvh_bytes = (device.memory_bytes() - before).max(0) as usize;
        Ok(this)
    }

    /// The scene's handle, for instances of it.
    pub(super) fn raw(&self) -> ffi::RTCScene {
        self.raw
    }

    /// Bytes of the acceleration structure (nodes and leaf primitives), as
    /// Embree's own memory monitor reports what the build left allocated; the
    /// vertex and index buffers are not counted.
    pub fn bvh_bytes(&self) -> usize {
        self.bvh_bytes
    }

    #[inline]
    pub fn intersect(&self, ray: &Ray) -> Option<Hit> {
        if !embree_takes(ray) {
            return None;
        }
        let mut rh = ffi::RTCRayHit {
            ray: embree_ray(ray),
            hit: ffi::RTCHit {
                geomID: api::INVALID_ID,
                primID: api::INVALID_ID,
                ..Default::default()
            },
        };
        // SAFETY: `self.raw` is a committed scene kept alive by `self`.
        unsafe { api::intersect1(self.raw, &mut rh) };
        (rh.hit.geomID != api::INVALID_ID).then_some(Hit {
            t: rh.ray.tfar,
            u: rh.hit.u,
            v: rh.hit.v,
            tri: rh.hit.primID,
            inst: 0,
        })
    }

    #[inline]
    pub fn occluded(&self, ray: &Ray) -> bool {
        if !embree_takes(ray) {
            return false;
        }
        let mut r = embree_ray(ray);
        // SAFETY: as in `intersect`.
        unsafe { api::occluded1(self.raw, &mut r) };
        r.tfar == f32::NEG_INFINITY
    }
}

/// A packet's valid mask (-1: trace the lane, 0: leave it), aligned as
/// Embree's packets of up to 16 lanes ask.
#[repr(C, align(64))]
struct Valid<const N: usize>([i32; N]);

/// The closest-hit and any-hit queries over a stream in packets of one width:
/// consecutive rays fill a packet's lanes, the last packet partly; invalid
/// rays ([`embree_takes`]) are left out of the valid mask and answer a miss,
/// as the single-ray queries do. Over an instanced scene (`first_tri` given:
/// each instance's first triangle in the scene's numbering) a hit names its
/// instance, and its triangle is numbered as the scene numbers it.
macro_rules! packet_queries {
    ($intersect:ident, $occluded:ident, $n:literal, $ray_hit:ident, $ray:ident, $api_intersect:ident, $api_occluded:ident) => {
        /// # Safety
        /// `scene` must be a committed scene that outlives the call.
        pub(super) unsafe fn $intersect(
            scene: ffi::RTCScene,
            rays: &[Ray],
            hits: &mut [Option<Hit>],
            first_tri: Option<&[u32]>,
            hint: api::Coherence,
        ) {
            for (rays, hits) in rays.chunks($n).zip(hits.chunks_mut($n)) {
                let mut valid = Valid([0i32; $n]);
                // SAFETY: the packet is plain f32 and u32 arrays, for which
                // all-zero bits are valid values (fields of newer Embree
                // versions included).
                let mut p: ffi::$ray_hit = unsafe { std::mem::zeroed() };
                p.hit.geomID = [api::INVALID_ID; $n];
                p.hit.primID = [api::INVALID_ID; $n];
                p.hit.instID = [[api::INVALID_ID; $n]; 1];
                lay_out_packet!(p.ray, rays, valid);
                // SAFETY: the caller guarantees `scene`; `valid` has one
                // aligned i32 per lane.
                unsafe { api::$api_intersect(valid.0.as_ptr(), scene, &mut p, hint) };
                for (lane, hit) in hits.iter_mut().enumerate() {
                    let (prim, inst) = (p.hit.primID[lane], p.hit.instID[0][lane]);
                    let found = valid.0[lane] != 0 && p.hit.geomID[lane] != api::INVALID_ID;
                    let (tri, inst) = match first_tri {
                        None => (prim, 0),
                        Some(_) if inst == api::INVALID_ID => {
                            *hit = None;
                            continue;
                        }
                        Some(first) => (first[inst as usize] + prim, inst),
                    };
                    *hit = found.then(|| Hit {
                        t: p.ray.tfar[lane],
                        u: p.hit.u[lane],
                        v: p.hit.v[lane],
                        tri,
                        inst,
                    });
                }
            }
        }

        /// # Safety
        /// As for the closest-hit query beside it.
        pub(super) unsafe fn $occluded(
            scene: ffi::RTCScene,
            rays: &[Ray],
            occluded: &mut [bool],
            hint: api::Coherence,
        ) {
            for (rays, occluded) in rays.chunks($n).zip(occluded.chunks_mut($n)) {
                let mut valid = Valid([0i32; $n]);
                // SAFETY: as above.
                let mut p: ffi::$ray = unsafe { std::mem::zeroed() };
                lay_out_packet!(p, rays, valid);
                // SAFETY: as above.
                unsafe { api::$api_occluded(valid.0.as_ptr(), scene, &mut p, hint) };
                for (lane, o) in occluded.iter_mut().enumerate() {
                    *o = valid.0[lane] != 0 && p.tfar[lane] == f32::NEG_INFINITY;
                }
            }
        }
    };
}

/// Lays `rays` out in the packet's rays `$p` ([`lanes::lay_out`]), every
/// lane of them with all mask bits set, and marks the lanes Embree takes in
/// `$valid`.
macro_rules! lay_out_packet {
    ($p:expr, $rays:expr, $valid:expr) => {{
        let (p, rays) = (&mut $p, $rays);
        let takes = lanes::lay_out(
            rays,
            [
                &mut p.org_x,
                &mut p.org_y,
                &mut p.org_z,
                &mut p.dir_x,
                &mut p.dir_y,
                &mut p.dir_z,
                &mut p.tnear,
                &mut p.tfar,
            ],
        );
        for lane in 0..rays.len() {
            $valid.0[lane] = -i32::from(takes >> lane & 1 == 1);
            p.mask[lane] = u32::MAX;
        }
    }};
}

packet_queries!(intersect4, occluded4, 4, RTCRayHit4, RTCRay4, intersect4, occluded4);
packet_queries!(intersect8, occluded8, 8, RTCRayHit8, RTCRay8, intersect8, occluded8);
packet_queries!(
    intersect16,
    occluded16,
    16,
    RTCRayHit16,
    RTCRay16,
    intersect16,
    occluded16
);

/// The packet width and coherence hint of `query`, when it is one of
/// Embree's packet paths.
pub(super) fn packet_path(query: Query) -> Option<(usize, api::Coherence)> {
    match query {
        Query::Packet(n) => Some((n, api::Coherence::Coherent)),
        Query::IncoherentPacket(n) => Some((n, api::Coherence::Incoherent)),
        _ => None,
    }
}

/// Closest hits of `rays` in Embree packets of `n` (4, 8 or 16) lanes; see
/// [`packet_queries`] for `first_tri`.
///
/// # Safety
/// `scene` must be a committed scene that outlives the call.
pub(super) unsafe fn intersect_packets(
    scene: ffi::RTCScene,
    n: usize,
    rays: &[Ray],
    hits: &mut [Option<Hit>],
    first_tri: Option<&[u32]>,
    hint: api::Coherence,
) {
    // SAFETY: the caller's guarantee, passed on.
    unsafe {
        match n {
            4 => intersect4(scene, rays, hits, first_tri, hint),
            8 => intersect8(scene, rays, hits, first_tri, hint),
            16 => intersect16(scene, rays, hits, first_tri, hint),
            _ => unreachable!("Embree's packets are 4, 8 or 16 rays"),
        }
    }
}

/// Occlusion of `rays` in Embree packets of `n` (4, 8 or 16) lanes.
///
/// # Safety
/// As for [`intersect_packets`].
pub(super) unsafe fn occluded_packets(
    scene: ffi::RTCScene,
    n: usize,
    rays: &[Ray],
    occluded: &mut [bool],
    hint: api::Coherence,
) {
    // SAFETY: the caller's guarantee, passed on.
    unsafe {
        match n {
            4 => occluded4(scene, rays, occluded, hint),
            8 => occluded8(scene, rays, occluded, hint),
            16 => occluded16(scene, rays, occluded, hint),
            _ => unreachable!("Embree's packets are 4, 8 or 16 rays"),
        }
    }
}

#[cfg(embree3)]
impl EmbreeScene {
    /// The stream API over `rays` (invalid rays answer a miss).
    fn intersect_1m(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        let mut records: Vec<ffi::RTCRayHit> = rays
            .iter()
            .map(|ray| {
                let mut r = embree_ray(ray);
                if !embree_takes(ray) {
                    r.tfar = f32::NEG_INFINITY; // Embree skips rays with tfar < tnear
                }
                ffi::RTCRayHit {
                    ray: r,
                    hit: ffi::RTCHit {
                        geomID: api::INVALID_ID,
                        primID: api::INVALID_ID,
                        ..Default::default()
                    },
                }
            })
            .collect();
        // SAFETY: `self.raw` is a committed scene kept alive by `self`.
        unsafe { api::intersect_stream(self.raw, &mut records) };
        for ((hit, rh), ray) in hits.iter_mut().zip(&records).zip(rays) {
            *hit = (embree_takes(ray) && rh.hit.geomID != api::INVALID_ID).then_some(Hit {
                t: rh.ray.tfar,
                u: rh.hit.u,
                v: rh.hit.v,
                tri: rh.hit.primID,
                inst: 0,
            });
        }
    }

    fn occluded_1m(&self, rays: &[Ray], occluded: &mut [bool]) {
        let mut records: Vec<ffi::RTCRay> = rays
            .iter()
            .map(|ray| {
                let mut r = embree_ray(ray);
                if !embree_takes(ray) {
                    r.tfar = f32::NEG_INFINITY;
                    r.tnear = 0.0;
                }
                r
            })
            .collect();
        // SAFETY: as above.
        unsafe { api::occluded_stream(self.raw, &mut records) };
        for ((o, r), ray) in occluded.iter_mut().zip(&records).zip(rays) {
            *o = embree_takes(ray) && r.tfar == f32::NEG_INFINITY;
        }
    }
}

impl Drop for EmbreeScene {
    fn drop(&mut self) {
        // SAFETY: releases our reference to a scene we created.
        unsafe { ffi::rtcReleaseScene(self.raw) };
    }
}

/// Our ray in Embree's layout: all mask bits set (Embree 4 gives geometries mask
/// 1 by default), time 0.
#[inline]
pub(super) fn embree_ray(ray: &Ray) -> ffi::RTCRay {
    ffi::RTCRay {
        org_x: ray.origin.x,
        org_y: ray.origin.y,
        org_z: ray.origin.z,
        tnear: ray.tmin,
        dir_x: ray.dir.x,
        dir_y: ray.dir.y,
        dir_z: ray.dir.z,
        time: 0.0,
        tfar: ray.tmax,
        mask: u32::MAX,
        id: 0,
        flags: 0,
    }
}

/// Embree as a render backend.
pub struct EmbreeBackend {
    scene: EmbreeScene,
    /// The API streams are traced with.
    query: Query,
    /// Packet widths the device traces natively.
    native: Vec<usize>,
    /// The threads its build ran on ([`tasking_threads`] once its device
    /// was made): more than asked while a device of more threads lived.
    build_threads: usize,
}

impl EmbreeBackend {
    /// Traces streams with `query`: single rays, packets of 4, 8 or 16
    /// (coherent or incoherent), or (Embree 3) the stream API.
    pub fn with_query(mut self, query: Query) -> Result<Self> {
        self.set_query(query)?;
        Ok(self)
    }

    /// [`Self::with_query`] in place (unchanged on an error).
    pub fn set_query(&mut self, query: Query) -> Result<()> {
        match query {
            Query::Single | Query::Packet(4 | 8 | 16) | Query::IncoherentPacket(4 | 8 | 16) => {}
            Query::Stream if api::HAS_STREAMS => {}
            _ => {
                return Err(Error::usage(
                    "--query",
                    format!("Embree {} has no {query} path", api::MAJOR),
                ))
            }
        }
        self.query = query;
        Ok(())
    }

    /// The threads its build ran on (see [`tasking_threads`]).
    pub fn build_threads(&self) -> usize {
        self.build_threads
    }

    /// Packet widths the device traces natively (others it emulates).
    pub fn native_packets(&self) -> &[usize] {
        &self.native
    }

    /// Bytes of Embree's acceleration structure ([`EmbreeScene::bvh_bytes`]).
    pub fn memory_bytes(&self) -> usize {
        self.scene.bvh_bytes()
    }

    /// Builds on a new device with `threads` build threads (device creation,
    /// buffer copies and the BVH build: what [`crate::accel::build_backend`] times).
    pub fn new(scene: &Scene, quality: Quality, robust: bool, threads: usize) -> Result<Self> {
        Self::from_mesh(&scene.positions, &scene.triangles, quality, robust, threads)
    }

    /// Builds over `scene` for per-frame updates ([`EmbreeScene::for_updates`])
    /// on a new device of `threads` threads.
    pub fn for_updates(scene: &Scene, update: EmbreeUpdate, threads: usize) -> Result<Self> {
        super::builder::release_device_above(threads);
        let device = Device::new(&format!("threads={threads}"))?;
        let build_threads = tasking_threads();
        let embree = EmbreeScene::for_updates(&device, &scene.positions, &scene.triangles, update)?;
        Ok(EmbreeBackend {
            scene: embree,
            query: Query::Single,
            native: device.native_packets(),
            build_threads,
        })
    }

    /// Moves the vertices and commits ([`EmbreeScene::update_positions`]).
    pub fn update_positions(&mut self, positions: &[Vec3]) -> Result<()> {
        self.scene.update_positions(positions)
    }

    /// Builds over raw arrays (degenerate triangles included), for stress tests.
    pub fn from_mesh(
        positions: &[Vec3],
        triangles: &[[u32; 3]],
        quality: Quality,
        robust: bool,
        threads: usize,
    ) -> Result<Self> {
        // Spatial splits at high quality get raylab's SBVH budget, not
        // Embree's default of 1.2 references per triangle (params.rs).
        // A kept builder device of more threads would widen this build.
        super::builder::release_device_above(threads);
        let device = Device::new(&format!(
            "threads={threads},max_spatial_split_replications={}",
            embree_split_replications()
        ))?;
        let build_threads = tasking_threads();
        let embree = EmbreeScene::new(&device, positions, triangles, quality, robust)?;
        Ok(EmbreeBackend {
            scene: embree,
            query: Query::Single,
            native: device.native_packets(),
            build_threads,
        })
    }
}

impl Backend for EmbreeBackend {
    fn memory_bytes(&self) -> Option<usize> {
        Some(self.scene.bvh_bytes())
    }

    #[inline]
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.scene.intersect(ray)
    }

    #[inline]
    fn occluded(&self, ray: &Ray) -> bool {
        self.scene.occluded(ray)
    }

    fn intersect_stream(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        let s = &self.scene;
        if let Some((n, hint)) = packet_path(self.query) {
            // SAFETY: `s` is a committed scene kept alive by `self`.
            return unsafe { intersect_packets(s.raw, n, rays, hits, None, hint) };
        }
        match self.query {
            #[cfg(embree3)]
            Query::Stream => s.intersect_1m(rays, hits),
            _ => {
                for (ray, hit) in rays.iter().zip(hits) {
                    *hit = s.intersect(ray);
                }
            }
        }
    }

    fn occluded_stream(&self, rays: &[Ray], occluded: &mut [bool]) {
        let s = &self.scene;
        if let Some((n, hint)) = packet_path(self.query) {
            // SAFETY: as above.
            return unsafe { occluded_packets(s.raw, n, rays, occluded, hint) };
        }
        match self.query {
            #[cfg(embree3)]
            Query::Stream => s.occluded_1m(rays, occluded),
            _ => {
                for (ray, o) in rays.iter().zip(occluded) {
                    *o = s.occluded(ray);
                }
            }
        }
    }

    fn flushes_denormals(&self) -> bool {
        true
    }
}
