//! What the builders read and work on: the input triangles ([`Triangles`]),
//! a triangle's reference as the builders move it ([`PrimRef`], 32 bytes),
//! boxes as SIMD vectors ([`Box4`]), what a split knows of a node
//! ([`NodeInfo`]), and the exact parallel fold they are computed with.

use glam::{BVec4A, Vec3, Vec4};
use rayon::prelude::*;

use super::params::PARALLEL_REDUCE_CUTOFF;
use super::simd::prefetch;
use crate::geometry::Aabb;
use crate::scene::MeshRef;

/// The triangles a BVH is built over: vertex triples in a slice, or a mesh's
/// (read through its index list, so the build makes no copy of them).
pub trait Triangles: Sync {
    fn count(&self) -> usize;
    /// The vertices of triangle `i`.
    fn get(&self, i: usize) -> [Vec3; 3];
    /// A hint that triangle `i` will be read soon, for reads in an order
    /// the hardware cannot guess (the leaf fill): `stage` 0 asks for what
    /// locates its vertices (a scene's index triple), 1 for the vertices
    /// themselves (reading the triple, which stage 0 should have brought).
    #[inline]
    fn prefetch(&self, _i: usize, _stage: u8) {}
}

/// Every triangle's vertices, gathered in index order (in parallel when
/// `parallel`): for builders that read triangles at random or need a slice.
pub(crate) fn gathered<T: Triangles + ?Sized>(triangles: &T, parallel: bool) -> Vec<[Vec3; 3]> {
    if parallel {
        use rayon::prelude::*;
        (0..triangles.count())
            .into_par_iter()
            .map(|i| triangles.get(i))
            .collect()
    } else {
        (0..triangles.count()).map(|i| triangles.get(i)).collect()
    }
}

/// Slices and vectors of vertex triples.
impl<L: AsRef<[[Vec3; 3]]> + Sync + ?Sized> Triangles for L {
    #[inline]
    fn count(&self) -> usize {
        self.as_ref().len()
    }
    #[inline]
    fn get(&self, i: usize) -> [Vec3; 3] {
        self.as_ref()[i]
    }
}

impl Triangles for MeshRef<'_> {
    #[inline]
    fn count(&self) -> usize {
        self.triangle_count()
    }
    #[inline]
    fn get(&self, i: usize) -> [Vec3; 3] {
        self.triangle(i)
    }
    #[inline]
    fn prefetch(&self, i: usize, stage: u8) {
        let Some(triple) = self.triangles.get(i) else {
            return;
        };
        if stage == 0 {
            prefetch(triple);
        } else {
            for &v in triple {
                if let Some(p) = self.positions.get(v as usize) {
                    prefetch(p);
                }
            }
        }
    }
}

/// The x, y and z lanes of a vector.
const XYZ: BVec4A = BVec4A::new(true, true, true, false);

/// Twice the bias that puts a scene index's bits in the normal float range.
const INDEX_BIAS: u32 = 0x0080_0000;

/// Most triangles a build takes: indices stay below this after the bias.
pub(crate) const MAX_TRIANGLES: usize = (0x7F00_0000 - 1) as usize;

/// A triangle as the builders see it: its box as two SIMD vectors (32 bytes,
/// as Embree's `PrimRef`). The minimum's w lane carries the scene index's bits,
/// shifted up by one exponent step so that they always form a normal float:
/// arithmetic on whole vectors never meets a denormal (slow on many CPUs).
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub(crate) struct PrimRef {
    pub lo: Vec4,
    pub hi: Vec4,
}

impl PrimRef {
    /// The reference to triangle `index` (at most [`MAX_TRIANGLES`]) with box `b`.
    #[inline]
    pub fn new(b: &Aabb, index: u32) -> PrimRef {
        debug_assert!((index as usize) < MAX_TRIANGLES);
        PrimRef {
            lo: b.min.extend(f32::from_bits(index + INDEX_BIAS)),
            hi: b.max.extend(0.0),
        }
    }

    /// Scene triangle index; also the final tie-break in every sort, so
    /// partitions never depend on the order primitives arrive in.
    #[inline]
    pub fn index(&self) -> u32 {
        self.lo.w.to_bits() - INDEX_BIAS
    }

    /// The reference carrying `key` (below 2^30) in its maximum's w lane,
    /// biased as the index is so that it is a normal float: the LBVH keeps
    /// each reference's Morton code there (the lane is otherwise unused).
    #[inline]
    pub fn with_key(self, key: u32) -> PrimRef {
        debug_assert!(key < 1 << 30);
        PrimRef {
            lo: self.lo,
            hi: self.hi.truncate().extend(f32::from_bits(key + INDEX_BIAS)),
        }
    }

    /// The key [`PrimRef::with_key`] put in.
    #[inline]
    pub fn key(&self) -> u32 {
        self.hi.w.to_bits() - INDEX_BIAS
    }

