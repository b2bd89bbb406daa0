//! tinybvh through tinybvh-rs 0.1.0-beta.3: `Build` or `BuildHQ` (spatial
//! splits), traversed as its 8-wide `BVH8_CPU` (leaves split to 4 triangles,
//! as the conversion requires) or as the binary tree it builds.
//!
//! Two things about the wrapper shape this file:
//! - Its Rust `Ray` is 64 bytes, but the C++ `Ray` it stands for is 128 (the
//!   C++ intersection record carries 64 more bytes of user data). Every ray
//!   handed over here therefore sits at the start of a 128-byte, 64-aligned
//!   [`RayRoom`], so whatever the C++ side reads or writes of its `Ray` is
//!   memory this file owns. `Ray::new` is never called: it returns the C++
//!   `Ray` by value into the 64-byte Rust one.
//! - The binary tree borrows the vertex array it was built from, so
//!   [`WaldTree`] keeps both and extends the borrow (see its SAFETY).
//!
//! Rays are not normalised (tinybvh's `Ray` constructor would), so `t` is in
//! the caller's units; the inverse direction is made as tinybvh makes it
//! (`tinybvh_safercp`: ±1e30 for components within 1e-12 of zero).

use std::mem::ManuallyDrop;

use tinybvh_rs::{bvh, bvh8_cpu, mbvh, Intersector as _};

use super::{started_at_tmin, TinybvhLayout};
use crate::accel::Backend;
use crate::error::Error;
use crate::geometry::{Hit, Ray};
use crate::scene::MeshRef;

/// tinybvh's "no hit" distance.
const BVH_FAR: f32 = tinybvh_rs::INFINITE;

/// The deepest binary tree raylab converts to `BVH8_CPU`. tinybvh's own
/// tree walks use fixed stacks (64 entries in `SplitLeafs`, 256 in the
/// conversions); a scene of 2000 identical triangles makes a 500-deep chain
/// of split leaves, and the conversion then writes past them (a segfault, found
/// by `raylab stress --suite degenerate`). Real scenes are under 40 deep.
const BVH8_MAX_DEPTH: usize = 64;

/// The depth of tinybvh's binary tree (root: 1).
fn depth(nodes: &[bvh::Node]) -> usize {
    let mut deepest = 0;
    let mut stack = vec![(0usize, 1usize)];
    while let Some((i, d)) = stack.pop() {
        deepest = deepest.max(d);
        let node = &nodes[i];
        if !node.is_leaf() {
            let first = node.left_first as usize;
            stack.push((first, d + 1));
            stack.push((first + 1, d + 1));
        }
    }
    deepest
}

/// A tinybvh ray with the room its C++ definition takes (see the module note).
#[repr(C, align(64))]
struct RayRoom {
    ray: tinybvh_rs::Ray,
    _cpp_tail: [u8; 64],
}

// The C++ `Ray` (tiny_bvh.h 1.6.8, INST_IDX_BITS 32): O, mask, D, instIdx, rD
// (44 bytes), then the packed Intersection (inst, t, u, v, prim, auxData,
// 56 user bytes: 84), aligned to 64: 128 bytes.
const _: () = assert!(std::mem::size_of::<RayRoom>() == 128);
const _: () = assert!(std::mem::size_of::<tinybvh_rs::Ray>() == 64);

impl RayRoom {
    /// The ray from `origin` along `dir` with no hit nearer than `tmax`.
    fn new(origin: glam::Vec3, dir: glam::Vec3, tmax: f32) -> Self {
        let safe_rcp = |x: f32| {
            if x.abs() > 1e-12 {
                1.0 / x
            } else if x >= 0.0 {
                BVH_FAR
            } else {
                -BVH_FAR
            }
        };
        let mut ray = tinybvh_rs::Ray {
            origin: origin.to_array(),
            // The C++ `mask` field: all instances (unused by a single BLAS).
            padding_0: 0xFFFF,
            dir: dir.to_array(),
            r_d: [safe_rcp(dir.x), safe_rcp(dir.y), safe_rcp(dir.z)],
            ..Default::default()
        };
        ray.hit.t = tmax.min(BVH_FAR);
        RayRoom {
            ray,
            _cpp_tail: [0; 64],
        }
    }
}

