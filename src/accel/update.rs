//! Following a scene whose vertices move: a backend built on the first frame
//! and brought up to date on each next one by a [`Strategy`]: raylab's tree
//! refitted, rebuilt at a rung, or refitted until its SAH cost has grown past
//! a factor of the cost it had when last built (the policy); Embree's scene
//! refitted or rebuilt at a quality. What each frame costs and how fast the
//! result traces is the `animation` bench part's question.
//!
//! A scene whose instances move (and whose meshes do not) is followed by the
//! two-level structures: raylab's refits or rebuilds its instances' tree
//! (the TLAS) alone, the meshes' trees built once on the first frame;
//! Embree's moves its instances and commits the top scene, which it builds
//! anew (it has no refit of instances).

use super::bvh::params::{Quality, PARALLEL_CUTOFF, REBUILD_FACTOR, REFIT_POLICY_COSTS};
use super::bvh::two_level::{fresh_tlas_cost, TwoLevel};
use super::bvh::{BuildParams, BvhBackend, Tree};
use super::{Backend, Query};
use crate::error::Result;
use crate::geometry::Intersector;
use crate::scene::Scene;

/// How a backend follows the frames of an animation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Strategy {
    /// raylab's 8-wide tree at a rung, built on the first frame and
    /// refitted on every next one.
    Refit(Quality),
    /// raylab's 8-wide tree rebuilt at a rung on every frame.
    Rebuild(Quality),
    /// Refit, and rebuild at the rung when the refitted tree's SAH cost
    /// exceeds `factor` times its cost right after its last build.
    Policy { rung: Quality, factor: f32 },
    /// Embree's refit (`RTC_BUILD_QUALITY_REFIT` in a dynamic scene).
    EmbreeRefit,
    /// Embree's scene rebuilt at a quality on every frame.
    EmbreeRebuild(Quality),
}

fn rung_name(q: Quality) -> &'static str {
    match q {
        Quality::Low => "low",
        Quality::Medium => "medium",
        Quality::High => "high",
    }
}

impl Strategy {
    /// The strategies the `animation` bench part compares: raylab's refit,
    /// rebuild at each rung and the policy at each of `factors` (refit and
    /// policy at the medium rung), and, where linked, Embree's refit and its
    /// rebuilds at each quality.
    pub fn compared(factors: &[f32]) -> Vec<Strategy> {
        let mut out = vec![
            Strategy::Refit(Quality::Medium),
            Strategy::Rebuild(Quality::Low),
            Strategy::Rebuild(Quality::Medium),
            Strategy::Rebuild(Quality::High),
        ];
        out.extend(factors.iter().map(|&factor| Strategy::Policy {
            rung: Quality::Medium,
            factor,
        }));
        if crate::accel::embree::AVAILABLE {
            out.extend([
                Strategy::EmbreeRefit,
                Strategy::EmbreeRebuild(Quality::Low),
                Strategy::EmbreeRebuild(Quality::Medium),
                Strategy::EmbreeRebuild(Quality::High),
            ]);
        }
        out
    }

    /// Its name in reports: `raylab-refit`, `raylab-rebuild-low`,
    /// `raylab-policy-1.5`, `embree-refit`, `embree-rebuild-medium`.
    pub fn name(&self) -> String {
        match self {
            Strategy::Refit(Quality::Medium) => "raylab-refit".into(),
            Strategy::Refit(q) => format!("raylab-refit-{}", rung_name(*q)),
            Strategy::Rebuild(q) => format!("raylab-rebuild-{}", rung_name(*q)),
            Strategy::Policy { factor, .. } => format!("raylab-policy-{factor}"),
            Strategy::EmbreeRefit => "embree-refit".into(),
            Strategy::EmbreeRebuild(q) => format!("embree-rebuild-{}", rung_name(*q)),
        }
    }

    /// Whether it is Embree's.
    pub fn is_embree(&self) -> bool {
        matches!(self, Strategy::EmbreeRefit | Strategy::EmbreeRebuild(_))
    }

    /// The rung a fresh raylab build of the same quality uses (for the SAH
    /// cost over a fresh build's), raylab's strategies only.
    pub fn rung(&self) -> Option<Quality> {
        match *self {
            Strategy::Refit(q) | Strategy::Rebuild(q) => Some(q),
            Strategy::Policy { rung, .. } => Some(rung),
            _ => None,
        }
    }
}

/// Policy factors from the command line: numbers above 1, separated by
/// commas (`1.25,1.5,2`).
pub fn parse_factors(s: &str) -> std::result::Result<Factors, String> {
    s.split(',')
        .map(|f| match f.trim().parse::<f32>() {
            Ok(x) if x.is_finite() && x > 1.0 => Ok(x),
            _ => Err(format!(
                "'{f}' is not a factor above 1 (the refitted tree's SAH cost over its cost when built; default {REBUILD_FACTOR})"
            )),
        })
        .collect::<std::result::Result<Vec<f32>, String>>()
        .map(Factors)
}

