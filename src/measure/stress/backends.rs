//! Which backends the leak and degenerate suites compare, parsed from
//! `--backends`, and built over raw arrays.

use glam::Vec3;

use crate::accel::bvh::BuildParams;
use crate::accel::embree::Quality;
use crate::accel::library::Library;
use crate::accel::{build_backend, BackendSpec, Built};
use crate::error::{Error, Result};
use crate::geometry::Intersector;
use crate::scene::MeshRef;

/// The backends the leak and degenerate suites compare when `--backends`
/// names none (`all`): the naive scan, the study's median tree and the tree
/// a render builds ([`BackendSpec::DEFAULT`]), each with Moller-Trumbore and
/// the watertight test; Embree plain and robust; each other library's
/// layouts ([`Library::ALL`]); those this raylab was built with, all built
/// on one thread.
pub fn default_stress_specs() -> Vec<BackendSpec> {
    let mut out = Vec::new();
    for intersector in [Intersector::Mt, Intersector::Watertight] {
        for spec in [
            BackendSpec::naive(),
            BackendSpec::bvh(BuildParams::median()),
            BackendSpec::DEFAULT,
        ] {
            out.push(spec.with_intersector(intersector));
        }
    }
    if crate::accel::embree::AVAILABLE {
        for robust in [false, true] {
            out.push(BackendSpec::Embree {
                quality: Quality::Medium,
                robust,
                threads: 1,
                query: crate::accel::Query::Single,
            });
        }
    }
    out.extend(library_specs());
    out
}

/// Each other library's layouts this raylab was built with, on one thread.
fn library_specs() -> impl Iterator<Item = BackendSpec> {
    Library::ALL
        .into_iter()
        .filter(Library::available)
        .map(|library| BackendSpec::library(library, 1))
}

/// Parses `--backends`: backend names as reports print them
/// ([`crate::accel::parse_backend`]: `bvh8-sah-watertight`,
/// `embree-medium-robust`, `tinybvh-bvh`, or a `--backend` name for its
/// default) separated by commas, `libraries` (each other library's layouts)
/// or `all` ([`default_stress_specs`]). A backend this raylab was built
/// without is an error when named.
pub fn parse_stress_backends(s: &str) -> Result<Vec<BackendSpec>> {
    let mut out: Vec<BackendSpec> = Vec::new();
    let mut push = |spec: BackendSpec| {
        if !out.contains(&spec) {
            out.push(spec);
        }
    };
    for p in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        match p {
            "all" => default_stress_specs().into_iter().for_each(&mut push),
            "libraries" => library_specs().for_each(&mut push),
            name => {
                let spec = crate::accel::parse_backend(name)
                    .map_err(|e| Error::usage("--backends", format!("{e}; or all, libraries")))?;
                match spec {
                    BackendSpec::Embree { .. } if !crate::accel::embree::AVAILABLE => {
                        return Err(crate::accel::embree::unavailable())
                    }
                    BackendSpec::Library { library, .. } if !library.available() => {
                        return Err(crate::accel::library::unavailable(&library))
                    }
                    _ => push(spec),
                }
            }
        }
    }
    if out.is_empty() {
        return Err(Error::usage("--backends", "no backend given"));
    }
    Ok(out)
}

/// `specs` built over raw arrays (degenerate triangles kept), with each
/// one's ray/triangle test as reports name it (`mt`, `watertight`, or
/// `embree` for Embree's own).
pub(super) fn stress_backends(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    specs: &[BackendSpec],
) -> Result<Vec<(Built, String)>> {
    built_or_not(positions, triangles, specs)
        .into_iter()
        .map(|(_, built, test)| Ok((built?, test)))
        .collect()
}

/// Each of `specs`, built, or why it could not be: a library refusing an
/// input is a finding, not the end of the suite.
pub(super) fn built_or_not(
    positions: &[Vec3],
    triangles: &[[u32; 3]],
    specs: &[BackendSpec],
) -> Vec<(BackendSpec, Result<Built>, String)> {
    let mesh = MeshRef {
        positions,
        triangles,
    };
    specs
        .iter()
        .map(|&spec| {
            let test = match spec {
                BackendSpec::Naive { intersector } | BackendSpec::Bvh { intersector, .. } => {
                    intersector.name()
                }
                BackendSpec::Embree { .. } => "embree",
                BackendSpec::Library { .. } => "its own",
            };
            let built = build_backend(&spec, mesh);
            (spec, built, test.to_string())
        })
        .collect()
}
