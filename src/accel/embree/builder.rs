//! Embree's BVH builder (`rtcNewBVH`/`rtcBuildBVH`, rtcore_builder.h) producing a
//! tree in raylab's own layout, so that builders can be compared with everything
//! else (traversal, triangle test, shading) equal.
//!
//! Embree calls back to create nodes and leaves in its thread-local allocator;
//! after the build the temporary tree is converted into raylab's flat layout (a
//! [`Skeleton`]) and the Embree BVH (with all that memory) is released. At quality `High` Embree may split
//! triangles spatially: a leaf then holds a triangle whose bounds were clipped to
//! a part of it, and a triangle can appear in several leaves.

use std::ffi::c_void;
use std::sync::Arc;

use glam::Vec3;

use super::{ffi, Device, Quality};
use crate::accel::bvh::node::{skeleton_of, BuildNode, Skeleton};
use crate::accel::bvh::params::embree_split_replications;
use crate::error::{Error, Result};
use crate::geometry::Aabb;

/// The builder's device, kept between builds (device start-up, its thread
/// pool, is not part of a build) for one thread count at a time: Embree's
/// builds run on the most threads any live device asked for
/// ([`super::tasking_threads`]), so a device kept for two threads would put
/// every later one-thread Embree build on two. Asking for another count, or an
/// Embree scene build on fewer threads ([`release_device_above`]), lets it go.
static KEPT: std::sync::Mutex<Option<(usize, Arc<Device>)>> = std::sync::Mutex::new(None);

/// The builder's device for `threads` build threads.
pub(crate) fn device(threads: usize) -> Result<Arc<Device>> {
    let threads = threads.max(1);
    let mut kept = KEPT.lock().unwrap_or_else(|e| e.into_inner());
    if let Some((t, device)) = kept.as_ref() {
        if *t == threads {
            return Ok(device.clone());
        }
    }
    // Let the old device go before the new one is made.
    *kept = None;
    let device = Device::new(&format!("threads={threads}"))?;
    *kept = Some((threads, device.clone()));
    Ok(device)
}

/// Lets the kept builder device go if it asked for more than `threads`.
pub(crate) fn release_device_above(threads: usize) {
    let mut kept = KEPT.lock().unwrap_or_else(|e| e.into_inner());
    if kept.as_ref().is_some_and(|(t, _)| *t > threads) {
        *kept = None;
    }
}

/// Marks the first field of every callback-allocated node.
const INNER: u32 = 0;
const LEAF: u32 = 1;

#[repr(C)]
struct Inner {
    kind: u32,
    bounds: [Aabb; 2],
    children: [*mut c_void; 2],
}

/// Followed in the same allocation by `count` triangle indices.
#[repr(C)]
struct Leaf {
    kind: u32,
    count: u32,
}

unsafe extern "C" fn create_node(
    alloc: ffi::RTCThreadLocalAllocator,
    children: u32,
    _user: *mut c_void,
) -> *mut c_void {
    debug_assert_eq!(children, 2);
    // SAFETY: Embree's allocator returns memory of the requested size and
    // alignment, owned by the RTCBVH until it is released.
    let p =
        unsafe { ffi::rtcThreadLocalAlloc(alloc, std::mem::size_of::<Inner>(), 16) } as *mut Inner;
    if !p.is_null() {
        // SAFETY: `p` is valid for one `Inner`.
        unsafe {
            p.write(Inner {
                kind: INNER,
                bounds: [Aabb::EMPTY; 2],
                children: [std::ptr::null_mut(); 2],
            })
        };
    }
    p as *mut c_void
}

unsafe extern "C" fn set_children(
    node: *mut c_void,
    children: *mut *mut c_void,
    count: u32,
    _user: *mut c_void,
) {
    let node = node as *mut Inner;
    for i in 0..count.min(2) as usize {
        // SAFETY: `node` came from `create_node`; `children` holds `count` pointers.
        unsafe { (*node).children[i] = *children.add(i) };
    }
}

unsafe extern "C" fn set_bounds(
    node: *mut c_void,
    bounds: *mut *const ffi::RTCBounds,
    count: u32,
    _user: *mut c_void,
) {
    let node = node as *mut Inner;
    for i in 0..count.min(2) as usize {
        // SAFETY: `bounds` holds `count` valid pointers for this call.
        let b = unsafe { &**bounds.add(i) };
        let aabb = Aabb {
            min: Vec3::new(b.lower_x, b.lower_y, b.lower_z),
            max: Vec3::new(b.upper_x, b.upper_y, b.upper_z),
        };
        // SAFETY: `node` came from `create_node`.
        unsafe { (*node).bounds[i] = aabb };
    }
}

