//! Comparing the hits of two backends: the same hit, a tie (both hit adjacent
//! triangles at the same distance, as on a shared edge or vertex), or a genuine
//! disagreement (one misses, or one reports a farther hit).

use glam::Vec3;

use crate::geometry::Hit;

/// Relative tolerance on `t` for two hits to count as the same distance.
pub const T_TOLERANCE: f32 = 1e-5;

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Agreement {
    /// Both miss, or both hit the same triangle at the same `t` (within tolerance).
    Same,
    /// Both hit different triangles that share a vertex, at the same `t`
    /// (within tolerance): which one wins is decided by rounding, not geometry.
    Tie,
    /// One misses, or the hits are at different distances or on unrelated triangles.
    Genuine,
}

fn same_t(a: f32, b: f32) -> bool {
    (a - b).abs() <= T_TOLERANCE * a.abs().max(b.abs()).max(1e-30)
}

/// Whether triangles `a` and `b` share at least one vertex position.
pub fn adjacent(a: &[Vec3; 3], b: &[Vec3; 3]) -> bool {
    a.iter().any(|p| b.contains(p))
}

/// Classifies two answers to the same closest-hit query; `triangles` are the
/// scene's triangles by index.
pub fn classify(a: Option<Hit>, b: Option<Hit>, triangles: &[[Vec3; 3]]) -> Agreement {
    match (a, b) {
        (None, None) => Agreement::Same,
        (Some(x), Some(y)) if same_t(x.t, y.t) => {
            if x.tri == y.tri {
                Agreement::Same
            } else if adjacent(&triangles[x.tri as usize], &triangles[y.tri as usize]) {
                Agreement::Tie
            } else {
                Agreement::Genuine
            }
        }
        _ => Agreement::Genuine,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hit(t: f32, tri: u32) -> Option<Hit> {
        Some(Hit {
            t,
            u: 0.0,
            v: 0.0,
            tri,
        })
    }

    #[test]
    fn classification() {
        let tris = [
            [Vec3::ZERO, Vec3::X, Vec3::Y],
            [Vec3::X, Vec3::Y, Vec3::ONE],
            [Vec3::splat(5.0), Vec3::splat(6.0), Vec3::new(5.0, 6.0, 7.0)],
        ];
        assert_eq!(classify(None, None, &tris), Agreement::Same);
        assert_eq!(
            classify(hit(1.0, 0), hit(1.0 + 1e-6, 0), &tris),
            Agreement::Same
        );
        assert_eq!(classify(hit(1.0, 0), hit(1.0, 1), &tris), Agreement::Tie);
        assert_eq!(
            classify(hit(1.0, 0), hit(1.0, 2), &tris),
            Agreement::Genuine
        );
        assert_eq!(
            classify(hit(1.0, 0), hit(1.1, 1), &tris),
            Agreement::Genuine
        );
        assert_eq!(classify(hit(1.0, 0), None, &tris), Agreement::Genuine);
        assert_eq!(classify(None, hit(1.0, 0), &tris), Agreement::Genuine);
    }
}