/// The policy factors `--rebuild-factor` gives (a type of their own, so
/// that the command line takes the list as one value).
#[derive(Clone, Debug, PartialEq)]
pub struct Factors(pub Vec<f32>);

enum Inner {
    Raylab {
        backend: BvhBackend,
        params: BuildParams,
        /// The SAH cost right after the last build (the policy's reference).
        built_cost: f64,
    },
    /// raylab's two-level tree over a scene whose instances move.
    TwoLevel {
        tree: TwoLevel,
        rung: Quality,
        /// The TLAS's SAH cost right after its last build.
        built_cost: f64,
    },
    #[cfg(feature = "embree")]
    Embree(crate::accel::embree::EmbreeBackend),
    #[cfg(feature = "embree")]
    EmbreeInstanced(crate::accel::embree::EmbreeInstanced),
}

/// A backend following an animation's frames.
pub struct Follower {
    pub strategy: Strategy,
    threads: usize,
    inner: Inner,
}

/// What an update did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Updated {
    /// Whether the structure was built anew (always for the rebuilds, when
    /// the cost grew too much for the policy, never for the refits).
    pub rebuilt: bool,
}

/// The SAH cost the policy compares (node visits and block tests in fixed
/// proportion, so that its decisions do not depend on a timing).
fn policy_cost(tree: &Tree) -> f64 {
    match tree {
        Tree::Wide8(t) => t.sah_cost(&REFIT_POLICY_COSTS),
        Tree::Wide4(t) => t.sah_cost(&REFIT_POLICY_COSTS),
        Tree::Binary(t) => crate::accel::bvh::quality::TreeStats::with_block(t, 1, 4).sah_cost,
    }
}

/// Refits `tree` to `frame` on `threads` threads, on the calling thread
/// below [`PARALLEL_CUTOFF`] triangles as the builds are (waking a pool
/// cost simple_skin's 8 triangles 0.1 ms a refit, 20x the refit).
fn refit(tree: &mut Tree, frame: &Scene, threads: usize) -> Result<()> {
    let threads = if frame.triangle_count() >= PARALLEL_CUTOFF {
        threads
    } else {
        1
    };
    tree.refit(&frame.mesh(), threads)
}

impl Follower {
    /// Builds the structure on `first` (the first frame) with `threads`
    /// build threads.
    pub fn new(strategy: Strategy, first: &Scene, threads: usize) -> Result<Follower> {
        let inner = if first.is_instanced() {
            Self::instanced(strategy, first, threads)?
        } else {
            Self::flat(strategy, first, threads)?
        };
        Ok(Follower {
            strategy,
            threads,
            inner,
        })
    }

    /// The structure over a scene whose instances move: a two-level tree,
    /// its meshes' trees and its TLAS at the strategy's rung.
    fn instanced(strategy: Strategy, first: &Scene, threads: usize) -> Result<Inner> {
        Ok(match strategy {
            Strategy::Refit(q) | Strategy::Rebuild(q) | Strategy::Policy { rung: q, .. } => {
                let params = BuildParams::for_quality(q)
                    .with_width(8)
                    .with_threads(threads);
                let tree = TwoLevel::with_tlas_rung(
                    first,
                    &params,
                    q,
                    Intersector::default(),
                    Query::Single,
                )?;
                let built_cost = tree.tlas_cost(&REFIT_POLICY_COSTS);
                Inner::TwoLevel {
                    tree,
                    rung: q,
                    built_cost,
                }
            }
            #[cfg(feature = "embree")]
            Strategy::EmbreeRefit | Strategy::EmbreeRebuild(_) => {
                use crate::accel::embree::{EmbreeInstanced, EmbreeUpdate};
                let update = match strategy {
                    Strategy::EmbreeRebuild(q) => EmbreeUpdate::Rebuild(q),
                    _ => EmbreeUpdate::Refit,
                };
                Inner::EmbreeInstanced(EmbreeInstanced::for_updates(first, update, threads)?)
            }
            #[cfg(not(feature = "embree"))]
            Strategy::EmbreeRefit | Strategy::EmbreeRebuild(_) => {
                return Err(crate::accel::embree::unavailable())
            }
        })
    }

    /// The structure over a scene whose vertices move.
    fn flat(strategy: Strategy, first: &Scene, threads: usize) -> Result<Inner> {
        Ok(match strategy {
            Strategy::Refit(q) | Strategy::Rebuild(q) | Strategy::Policy { rung: q, .. } => {
                let params = BuildParams::for_quality(q)
                    .with_width(8)
                    .with_threads(threads);
                let backend = BvhBackend::new(&first.mesh(), &params)?;
                let built_cost = policy_cost(&backend.tree);
                Inner::Raylab {
                    backend,
                    params,
                    built_cost,
                }
            }
            #[cfg(feature = "embree")]
            Strategy::EmbreeRefit | Strategy::EmbreeRebuild(_) => {
                use crate::accel::embree::{EmbreeBackend, EmbreeUpdate};
                let update = match strategy {
                    Strategy::EmbreeRebuild(q) => EmbreeUpdate::Rebuild(q),
                    _ => EmbreeUpdate::Refit,
                };
                Inner::Embree(EmbreeBackend::for_updates(first, update, threads)?)
            }
            #[cfg(not(feature = "embree"))]
            Strategy::EmbreeRefit | Strategy::EmbreeRebuild(_) => {
                return Err(crate::accel::embree::unavailable())
            }
        })
    }

