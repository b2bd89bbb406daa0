//! `raylab stress`: where intersection methods fail, measured, and proof that
//! raylab itself does not fail on hostile input.
//!
//! - **leaks**: closed meshes (icosphere, cube, torus, a high-valence double
//!   fan, and any OBJ given) and rays aimed exactly at their vertices and at
//!   points on their edges, from inside and from outside; a ray that misses a
//!   mesh it must hit is a leak. Counted per backend and triangle test.
//! - **offset**: a floor translated by 0 .. 1e6 units; rays leaving it by each
//!   [`OffsetStrategy`]: the rate of false self-hits, and of missed occluders
//!   at 1e-3, 5e-5 and 1e-5 of the scene's scale above the floor.
//! - **degenerate**: zero-area, collinear, repeated-vertex, sliver, huge and
//!   tiny, coplanar and identical triangles; random, parallel, axis-aligned and
//!   NaN rays: no panic, no NaN, and the same answers as naive.
//! - **hostile**: randomly mutated OBJ/MTL text: the loader returns a valid
//!   scene or a one-line error, never panics.

mod backends;
mod degenerate;
mod hostile;
mod leaks;
mod offset;

use serde::Serialize;

pub use backends::{default_stress_specs, parse_stress_backends};
pub use degenerate::{
    degenerate_cases, degenerate_suite, degenerate_table, DegenerateCase, DegenerateRow,
};
pub use hostile::{hostile_suite, mutate, HostileReport};
pub use leaks::{
    cube, double_fan, file_mesh, icosphere, leak_meshes, leak_rays, leak_suite, leak_suite_with,
    leak_table, torus, LeakRow, TestMesh,
};
pub use offset::{offset_suite, offset_table, OffsetRow};

/// Everything one `raylab stress` run measured.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StressReport {
    pub leaks: Vec<LeakRow>,
    pub offset: Vec<OffsetRow>,
    pub degenerate: Vec<DegenerateRow>,
    pub hostile: Option<HostileReport>,
}

impl StressReport {
    /// The report as Markdown tables.
    pub fn markdown(&self) -> String {
        let mut out = String::new();
        if !self.leaks.is_empty() {
            out.push_str(
                "## Leaks: rays aimed at vertices and edges of closed meshes that miss them\n\n",
            );
            out.push_str(&leak_table(&self.leaks).markdown());
            out.push('\n');
        }
        if !self.offset.is_empty() {
            out.push_str("## Offset: rays leaving a floor translated by T (rates)\n\n");
            out.push_str(&offset_table(&self.offset).markdown());
            out.push('\n');
        }
        if !self.degenerate.is_empty() {
            out.push_str(
                "## Degenerate input: NaN results, genuine disagreements with naive, wrong answers against the exact reference\n\n",
            );
            out.push_str(&degenerate_table(&self.degenerate).markdown());
            out.push('\n');
        }
        if let Some(h) = &self.hostile {
            out.push_str(&format!(
                "## Hostile OBJ/MTL\n\n{} mutated files: {} loaded, {} rejected with an error, {} panics, {} multi-line errors, {} invalid scenes\n",
                h.cases, h.loaded, h.rejected, h.panics, h.multi_line_errors, h.invalid_scenes
            ));
        }
        out
    }
}
