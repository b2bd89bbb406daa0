//! Polygon triangulation for the loaders: fans for convex polygons (as every
//! OBJ reader does, so convex faces keep the triangles other tools report), ear
//! clipping in the polygon's best-fit plane for concave ones (a fan would cover
//! the notch of a U or fill the hole of a ring).

use glam::{DVec3, Vec3};

/// Corners past which a face is fanned, not ear-clipped: ear clipping's time
/// grows faster than the square of a face's corners (concave stars on one
/// core: 4,000 corners 15 ms, 16,000 0.3 s, 64,000 2.8 s, 400,000 56 s), so
/// one face of a small file could hold the loader for minutes. At this size
/// a face costs under 10 ms. The readers warn (one line, with the count)
/// when they fan such a face ([`FaceTriangulator::huge_faces`]): a concave
/// one may be covered wrongly.
pub const MAX_EAR_CLIPPED: usize = 4096;

/// Triangulates the polygon with corners `corners` (positions of its vertices,
/// in order) into triangles of corner indices, appended to `out`. Fewer than 3
/// corners give nothing. A polygon whose plane cannot be found (all corners on
/// a line) is fanned; its zero-area triangles are dropped later like any
/// degenerate triangle.
pub fn triangulate(corners: &[Vec3], out: &mut Vec<[usize; 3]>) {
    let n = corners.len();
    if n < 3 {
        return;
    }
    if n == 3 || n > MAX_EAR_CLIPPED || is_convex(corners) {
        out.extend((1..n - 1).map(|i| [0, i, i + 1]));
        return;
    }
    let normal = newell_normal(corners);
    let (u, v) = plane_basis(normal);
    let origin = corners[0].as_dvec3();
    let flat: Vec<[f64; 2]> = corners
        .iter()
        .map(|c| {
            let d = c.as_dvec3() - origin;
            [d.dot(u), d.dot(v)]
        })
        .collect();
    let mut indices: Vec<u32> = Vec::with_capacity(3 * (n - 2));
    earcut::Earcut::new().earcut(flat.iter().copied(), &[] as &[u32], &mut indices);
    if indices.is_empty() {
        // Ear clipping found no ear (a self-intersecting outline): fan it, as
        // other readers would, rather than lose the face.
        out.extend((1..n - 1).map(|i| [0, i, i + 1]));
        return;
    }
    out.extend(
        indices
            .chunks_exact(3)
            .map(|t| [t[0] as usize, t[1] as usize, t[2] as usize]),
    );
}

/// Triangulates faces given as vertex indices into one position array (what the
/// OBJ and PLY readers have), reusing its buffers from face to face.
#[derive(Default)]
pub struct FaceTriangulator {
    corners: Vec<Vec3>,
    local: Vec<[usize; 3]>,
    /// Concave faces of more than [`MAX_EAR_CLIPPED`] corners seen (fanned).
    pub huge_faces: usize,
}

impl FaceTriangulator {
    /// Appends the triangles of the face whose corners are `positions[ids[..]]`,
    /// in order, to `out` as index triples; returns how many it appended.
    pub fn face(&mut self, positions: &[Vec3], ids: &[u32], out: &mut Vec<[u32; 3]>) -> usize {
        self.corners.clear();
        self.corners
            .extend(ids.iter().map(|&i| positions[i as usize]));
        if ids.len() > MAX_EAR_CLIPPED && !is_convex(&self.corners) {
            self.huge_faces += 1;
        }
        self.local.clear();
        triangulate(&self.corners, &mut self.local);
        out.extend(self.local.iter().map(|t| t.map(|c| ids[c])));
        self.local.len()
    }
}

/// Newell's normal of a polygon (robust for non-planar and concave outlines);
/// its length is twice the projected area. In f64, so any f32 input is exact.
fn newell_normal(corners: &[Vec3]) -> DVec3 {
    let mut n = DVec3::ZERO;
    let origin = corners[0].as_dvec3();
    for i in 0..corners.len() {
        let a = corners[i].as_dvec3() - origin;
        let b = corners[(i + 1) % corners.len()].as_dvec3() - origin;
        n += a.cross(b);
    }
    n
}

fn plane_basis(normal: DVec3) -> (DVec3, DVec3) {
    let n = normal.normalize_or(DVec3::Z);
    let u = n.any_orthonormal_vector();
    (u, n.cross(u))
}