/// The largest origin or direction component tinybvh is given, as Embree's
/// `FLT_LARGE`: past it its traversal meets infinities and NaNs (box minus
/// origin overflows, 1/dir is denormal and flushed to 0, inf * 0), and
/// BVH8_CPU's `Intersect` crashed (SIGSEGV, found by tests/fuzz.rs) on the
/// finite ray from (-f32::MAX, 3e38, f32::MAX) towards the Cornell box.
pub const TINYBVH_MAX_COORDINATE: f32 = 1.844e18;

/// Whether tinybvh can take `ray` (after its move to tmin). tinybvh's
/// `VALIDATE_RAY` (tiny_bvh.h) ends the process ("Input ray contains NaNs",
/// exit 1) when the sum of the direction, `t` and origin is NaN, as it is
/// for a finite ray whose move to tmin overflowed to +inf and -inf; and
/// components past [`TINYBVH_MAX_COORDINATE`] crash its traversal. Such
/// rays are answered as misses without calling it.
fn tinybvh_takes(ray: &tinybvh_rs::Ray) -> bool {
    let (d, o) = (ray.dir, ray.origin);
    ray.hit.t.is_finite()
        && d.iter()
            .chain(o.iter())
            .all(|x| x.abs() <= TINYBVH_MAX_COORDINATE)
}

/// tinybvh's binary tree and the vertices it reads.
struct WaldTree {
    // Declared first, so dropped before the vertices it borrows.
    tree: ManuallyDrop<bvh::BVH<'static>>,
    _vertices: Box<[[f32; 4]]>,
}

impl Drop for WaldTree {
    fn drop(&mut self) {
        // SAFETY: dropped once, here, while `_vertices` is still alive.
        unsafe { ManuallyDrop::drop(&mut self.tree) }
    }
}