    #[cfg(test)]
    pub fn bounds(&self) -> Aabb {
        Aabb {
            min: self.lo.truncate(),
            max: self.hi.truncate(),
        }
    }

    /// Twice the box centre in xyz (`lo + hi`): what the builders bin and sort
    /// by, in the same order as the centre, without a multiplication. The w
    /// lane is 0, by a blend, not arithmetic: the sum of the index's bits
    /// is a tiny normal, but two such sums differ by a denormal, and the
    /// binning's `(c - lo) * scale` then took a microcode assist per
    /// primitive on Intel cores (Sapphire Rapids: 2.3x the SAH build time).
    #[inline]
    pub fn centroid2(&self) -> Vec4 {
        Vec4::select(XYZ, self.lo + self.hi, Vec4::ZERO)
    }
}

/// An axis-aligned box as two SIMD vectors (w lanes unused).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Box4 {
    pub lo: Vec4,
    pub hi: Vec4,
}

impl Box4 {
    pub const EMPTY: Box4 = Box4 {
        lo: Vec4::INFINITY,
        hi: Vec4::NEG_INFINITY,
    };

    #[inline]
    pub fn union(self, o: Box4) -> Box4 {
        Box4 {
            lo: self.lo.min(o.lo),
            hi: self.hi.max(o.hi),
        }
    }

    #[inline]
    pub fn grow(&mut self, p: Vec4) {
        self.lo = self.lo.min(p);
        self.hi = self.hi.max(p);
    }

    /// Surface area, 0 for the empty box; the same arithmetic as
    /// [`Aabb::surface_area`], so both give the same bits.
    #[inline]
    pub fn area(self) -> f32 {
        let e = (self.hi - self.lo).max(Vec4::ZERO);
        2.0 * (e.x * e.y + e.y * e.z + e.z * e.x)
    }

    #[inline]
    pub fn to_aabb(self) -> Aabb {
        Aabb {
            min: self.lo.truncate(),
            max: self.hi.truncate(),
        }
    }
}

/// What a node's split needs to know of its primitives, and what a split
/// returns for each child: the union of their boxes and the bounds of their
/// doubled centroids ([`PrimRef::centroid2`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct NodeInfo {
    pub bounds: Box4,
    pub centroids: Box4,
}

impl NodeInfo {
    /// Of `prims`, in parallel chunks for large inputs when `parallel`.
    pub fn of(prims: &[PrimRef], parallel: bool) -> NodeInfo {
        let empty = NodeInfo {
            bounds: Box4::EMPTY,
            centroids: Box4::EMPTY,
        };
        reduce_prims(
            prims,
            parallel,
            empty,
            |i, p| {
                i.bounds = i.bounds.union(Box4 { lo: p.lo, hi: p.hi });
                i.centroids.grow(p.centroid2());
            },
            |a, b| {
                a.bounds = a.bounds.union(b.bounds);
                a.centroids = a.centroids.union(b.centroids);
            },
        )
    }
}

/// Folds `prims` into one value; in parallel chunks for large inputs when
/// `parallel`. Every use is exact (box unions, integer counts), so the result does
/// not depend on the chunking and the tree stays deterministic.
pub(crate) fn reduce_prims<T: Send + Sync + Clone>(
    prims: &[PrimRef],
    parallel: bool,
    identity: T,
    fold: impl Fn(&mut T, &PrimRef) + Sync,
    combine: impl Fn(&mut T, T) + Sync + Send,
) -> T {
    // Accumulators are updated in place: a large one (SAH bins) must not be
    // moved or copied per primitive, nor cloned for a serial fold.
    let fold_into = |mut acc: T, chunk: &[PrimRef]| {
        for p in chunk {
            fold(&mut acc, p);
        }
        acc
    };
    if parallel && prims.len() >= PARALLEL_REDUCE_CUTOFF {
        prims
            .par_chunks(PARALLEL_REDUCE_CUTOFF / 4)
            .map(|chunk| fold_into(identity.clone(), chunk))
            .reduce(
                || identity.clone(),
                |mut a, b| {
                    combine(&mut a, b);
                    a
                },
            )
    } else {
        fold_into(identity, prims)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prim_refs_keep_index_and_box_and_never_hold_denormals() {
        let b = Aabb::from_points(&[Vec3::new(-1.0, 2.0, 3.0), Vec3::new(4.0, 5.0, 6.5)]);
        for index in [0, 1, 12345, (MAX_TRIANGLES - 1) as u32] {
            let p = PrimRef::new(&b, index);
            assert_eq!(p.index(), index);
            assert_eq!(p.bounds(), b);
            assert!(p.lo.w.is_normal(), "{index}");
            // No lane of a centroid, nor of a difference of two, is denormal.
            assert_eq!(p.centroid2().w.to_bits(), 0, "{index}");
            assert_eq!(p.centroid2().truncate(), b.min + b.max);
        }
    }
}