/// Whether the polygon turns the same way at every corner in its best-fit plane
/// (collinear corners allowed). A polygon with no plane counts as convex.
fn is_convex(corners: &[Vec3]) -> bool {
    let normal = newell_normal(corners);
    if normal == DVec3::ZERO {
        return true;
    }
    let n = corners.len();
    let scale = normal.length();
    (0..n).all(|i| {
        let a = corners[i].as_dvec3();
        let b = corners[(i + 1) % n].as_dvec3();
        let c = corners[(i + 2) % n].as_dvec3();
        // Turn at b against the polygon's normal; a tiny negative turn from
        // rounding on a straight edge still counts as convex.
        (b - a).cross(c - b).dot(normal) >= -1e-12 * scale * scale
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn area(corners: &[Vec3], tris: &[[usize; 3]]) -> f64 {
        tris.iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| corners[i].as_dvec3());
                0.5 * (b - a).cross(c - a).length()
            })
            .sum()
    }

    fn xy(points: &[(f32, f32)]) -> Vec<Vec3> {
        points.iter().map(|&(x, y)| Vec3::new(x, y, 0.0)).collect()
    }

    #[test]
    fn huge_concave_faces_are_fanned_quickly_and_counted() {
        // A star of 400,000 corners (56 s of ear clipping) fans in a blink.
        let n = 400_000;
        let positions: Vec<Vec3> = (0..n)
            .map(|i| {
                let a = std::f32::consts::TAU * i as f32 / n as f32;
                let r = if i % 2 == 0 { 1.0 } else { 0.5 };
                Vec3::new(r * a.cos(), r * a.sin(), 0.0)
            })
            .collect();
        let ids: Vec<u32> = (0..n as u32).collect();
        let mut t = FaceTriangulator::default();
        let mut out = Vec::new();
        let start = std::time::Instant::now();
        assert_eq!(t.face(&positions, &ids, &mut out), n - 2);
        assert!(start.elapsed().as_secs_f64() < 2.0, "{:?}", start.elapsed());
        assert_eq!(t.huge_faces, 1);
        assert_eq!(out[1], [0, 2, 3]);
        // A star at the cap is still ear-clipped, and not counted.
        let small: Vec<u32> = (0..MAX_EAR_CLIPPED as u32).collect();
        let star: Vec<Vec3> = small.iter().map(|&i| positions[i as usize * 97]).collect();
        let _ = t.face(&star, &small, &mut out);
        assert_eq!(t.huge_faces, 1);
    }

    #[test]
    fn convex_polygons_are_fanned() {
        let quad = xy(&[(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]);
        let mut out = Vec::new();
        triangulate(&quad, &mut out);
        assert_eq!(out, vec![[0, 1, 2], [0, 2, 3]]);
    }

    /// A U of outer size 3x3 with a 1x2 notch from the top (area 7), in z = 0.
    fn u_shape() -> Vec<Vec3> {
        xy(&[
            (0.0, 0.0),
            (3.0, 0.0),
            (3.0, 3.0),
            (2.0, 3.0),
            (2.0, 1.0),
            (1.0, 1.0),
            (1.0, 3.0),
            (0.0, 3.0),
        ])
    }

    #[test]
    fn a_u_shape_is_cut_along_its_notch() {
        // A U of outer size 3x3 with a 1x2 notch from the top: area 9 - 2 = 7.
        let u = u_shape();
        let mut out = Vec::new();
        triangulate(&u, &mut out);
        assert_eq!(out.len(), 6);
        assert!((area(&u, &out) - 7.0).abs() < 1e-9, "{}", area(&u, &out));
        // No triangle covers the notch's centre.
        let p = Vec3::new(1.5, 2.0, 0.0);
        for t in &out {
            let [a, b, c] = t.map(|i| u[i]);
            let s = |p0: Vec3, p1: Vec3| (p1 - p0).cross(p - p0).z;
            let inside = s(a, b) > 0.0 && s(b, c) > 0.0 && s(c, a) > 0.0
                || s(a, b) < 0.0 && s(b, c) < 0.0 && s(c, a) < 0.0;
            assert!(!inside, "{t:?} covers the notch");
        }
    }

    #[test]
    fn a_ring_with_a_bridge_keeps_its_hole() {
        // Outer square 4x4, hole 2x2, joined by a zero-width bridge along y = 1:
        // the area is 16 - 4 = 12, a fan would give more.
        let ring = xy(&[
            (0.0, 0.0),
            (4.0, 0.0),
            (4.0, 4.0),
            (0.0, 4.0),
            (0.0, 1.0),
            (1.0, 1.0),
            (1.0, 3.0),
            (3.0, 3.0),
            (3.0, 1.0),
            (1.0, 1.0),
            (0.0, 1.0),
        ]);
        let mut out = Vec::new();
        triangulate(&ring, &mut out);
        assert!(
            (area(&ring, &out) - 12.0).abs() < 1e-6,
            "{}",
            area(&ring, &out)
        );
    }

    #[test]
    fn tilted_concave_polygons_use_their_own_plane() {
        // The U above, rotated out of every axis plane.
        let rot = glam::Quat::from_euler(glam::EulerRot::XYZ, 0.7, -0.4, 1.1);
        let u: Vec<Vec3> = u_shape()
            .into_iter()
            .map(|p| rot * p + Vec3::new(5.0, -2.0, 1.0))
            .collect();
        let mut out = Vec::new();
        triangulate(&u, &mut out);
        assert!((area(&u, &out) - 7.0).abs() < 1e-4, "{}", area(&u, &out));
    }

    #[test]
    fn too_few_corners_give_nothing() {
        let mut out = Vec::new();
        triangulate(&xy(&[(0.0, 0.0), (1.0, 0.0)]), &mut out);
        assert!(out.is_empty());
    }
}