unsafe extern "C" fn create_leaf(
    alloc: ffi::RTCThreadLocalAllocator,
    prims: *const ffi::RTCBuildPrimitive,
    count: usize,
    _user: *mut c_void,
) -> *mut c_void {
    let size = std::mem::size_of::<Leaf>() + 4 * count;
    // SAFETY: as in `create_node`.
    let p = unsafe { ffi::rtcThreadLocalAlloc(alloc, size, 16) } as *mut Leaf;
    if p.is_null() {
        return p as *mut c_void;
    }
    // SAFETY: `p` is valid for the header and `count` u32s after it; `prims`
    // holds `count` primitives.
    unsafe {
        p.write(Leaf {
            kind: LEAF,
            count: count as u32,
        });
        let ids = (p as *mut u8).add(std::mem::size_of::<Leaf>()) as *mut u32;
        for i in 0..count {
            ids.add(i).write((*prims.add(i)).primID);
        }
    }
    p as *mut c_void
}

/// The triangles, handed to the split callback through the user pointer.
struct SplitData<'a> {
    triangles: &'a [[Vec3; 3]],
}

/// Splits a primitive's bounds at `position` on axis `dim`: the bounds of the
/// part of the triangle on each side (vertices on that side plus the edge
/// crossings), clipped to the primitive's current bounds.
unsafe extern "C" fn split_primitive(
    prim: *const ffi::RTCBuildPrimitive,
    dim: u32,
    position: f32,
    left: *mut ffi::RTCBounds,
    right: *mut ffi::RTCBounds,
    user: *mut c_void,
) {
    // SAFETY: `user` is the `SplitData` passed to rtcBuildBVH, alive during the
    // build; `prim`, `left` and `right` are valid for this call.
    let (data, prim, left, right) = unsafe {
        (
            &*(user as *const SplitData),
            &*prim,
            &mut *left,
            &mut *right,
        )
    };
    let d = dim as usize;
    let tri = &data.triangles[prim.primID as usize];
    let mut lo = Aabb::EMPTY;
    let mut hi = Aabb::EMPTY;
    for i in 0..3 {
        let (a, b) = (tri[i], tri[(i + 1) % 3]);
        if a[d] <= position {
            lo = lo.grown(a);
        }
        if a[d] >= position {
            hi = hi.grown(a);
        }
        if (a[d] < position && b[d] > position) || (a[d] > position && b[d] < position) {
            let t = (position - a[d]) / (b[d] - a[d]);
            let mut p = a + (b - a) * t;
            p[d] = position;
            lo = lo.grown(p);
            hi = hi.grown(p);
        }
    }
    let current = Aabb {
        min: Vec3::new(prim.lower_x, prim.lower_y, prim.lower_z),
        max: Vec3::new(prim.upper_x, prim.upper_y, prim.upper_z),
    };
    let clip = |b: Aabb, side_max: bool| {
        let mut c = Aabb {
            min: b.min.max(current.min),
            max: b.max.min(current.max),
        };
        if side_max {
            c.max[d] = c.max[d].min(position);
        } else {
            c.min[d] = c.min[d].max(position);
        }
        c
    };
    let (l, r) = (clip(lo, true), clip(hi, false));
    let write = |out: &mut ffi::RTCBounds, b: Aabb| {
        out.lower_x = b.min.x;
        out.lower_y = b.min.y;
        out.lower_z = b.min.z;
        out.upper_x = b.max.x;
        out.upper_y = b.max.y;
        out.upper_z = b.max.z;
    };
    write(left, l);
    write(right, r);
}

