//! Budgets checked before a scene or an image is allocated, so that a small
//! hostile file (a glTF instancing one mesh 10^8 times, nodes sharing children)
//! or a flag (`--size 16384x16384`) is refused in one line instead of taking
//! the machine's memory and dying by abort.
//!
//! The budgets are process-wide: the CLI sets them once from `--max-triangles`
//! and `--max-pixels` before it loads anything, and every reader checks the
//! same numbers without each of the many load paths carrying them.
//!
//! Defaults: 200 million triangles is about 10 GB once loaded and built
//! (positions, indices, materials and a BVH take roughly 50 bytes a
//! triangle), well past the largest scenes raylab is used with (tens of
//! millions) and within a workstation's memory. 100 million pixels (e.g.
//! 10000x10000) is 2.4 GB of image buffers at raylab's 24 bytes a pixel
//! (an f32 RGB accumulator, an 8-bit image and per-pixel statistics).

use std::sync::atomic::{AtomicU64, Ordering};

/// Triangles a scene may expand to unless `--max-triangles` says otherwise.
pub const DEFAULT_MAX_TRIANGLES: u64 = 200_000_000;
/// Pixels an image may have unless `--max-pixels` says otherwise.
pub const DEFAULT_MAX_PIXELS: u64 = 100_000_000;

static MAX_TRIANGLES: AtomicU64 = AtomicU64::new(DEFAULT_MAX_TRIANGLES);
static MAX_PIXELS: AtomicU64 = AtomicU64::new(DEFAULT_MAX_PIXELS);

/// The triangle budget in force.
pub fn max_triangles() -> u64 {
    MAX_TRIANGLES.load(Ordering::Relaxed)
}

/// Sets the triangle budget (`--max-triangles`).
pub fn set_max_triangles(n: u64) {
    MAX_TRIANGLES.store(n, Ordering::Relaxed);
}

/// The pixel budget in force.
pub fn max_pixels() -> u64 {
    MAX_PIXELS.load(Ordering::Relaxed)
}

/// Sets the pixel budget (`--max-pixels`).
pub fn set_max_pixels(n: u64) {
    MAX_PIXELS.store(n, Ordering::Relaxed);
}

/// The message for a scene that would expand past the triangle budget:
/// `what` says what was counted ("expands to 10^8 triangles").
pub fn triangles_over(count: u64) -> Option<String> {
    let max = max_triangles();
    (count > max).then(|| {
        format!("expands to {count} triangles, over the budget of {max} (raise it with --max-triangles)")
    })
}

/// The message for vertices past the budget (three per budgeted triangle:
/// vertices cost memory as triangles do, and a file can declare many vertices
/// and few triangles).
pub fn vertices_over(count: u64) -> Option<String> {
    let max = max_triangles().saturating_mul(3);
    (count > max).then(|| {
        format!("expands to {count} vertices, over the budget of {max} (3 per triangle of --max-triangles; raise it with --max-triangles)")
    })
}

/// Instances any budget allows (a small `--max-triangles` still loads a
/// file that places a few meshes a few times).
pub const MIN_INSTANCES: u64 = 1000;

/// The message for instances past the budget: one per 20 budgeted
/// triangles, at least [`MIN_INSTANCES`] (an instance costs about 250 bytes
/// with its share of the top-level trees, raylab's and Embree's, the price
/// of 5 triangles; 10^7 instances at the default budget).
pub fn instances_over(count: u64) -> Option<String> {
    let max = (max_triangles() / 20).max(MIN_INSTANCES);
    (count > max).then(|| {
        format!("places {count} instances, over the budget of {max} (1 per 20 triangles of --max-triangles; raise it with --max-triangles)")
    })
}

/// The message for an image past the pixel budget.
pub fn pixels_over(width: u32, height: u32) -> Option<String> {
    let max = max_pixels();
    let count = u64::from(width) * u64::from(height);
    (count > max).then(|| {
        format!("{width}x{height} is {count} pixels, over the budget of {max} (raise it with --max-pixels)")
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_take_big_scenes_and_refuse_past_them() {
        // Only the defaults are read here: tests run in threads of one
        // process, and the setters are the CLI's.
        assert_eq!(triangles_over(DEFAULT_MAX_TRIANGLES), None);
        let e = triangles_over(DEFAULT_MAX_TRIANGLES + 1).unwrap();
        assert!(
            e.contains("--max-triangles") && e.contains("200000001"),
            "{e}"
        );
        assert!(vertices_over(3 * DEFAULT_MAX_TRIANGLES + 1).is_some());
        assert_eq!(pixels_over(10_000, 10_000), None);
        let e = pixels_over(16384, 16384).unwrap();
        assert!(
            e.starts_with("16384x16384 is 268435456 pixels") && e.contains("--max-pixels"),
            "{e}"
        );
    }
}