/// Runs `f` with the process's stdout (fd 1) going to a temporary file,
/// and returns what was printed there: tinybvh prints warnings ("failed to
/// split large node") with printf, which would land in the middle of
/// `--json` output. Nothing else writes to stdout while a backend is built.
/// Without a temporary file, `f` runs as is. Fd 1 is the whole process's:
/// two builds on two threads swapping it at once could each restore the
/// other's file, so the swaps take turns.
fn capture_stdout<T>(f: impl FnOnce() -> T) -> (T, String) {
    use std::io::{Read, Seek, Write};
    use std::os::fd::AsRawFd;
    static SWAP: std::sync::Mutex<()> = std::sync::Mutex::new(());
    // A poisoned lock (an earlier build panicked) does not stop this one.
    let _turn = SWAP.lock().unwrap_or_else(|e| e.into_inner());
    let path = std::env::temp_dir().join(format!(
        "raylab-tinybvh-stdout-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    let Ok(mut file) = std::fs::OpenOptions::new()
        .create(true)
        .truncate(true)
        .read(true)
        .write(true)
        .open(&path)
    else {
        return (f(), String::new());
    };
    std::fs::remove_file(&path).ok();
    std::io::stdout().flush().ok();
    // SAFETY: fflush(NULL) flushes every C stream; dup and dup2 act on fd 1
    // (open for the process's life) and on `file`'s descriptor, which
    // outlives the swap. A failed dup (-1) skips the swap.
    let saved = unsafe {
        libc::fflush(std::ptr::null_mut());
        let saved = libc::dup(1);
        if saved >= 0 {
            libc::dup2(file.as_raw_fd(), 1);
        }
        saved
    };
    let out = f();
    // SAFETY: as above; `saved` is the descriptor dup returned, closed once.
    unsafe {
        libc::fflush(std::ptr::null_mut());
        if saved >= 0 {
            libc::dup2(saved, 1);
            libc::close(saved);
        }
    }
    let mut printed = String::new();
    if file.rewind().is_ok() {
        file.read_to_string(&mut printed).ok();
    }
    (out, printed)
}

enum Tree {
    Bvh8(bvh8_cpu::BVH),
    Wald(WaldTree),
    /// No triangles: nothing to build (tinybvh needs at least one).
    Empty,
}

pub struct TinybvhBackend {
    tree: Tree,
}

impl TinybvhBackend {
    pub fn new(mesh: &MeshRef, layout: TinybvhLayout, hq: bool) -> crate::Result<Self> {
        if mesh.triangle_count() == 0 {
            return Ok(TinybvhBackend { tree: Tree::Empty });
        }
        let vertices: Box<[[f32; 4]]> = (0..mesh.triangle_count())
            .flat_map(|i| mesh.triangle(i).map(|v| v.extend(0.0).to_array()))
            .collect();
        let failed = |e: tinybvh_rs::Error| Error::Other(format!("tinybvh build: {e}"));
        let (tree, printed) = capture_stdout(|| -> crate::Result<Tree> {
            Ok(match layout {
                TinybvhLayout::Bvh8 => {
                    let mut wald = if hq {
                        bvh::BVH::new_hq(vertices.as_ref().into())
                    } else {
                        bvh::BVH::new(vertices.as_ref().into())
                    }
                    .map_err(failed)?;
                    wald.split_leaves(4);
                    let depth = depth(wald.nodes());
                    if depth > BVH8_MAX_DEPTH {
                        return Err(Error::Other(format!(
                            "tinybvh: its tree is {depth} levels deep here (many triangles with \
                         one centroid, split into a chain of leaves); its BVH8_CPU conversion \
                         crashes on such trees (its traversal stacks assume at most \
                         {BVH8_MAX_DEPTH}): use --layout bvh"
                        )));
                    }
                    let wide = mbvh::BVH::new(&wald);
                    // BVH8_CPU copies the triangles into its leaves: it outlives
                    // the trees it was converted from and the vertex array.
                    Tree::Bvh8(bvh8_cpu::BVH::new(&wide).map_err(failed)?)
                }
                TinybvhLayout::Bvh => {
                    // SAFETY: the slice is the heap allocation of `vertices`,
                    // which is moved (not reallocated) into the same WaldTree,
                    // never mutated, and dropped after the tree (WaldTree's Drop
                    // drops the tree first), so the borrow the tree holds is valid
                    // for the tree's whole life.
                    let borrowed: &'static [[f32; 4]] =
                        unsafe { &*(vertices.as_ref() as *const [[f32; 4]]) };
                    let tree = if hq {
                        bvh::BVH::new_hq(borrowed.into())
                    } else {
                        bvh::BVH::new(borrowed.into())
                    }
                    .map_err(failed)?;
                    Tree::Wald(WaldTree {
                        tree: ManuallyDrop::new(tree),
                        _vertices: vertices,
                    })
                }
            })
        });
        // On success its warnings are passed on as one line on stderr; on
        // failure the error says what went wrong.
        let tree = tree?;
        let printed = printed.split_whitespace().collect::<Vec<_>>().join(" ");
        if !printed.is_empty() {
            crate::console::say(&format!("raylab: tinybvh printed: {printed}"));
        }
        Ok(TinybvhBackend { tree })
    }

    /// tinybvh's closest hit within `(0, tmax)` of the ray started at tmin.
    fn trace(&self, ray: &Ray) -> Option<Hit> {
        if !ray.is_valid() {
            return None;
        }
        let (origin, tmax, shift) = started_at_tmin(ray)?;
        let mut room = RayRoom::new(origin, ray.dir, tmax);
        if !tinybvh_takes(&room.ray) {
            return None;
        }
        match &self.tree {
            Tree::Bvh8(tree) => tree.intersect(&mut room.ray),
            Tree::Wald(wald) => wald.tree.intersect(&mut room.ray),
            Tree::Empty => return None,
        };
        let hit = room.ray.hit;
        (hit.t < tmax.min(BVH_FAR)).then_some(Hit {
            t: hit.t + shift,
            u: hit.u,
            v: hit.v,
            tri: hit.prim,
            inst: 0,
        })
    }
}

impl Backend for TinybvhBackend {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.trace(ray)
    }

    fn occluded(&self, ray: &Ray) -> bool {
        // tinybvh-rs exposes no IsOccluded: the closest hit within tmax.
        self.trace(ray).is_some()
    }
}

// cxx marks opaque C++ types neither Send nor Sync. Both trees are owned
// outright by this backend (no C++ state shared with anything else), and
// after the build only `Intersect` is called, a `const` method of both
// classes (tiny_bvh.h declares no `mutable` member) that reads the tree and
// writes only the caller's ray.
// SAFETY: see above; moving the owner to another thread moves sole ownership.
unsafe impl Send for TinybvhBackend {}
// SAFETY: see above; concurrent calls only read the tree.
unsafe impl Sync for TinybvhBackend {}