/// Builds a BVH over `triangles` with Embree's builder at `quality`, leaves of at
/// most `max_leaf` triangles and the same SAH constants and block size
/// (`sahBlockSize`) as raylab's SAH builder.
pub(crate) fn build(
    device: &Arc<Device>,
    triangles: &[[Vec3; 3]],
    quality: Quality,
    max_leaf: usize,
    sah_block: usize,
) -> Result<Skeleton> {
    if triangles.is_empty() {
        return Ok(Skeleton::default());
    }
    let count = triangles.len();
    // Room for spatial splits at high quality: raylab's SBVH budget.
    let capacity = if quality == Quality::High {
        (count as f64 * embree_split_replications() as f64) as usize
    } else {
        count
    };
    let mut prims: Vec<ffi::RTCBuildPrimitive> = Vec::with_capacity(capacity);
    for (i, t) in triangles.iter().enumerate() {
        let b = Aabb::from_points(t);
        prims.push(ffi::RTCBuildPrimitive {
            lower_x: b.min.x,
            lower_y: b.min.y,
            lower_z: b.min.z,
            geomID: 0,
            upper_x: b.max.x,
            upper_y: b.max.y,
            upper_z: b.max.z,
            primID: i as u32,
        });
    }
    prims.resize(capacity, ffi::RTCBuildPrimitive::default());
    let split = SplitData { triangles };

    // SAH constants: the same as raylab's own SAH builder.
    let (c_t, c_i) = (
        crate::accel::bvh::params::C_TRAVERSAL,
        crate::accel::bvh::params::C_INTERSECT,
    );
    // SAFETY: a live device.
    let bvh = unsafe { ffi::rtcNewBVH(device.raw()) };
    device.check("rtcNewBVH")?;
    let args = ffi::RTCBuildArguments {
        byteSize: std::mem::size_of::<ffi::RTCBuildArguments>(),
        buildQuality: match quality {
            Quality::Low => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_LOW,
            Quality::Medium => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_MEDIUM,
            Quality::High => ffi::RTCBuildQuality_RTC_BUILD_QUALITY_HIGH,
        },
        buildFlags: ffi::RTCBuildFlags_RTC_BUILD_FLAG_NONE,
        maxBranchingFactor: 2,
        // Within raylab's traversal stack of 64.
        maxDepth: 48,
        sahBlockSize: sah_block.clamp(1, 64) as u32,
        minLeafSize: 1,
        maxLeafSize: max_leaf.clamp(1, 32) as u32,
        traversalCost: c_t,
        intersectionCost: c_i,
        bvh,
        primitives: prims.as_mut_ptr(),
        primitiveCount: count,
        primitiveArrayCapacity: capacity,
        createNode: Some(create_node),
        setNodeChildren: Some(set_children),
        setNodeBounds: Some(set_bounds),
        createLeaf: Some(create_leaf),
        splitPrimitive: Some(split_primitive),
        buildProgress: None,
        userPtr: &split as *const SplitData as *mut c_void,
    };
    // SAFETY: `args` points to live data (`prims` with `capacity` slots, `split`)
    // for the duration of the call; the callbacks only touch what they are given.
    let root = unsafe { ffi::rtcBuildBVH(&args) };
    let result = device.check("rtcBuildBVH").and_then(|()| {
        if root.is_null() {
            return Err(Error::Other("embree: rtcBuildBVH returned no tree".into()));
        }
        let mut tri_ids = Vec::with_capacity(capacity);
        // SAFETY: `root` and every node below it were made by our callbacks in
        // memory owned by `bvh`, which is released only after this conversion.
        let tree = unsafe { convert(root, None, triangles, &mut tri_ids) };
        Ok(skeleton_of(tree, tri_ids))
    });
    // SAFETY: releases the Embree BVH and all callback-allocated nodes.
    unsafe { ffi::rtcReleaseBVH(bvh) };
    result
}

/// Converts a callback-made node into the builders' temporary tree, appending
/// leaf triangles to `tri_ids`. `bounds` is the node's box as its parent knows it
/// (None for the root).
///
/// # Safety
/// `node` must be a node created by `create_node` or `create_leaf`, with all
/// children set, in memory that stays alive during the call.
unsafe fn convert(
    node: *mut c_void,
    bounds: Option<Aabb>,
    triangles: &[[Vec3; 3]],
    tri_ids: &mut Vec<u32>,
) -> BuildNode {
    // SAFETY: every node starts with its kind (u32).
    let kind = unsafe { *(node as *const u32) };
    if kind == LEAF {
        let leaf = node as *const Leaf;
        // SAFETY: a leaf header followed by `count` ids (see `create_leaf`).
        let (count, ids) = unsafe {
            (
                (*leaf).count as usize,
                (leaf as *const u8).add(std::mem::size_of::<Leaf>()) as *const u32,
            )
        };
        let start = tri_ids.len() as u32;
        let mut own = Aabb::EMPTY;
        for i in 0..count {
            // SAFETY: within the `count` ids.
            let id = unsafe { *ids.add(i) };
            tri_ids.push(id);
            own = own.union(Aabb::from_points(&triangles[id as usize]));
        }
        // A spatially split leaf's box (from its parent) is smaller than its
        // triangles' boxes; use it, but never larger than the triangles need.
        let bounds = match bounds {
            Some(b) => Aabb {
                min: b.min.max(own.min),
                max: b.max.min(own.max),
            },
            None => own,
        };
        return BuildNode::Leaf {
            bounds,
            start,
            count: count as u32,
        };
    }
    let inner = node as *const Inner;
    // SAFETY: an inner node made by `create_node` with children and bounds set.
    let (child_bounds, children) = unsafe { ((*inner).bounds, (*inner).children) };
    // SAFETY: children are valid nodes of the same tree.
    let left = unsafe { convert(children[0], Some(child_bounds[0]), triangles, tri_ids) };
    // SAFETY: as above.
    let right = unsafe { convert(children[1], Some(child_bounds[1]), triangles, tri_ids) };
    let own = child_bounds[0].union(child_bounds[1]);
    BuildNode::Interior {
        bounds: bounds.unwrap_or(own),
        children: Box::new([left, right]),
    }
}