    /// Brings the structure up to `frame` (the same triangles, moved).
    pub fn update(&mut self, frame: &Scene) -> Result<Updated> {
        let threads = self.threads;
        match &mut self.inner {
            Inner::Raylab {
                backend,
                params,
                built_cost,
            } => {
                let rebuild = match self.strategy {
                    Strategy::Rebuild(_) => true,
                    Strategy::Policy { factor, .. } => {
                        refit(&mut backend.tree, frame, threads)?;
                        policy_cost(&backend.tree) > factor as f64 * *built_cost
                    }
                    _ => {
                        refit(&mut backend.tree, frame, threads)?;
                        false
                    }
                };
                if rebuild {
                    let query = backend.query();
                    *backend = BvhBackend::new(&frame.mesh(), params)?.with_query(query)?;
                    *built_cost = policy_cost(&backend.tree);
                }
                Ok(Updated { rebuilt: rebuild })
            }
            Inner::TwoLevel {
                tree,
                rung,
                built_cost,
            } => {
                let rebuild = match self.strategy {
                    Strategy::Rebuild(_) => true,
                    _ => {
                        let threads = if frame.instance_count() >= PARALLEL_CUTOFF {
                            threads
                        } else {
                            1
                        };
                        tree.refit_instances(frame, threads)?;
                        match self.strategy {
                            Strategy::Policy { factor, .. } => {
                                tree.tlas_cost(&REFIT_POLICY_COSTS) > factor as f64 * *built_cost
                            }
                            _ => false,
                        }
                    }
                };
                if rebuild {
                    tree.rebuild_instances(frame, *rung, threads)?;
                    *built_cost = tree.tlas_cost(&REFIT_POLICY_COSTS);
                }
                Ok(Updated { rebuilt: rebuild })
            }
            #[cfg(feature = "embree")]
            Inner::EmbreeInstanced(e) => {
                let Some(instancing) = &frame.instancing else {
                    return Err(crate::Error::Other(format!(
                        "{}: a frame without instances for Embree's instanced scene",
                        frame.name
                    )));
                };
                e.move_instances(instancing)?;
                Ok(Updated { rebuilt: true })
            }
            #[cfg(feature = "embree")]
            Inner::Embree(e) => {
                e.update_positions(&frame.positions)?;
                Ok(Updated {
                    rebuilt: self.strategy != Strategy::EmbreeRefit,
                })
            }
        }
    }

    /// Traces streams with `query` from now on.
    pub fn set_query(&mut self, query: Query) -> Result<()> {
        match &mut self.inner {
            Inner::Raylab { backend, .. } => backend.set_query(query),
            Inner::TwoLevel { tree, .. } => tree.set_query(query),
            #[cfg(feature = "embree")]
            Inner::Embree(e) => e.set_query(query),
            #[cfg(feature = "embree")]
            Inner::EmbreeInstanced(e) => e.set_query(query),
        }
    }

    /// The query paths it can trace with (Embree's packets coherent and
    /// incoherent).
    pub fn queries(&self) -> Vec<Query> {
        let mut paths = vec![Query::Single, Query::Packet(8), Query::Packet(16)];
        if self.strategy.is_embree() {
            paths.extend([Query::IncoherentPacket(8), Query::IncoherentPacket(16)]);
        }
        paths
    }

    /// The backend as it stands.
    pub fn backend(&self) -> &dyn Backend {
        match &self.inner {
            Inner::Raylab { backend, .. } => backend,
            Inner::TwoLevel { tree, .. } => tree,
            #[cfg(feature = "embree")]
            Inner::Embree(e) => e,
            #[cfg(feature = "embree")]
            Inner::EmbreeInstanced(e) => e,
        }
    }

    /// The SAH cost the policy compares, for raylab's trees.
    pub fn policy_cost(&self) -> Option<f64> {
        match &self.inner {
            Inner::Raylab { backend, .. } => Some(policy_cost(&backend.tree)),
            Inner::TwoLevel { tree, .. } => Some(tree.tlas_cost(&REFIT_POLICY_COSTS)),
            #[cfg(feature = "embree")]
            Inner::Embree(_) | Inner::EmbreeInstanced(_) => None,
        }
    }
}

/// The SAH cost of a fresh raylab build at `rung` on `frame` (what the
/// strategies' costs are divided by): of the TLAS alone for a scene whose
/// instances move.
pub fn fresh_cost(frame: &Scene, rung: Quality, threads: usize) -> Result<f64> {
    if frame.is_instanced() {
        return fresh_tlas_cost(frame, rung, threads, &REFIT_POLICY_COSTS);
    }
    let params = BuildParams::for_quality(rung)
        .with_width(8)
        .with_threads(threads);
    let tree = crate::accel::bvh::build(&frame.mesh(), &params)?;
    Ok(policy_cost(&tree))
}
