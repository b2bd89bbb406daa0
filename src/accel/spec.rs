//! What to build, and building it: a [`BackendSpec`] names one backend with
//! its own options, [`build_backend`] turns it into a [`Built`] backend, timed
//! once here, and every report names a backend by its spec ([`BackendSpec::name`]).

use std::time::{Duration, Instant};

use super::bvh::BuilderKind;
use super::bvh::{BuildParams, BvhBackend};
use super::embree::Quality;
use super::library::{Library, ObvhsLayout, TinybvhLayout};
use super::naive::Naive;
use super::query::Query;
use super::Backend;
use crate::error::Error;
use crate::geometry::Intersector;
use crate::scene::{MeshRef, Scene};

/// The backends a user can pick with `--backend` (and `validate --against`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendKind {
    /// Every triangle for every ray (the study's O(N) baseline).
    Naive,
    /// A hand-built BVH (`--builder` chooses how).
    Bvh,
    /// Intel Embree (16-ray packets by default, rtcIntersect16/rtcOccluded16;
    /// `--query` picks single rays, streams or other packet widths).
    Embree,
    /// tinybvh through tinybvh-rs (`--layout bvh8|bvh`; `--quality high`: BuildHQ).
    Tinybvh,
    /// obvhs (`--layout cwbvh|bvh2`; `--quality` picks its preset).
    Obvhs,
    /// The bvh crate (svenstaro/bvh).
    #[value(name = "bvh-crate")]
    BvhCrate,
}

impl BackendKind {
    /// Every kind, in `--backend`'s order.
    pub const ALL: [BackendKind; 6] = [
        BackendKind::Naive,
        BackendKind::Bvh,
        BackendKind::Embree,
        BackendKind::Tinybvh,
        BackendKind::Obvhs,
        BackendKind::BvhCrate,
    ];

    /// Whether this is another library's BVH.
    pub const fn is_library(self) -> bool {
        matches!(
            self,
            BackendKind::Tinybvh | BackendKind::Obvhs | BackendKind::BvhCrate
        )
    }
}

/// One backend and how to build it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BackendSpec {
    /// The naive scan with its ray/triangle test.
    Naive { intersector: Intersector },
    /// raylab's BVH: builder, width, build threads, the ray/triangle test,
    /// and how streams are traced.
    Bvh {
        params: BuildParams,
        intersector: Intersector,
        query: Query,
    },
    /// Embree's scene at a build quality, optionally robust, built on
    /// `threads`, and the Embree API streams are traced with.
    Embree {
        quality: Quality,
        robust: bool,
        threads: usize,
        query: Query,
    },
    /// Another library's BVH, built on `threads` where it can build in
    /// parallel, traversed one ray at a time with its own kernels.
    Library { library: Library, threads: usize },
}

impl BackendSpec {
    /// The naive scan with Moller-Trumbore.
    pub const fn naive() -> Self {
        BackendSpec::Naive {
            intersector: Intersector::Mt,
        }
    }

    /// raylab's BVH built with `params`, Moller-Trumbore.
    pub const fn bvh(params: BuildParams) -> Self {
        BackendSpec::Bvh {
            params,
            intersector: Intersector::Mt,
            query: Query::Single,
        }
    }

    /// Embree at medium quality, not robust (Embree's defaults), built on `threads`.
    pub const fn embree(threads: usize) -> Self {
        Self::embree_at(Quality::Medium, threads)
    }

    /// Embree at build `quality`, not robust, built on `threads`.
    pub const fn embree_at(quality: Quality, threads: usize) -> Self {
        BackendSpec::Embree {
            quality,
            robust: false,
            threads,
            query: Query::Single,
        }
    }

    /// Another library's BVH built on `threads` (one where it cannot build
    /// in parallel).
    pub const fn library(library: Library, threads: usize) -> Self {
        BackendSpec::Library {
            library,
            threads: if library.builds_in_parallel() {
                threads
            } else {
                1
            },
        }
    }

    /// The backend a render builds when no flag says otherwise: raylab's
    /// 8-wide SAH tree, Moller-Trumbore, built on one thread (the flags'
    /// defaults are read from it), and what "the default bvh" means
    /// wherever one is named by its kind (`validate --against bvh`).
    pub const DEFAULT: BackendSpec = BackendSpec::bvh(BuildParams::sah().with_width(8));

    /// Each kind's default (for `bvh`: [`Self::DEFAULT`]; for the other
    /// libraries their fastest layout at their default build), built on `threads`.
    pub const fn default_for(kind: BackendKind, threads: usize) -> Self {
        match kind {
            BackendKind::Naive => Self::naive(),
            BackendKind::Bvh => Self::DEFAULT.with_build_threads(threads),
            BackendKind::Embree => Self::embree(threads),
            BackendKind::Tinybvh => Self::library(
                Library::Tinybvh {
                    layout: TinybvhLayout::Bvh8,
                    hq: false,
                },
                threads,
            ),
            BackendKind::Obvhs => Self::library(
                Library::Obvhs {
                    layout: ObvhsLayout::CwBvh,
                    quality: Quality::Medium,
                },
                threads,
            ),
            BackendKind::BvhCrate => Self::library(Library::BvhCrate, threads),
        }
    }

    pub const fn kind(&self) -> BackendKind {
        match self {
            BackendSpec::Naive { .. } => BackendKind::Naive,
            BackendSpec::Bvh { .. } => BackendKind::Bvh,
            BackendSpec::Embree { .. } => BackendKind::Embree,
            BackendSpec::Library { library, .. } => match library {
                Library::Tinybvh { .. } => BackendKind::Tinybvh,
                Library::Obvhs { .. } => BackendKind::Obvhs,
                Library::BvhCrate => BackendKind::BvhCrate,
            },
        }
    }

    /// Whether this is Embree (the industrial reference, with its own arithmetic).
    pub const fn is_embree(&self) -> bool {
        matches!(self, BackendSpec::Embree { .. })
    }

    /// Whether this is another library's BVH (with its own arithmetic).
    pub const fn is_library(&self) -> bool {
        matches!(self, BackendSpec::Library { .. })
    }

    /// Whether this is raylab's own (the naive scan or its BVH): the same
    /// triangle test as the naive scan, so the same hits bit for bit.
    pub const fn is_own(&self) -> bool {
        !self.is_embree() && !self.is_library()
    }

    /// The name reports use: `naive`, `bvh-<builder>` (`bvh4-`, `bvh8-` for the
    /// wide trees; `-opt` when reinsertion-optimised), `embree-<quality>` (`-robust`); raylab's backends add
    /// `-watertight` for the watertight triangle test; a query path other
    /// than single rays adds its name (`-packet8`, `-stream`).
    pub fn name(&self) -> String {
        match self.query() {
            Query::Single => self.structure_name(),
            q => format!("{}-{q}", self.structure_name()),
        }
    }

    /// Whether its triangle test promises that no ray passes between two
    /// triangles sharing an edge: raylab's watertight test, Embree's robust
    /// mode.
    pub fn is_robust(&self) -> bool {
        match *self {
            BackendSpec::Naive { intersector } | BackendSpec::Bvh { intersector, .. } => {
                intersector == Intersector::Watertight
            }
            BackendSpec::Embree { robust, .. } => robust,
            BackendSpec::Library { .. } => false,
        }
    }

    /// The name without the query path: what was built.
    pub fn structure_name(&self) -> String {
        let with_test = |base: String, intersector: &Intersector| match intersector {
            Intersector::Mt => base,
            other => format!("{base}-{}", other.name()),
        };
        match self {
            BackendSpec::Naive { intersector } => with_test("naive".into(), intersector),
            BackendSpec::Bvh {
                params,
                intersector,
                ..
            } => {
                let tree = match params.width {
                    2 => "bvh".to_string(),
                    w => format!("bvh{w}"),
                };
                let optimized = if params.optimize { "-opt" } else { "" };
                with_test(
                    format!("{tree}-{}{optimized}", params.builder.name()),
                    intersector,
                )
            }
            BackendSpec::Embree {
                quality, robust, ..
            } => format!(
                "embree-{}{}",
                quality.name(),
                if *robust { "-robust" } else { "" }
            ),
            BackendSpec::Library { library, .. } => library.name(),
        }
    }

    /// The name with what is each kind's default left out where the name
    /// stays unambiguous: Embree's `medium` quality, tinybvh's `bvh8`
    /// layout, obvhs's `cwbvh` layout and `medium` preset (`embree`,
    /// `tinybvh-hq`, `obvhs-bvh2`); raylab's own names are kept whole. The
    /// bench's variants are named with it; it parses back to the same spec.
    pub fn short_name(&self) -> String {
        let query = match self.query() {
            Query::Single => String::new(),
            q => format!("-{q}"),
        };
        let quality = |q: Quality| match q {
            Quality::Medium => String::new(),
            q => format!("-{}", q.name()),
        };
        match self {
            BackendSpec::Embree {
                quality: q, robust, ..
            } => format!(
                "embree{}{}{query}",
                quality(*q),
                if *robust { "-robust" } else { "" }
            ),
            BackendSpec::Library {
                library: Library::Tinybvh { layout, hq },
                ..
            } => format!(
                "tinybvh{}{}",
                match layout {
                    TinybvhLayout::Bvh8 => "",
                    TinybvhLayout::Bvh => "-bvh",
                },
                if *hq { "-hq" } else { "" }
            ),
            BackendSpec::Library {
                library: Library::Obvhs { layout, quality: q },
                ..
            } => format!(
                "obvhs{}{}",
                match layout {
                    ObvhsLayout::CwBvh => "",
                    ObvhsLayout::Bvh2 => "-bvh2",
                },
                quality(*q)
            ),
            _ => self.name(),
        }
    }

    /// Every backend a name can say, built on one thread: each test for
    /// raylab's own, each builder, width and reinsertion for its BVH, each
    /// quality and mode of Embree, each library's layouts and builds; each
    /// with every query path it has ([`Self::queries`]).
    pub fn all() -> Vec<BackendSpec> {
        let mut structures = Vec::new();
        for intersector in [Intersector::Mt, Intersector::Watertight] {
            structures.push(Self::naive().with_intersector(intersector));
            for width in [2, 4, 8] {
                for builder in BuilderKind::ALL {
                    for optimize in [false, true] {
                        let params = BuildParams::for_builder(builder)
                            .with_width(width)
                            .with_optimize(optimize);
                        structures.push(Self::bvh(params).with_intersector(intersector));
                    }
                }
            }
        }
        for quality in [Quality::Low, Quality::Medium, Quality::High] {
            for robust in [false, true] {
                structures.push(BackendSpec::Embree {
                    quality,
                    robust,
                    threads: 1,
                    query: Query::Single,
                });
            }
        }
        for layout in [TinybvhLayout::Bvh8, TinybvhLayout::Bvh] {
            for hq in [false, true] {
                structures.push(Self::library(Library::Tinybvh { layout, hq }, 1));
            }
        }
        for layout in [ObvhsLayout::CwBvh, ObvhsLayout::Bvh2] {
            for quality in [Quality::Low, Quality::Medium, Quality::High] {
                structures.push(Self::library(Library::Obvhs { layout, quality }, 1));
            }
        }
        structures.push(Self::library(Library::BvhCrate, 1));
        structures
            .into_iter()
            .flat_map(|s| {
                s.queries()
                    .into_iter()
                    .filter_map(move |q| s.with_query(q).ok())
            })
            .collect()
    }

    /// How streams are traced (the naive scan: one ray at a time).
    pub const fn query(&self) -> Query {
        match self {
            BackendSpec::Naive { .. } | BackendSpec::Library { .. } => Query::Single,
            BackendSpec::Bvh { query, .. } | BackendSpec::Embree { query, .. } => *query,
        }
    }

    /// The query paths this backend has: single rays for all; raylab's
    /// 8- and 16-ray packets for the 8-wide tree (16 in AVX-512 lanes where
    /// the CPU has it); Embree's packets of 4, 8 and 16 rays, coherent and
    /// incoherent, and its stream API where the linked Embree has it (3,
    /// not 4).
    pub fn queries(&self) -> Vec<Query> {
        match self {
            BackendSpec::Naive { .. } | BackendSpec::Library { .. } => vec![Query::Single],
            BackendSpec::Bvh { params, .. } if params.width == 8 => {
                vec![Query::Single, Query::Packet(8), Query::Packet(16)]
            }
            BackendSpec::Bvh { .. } => vec![Query::Single],
            BackendSpec::Embree { .. } => {
                let mut all = Query::ALL.to_vec();
                #[cfg(feature = "embree")]
                let streams = super::embree::api::HAS_STREAMS;
                #[cfg(not(feature = "embree"))]
                let streams = false;
                if !streams {
                    all.retain(|&q| q != Query::Stream);
                }
                all
            }
        }
    }

    /// The same backend on its fastest query path, which a render uses unless
    /// `--query` says otherwise. Measured by `raylab bench --part trace`
    /// (docs/results.md): for raylab's 8-wide tree its own packets, of 16
    /// rays where the CPU has AVX-512F and of 8 elsewhere; for Embree its
    /// packets of 16 rays where it traces them natively (AVX-512), else of 8.
    pub fn with_fastest_query(self) -> Self {
        let fastest = match self {
            BackendSpec::Bvh { params, .. } if params.width == 8 => {
                if crate::accel::bvh::simd::Avx512::detect().is_some() {
                    Query::Packet(16)
                } else {
                    Query::Packet(8)
                }
            }
            BackendSpec::Embree { .. } => {
                if super::embree::native_packets_or_none().contains(&16) {
                    Query::Packet(16)
                } else {
                    Query::Packet(8)
                }
            }
            _ => Query::Single,
        };
        self.with_query(fastest).unwrap_or(self)
    }

    /// The same backend tracing streams with `query`, or the error `--query`
    /// gets when it has no such path ([`Self::queries`]).
    pub fn with_query(mut self, query: Query) -> crate::Result<Self> {
        let have = self.queries();
        if !have.contains(&query) {
            let names: Vec<String> = have.iter().map(|q| q.name()).collect();
            return Err(Error::usage(
                "--query",
                format!(
                    "{} has no {query} path (it has: {}{})",
                    self.structure_name(),
                    names.join(", "),
                    match (self, query) {
                        (BackendSpec::Bvh { .. }, Query::Packet(8 | 16)) =>
                            "; raylab's packets traverse the 8-wide tree: --bvh-width 8",
                        (BackendSpec::Embree { .. }, Query::Stream) =>
                            "; Embree 4 removed the stream API",
                        _ => "",
                    }
                ),
            ));
        }
        match &mut self {
            BackendSpec::Naive { .. } | BackendSpec::Library { .. } => {}
            BackendSpec::Bvh { query: q, .. } | BackendSpec::Embree { query: q, .. } => *q = query,
        }
        Ok(self)
    }

    /// Threads the build runs on (the naive scan builds nothing: 1).
    pub const fn build_threads(&self) -> usize {
        match self {
            BackendSpec::Naive { .. } => 1,
            BackendSpec::Bvh { params, .. } => params.threads,
            BackendSpec::Embree { threads, .. } | BackendSpec::Library { threads, .. } => *threads,
        }
    }

    /// The same backend built on `threads`.
    pub const fn with_build_threads(mut self, threads: usize) -> Self {
        match &mut self {
            BackendSpec::Naive { .. } => {}
            BackendSpec::Bvh { params, .. } => *params = params.with_threads(threads),
            BackendSpec::Embree { threads: t, .. } => *t = threads,
            BackendSpec::Library {
                library,
                threads: t,
            } => {
                *t = if library.builds_in_parallel() {
                    threads
                } else {
                    1
                }
            }
        }
        self
    }

    /// The same backend with `intersector` for its triangle tests; Embree and
    /// the other libraries have their own tests, so their specs are returned
    /// unchanged.
    pub const fn with_intersector(mut self, test: Intersector) -> Self {
        match &mut self {
            BackendSpec::Naive { intersector } | BackendSpec::Bvh { intersector, .. } => {
                *intersector = test
            }
            BackendSpec::Embree { .. } | BackendSpec::Library { .. } => {}
        }
        self
    }
}

/// What a backend's name may be ([`BackendSpec`]'s `FromStr`), in one line
/// for the errors of the flags that take one.
pub fn name_grammar() -> String {
    let builders: Vec<&str> = BuilderKind::ALL.map(BuilderKind::name).to_vec();
    format!(
        "naive[-watertight], bvh|bvh4|bvh8-BUILDER[-opt][-watertight][-packet8|-packet16] (BUILDER: {}), embree[-low|-medium|-high][-robust][-packet4|-packet8|-packet16[-incoherent]|-stream], tinybvh[-bvh8|-bvh][-hq], obvhs[-cwbvh|-bvh2][-low|-medium|-high], bvh-crate; e.g. {}",
        builders.join(", "),
        BackendSpec::DEFAULT.name()
    )
}

/// A backend named on a command line (`validate --against`, `stress
/// --backends`): its name as reports print it ([`BackendSpec`]'s
/// `FromStr`), or a `--backend` name for that kind's default
/// ([`BackendSpec::default_for`]; `bvh` is [`BackendSpec::DEFAULT`]), built
/// on one thread.
pub fn parse_backend(s: &str) -> Result<BackendSpec, String> {
    use clap::ValueEnum;
    match BackendKind::from_str(s.trim(), false) {
        Ok(kind) => Ok(BackendSpec::default_for(kind, 1)),
        Err(_) => s.parse().map_err(|e: String| {
            let kinds: Vec<&str> = BackendKind::ALL.map(BackendKind::name).to_vec();
            format!("{e}, or a --backend name ({})", kinds.join(", "))
        }),
    }
}

/// Takes `word` (one or more whole `-`-separated words) off the front of
/// `rest`, with the `-` after it; whether it was there.
fn eat(rest: &mut &str, word: &str) -> bool {
    match rest.strip_prefix(word) {
        Some("") => *rest = "",
        Some(after) if after.starts_with('-') => *rest = &after[1..],
        _ => return false,
    }
    true
}

/// The first of `values` whose name is at the front of `rest`, taken off.
fn eat_one<T: Copy>(rest: &mut &str, values: &[T], name: impl Fn(T) -> String) -> Option<T> {
    values.iter().copied().find(|&v| eat(rest, &name(v)))
}

fn eat_quality(rest: &mut &str) -> Option<Quality> {
    eat_one(rest, &[Quality::Low, Quality::Medium, Quality::High], |q| {
        q.name().to_string()
    })
}

/// A backend by name: what [`BackendSpec::name`] and
/// [`BackendSpec::short_name`] print parses back to the same spec, built on
/// one thread (with each builder's own leaf size). The error says what names
/// there are ([`name_grammar`]).
impl std::str::FromStr for BackendSpec {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let unknown = || format!("unknown backend '{s}' (names: {})", name_grammar());
        let mut rest = s.trim();
        let test = |rest: &mut &str| {
            if eat(rest, Intersector::Watertight.name()) {
                Intersector::Watertight
            } else {
                Intersector::Mt
            }
        };
        let spec = if eat(&mut rest, "bvh-crate") {
            Self::library(Library::BvhCrate, 1)
        } else if eat(&mut rest, "naive") {
            Self::naive().with_intersector(test(&mut rest))
        } else if let Some(width) = eat_one(&mut rest, &[2, 4, 8], |w| match w {
            2 => "bvh".into(),
            w => format!("bvh{w}"),
        }) {
            let builder =
                eat_one(&mut rest, &BuilderKind::ALL, |b| b.name().into()).ok_or_else(unknown)?;
            let optimize = eat(&mut rest, "opt");
            let params = BuildParams::for_builder(builder)
                .with_width(width)
                .with_optimize(optimize);
            Self::bvh(params).with_intersector(test(&mut rest))
        } else if eat(&mut rest, "embree") {
            let quality = eat_quality(&mut rest).unwrap_or(Quality::Medium);
            BackendSpec::Embree {
                quality,
                robust: eat(&mut rest, "robust"),
                threads: 1,
                query: Query::Single,
            }
        } else if eat(&mut rest, "tinybvh") {
            let layout = eat_one(&mut rest, &[TinybvhLayout::Bvh8, TinybvhLayout::Bvh], |l| {
                match l {
                    TinybvhLayout::Bvh8 => "bvh8",
                    TinybvhLayout::Bvh => "bvh",
                }
                .into()
            })
            .unwrap_or(TinybvhLayout::Bvh8);
            let hq = eat(&mut rest, "hq");
            Self::library(Library::Tinybvh { layout, hq }, 1)
        } else if eat(&mut rest, "obvhs") {
            let layout = eat_one(&mut rest, &[ObvhsLayout::CwBvh, ObvhsLayout::Bvh2], |l| {
                match l {
                    ObvhsLayout::CwBvh => "cwbvh",
                    ObvhsLayout::Bvh2 => "bvh2",
                }
                .into()
            })
            .unwrap_or(ObvhsLayout::CwBvh);
            let quality = eat_quality(&mut rest).unwrap_or(Quality::Medium);
            Self::library(Library::Obvhs { layout, quality }, 1)
        } else {
            return Err(unknown());
        };
        let query = match spec {
            BackendSpec::Bvh { .. } | BackendSpec::Embree { .. } => {
                // Longest names first: `packet16` is a prefix of
                // `packet16-incoherent`.
                let mut paths = Query::ALL[1..].to_vec();
                paths.sort_by_key(|q| std::cmp::Reverse(q.name().len()));
                eat_one(&mut rest, &paths, Query::name).unwrap_or(Query::Single)
            }
            _ => Query::Single,
        };
        if !rest.is_empty() {
            return Err(unknown());
        }
        spec.with_query(query).map_err(|_| {
            let have: Vec<String> = spec.queries().iter().map(|q| q.name()).collect();
            format!(
                "backend '{s}': {} has no {query} path (it has: {})",
                spec.structure_name(),
                have.join(", ")
            )
        })
    }
}

/// A backend as built: the structure, the spec it was built from, and the wall
/// time from the triangles to a ready structure.
pub struct Built {
    pub spec: BackendSpec,
    pub backend: Box<dyn Backend>,
    pub build_time: Duration,
    /// The threads the build ran on: the spec's
    /// ([`BackendSpec::build_threads`]), but for Embree's scene the most any
    /// live Embree device asked for ([`crate::accel::embree::tasking_threads`]).
    pub build_threads: usize,
}

impl Built {
    /// [`BackendSpec::name`].
    pub fn name(&self) -> String {
        self.spec.name()
    }

    /// An error unless the build ran on the threads its spec asked for: a
    /// timed build must be what it is named.
    pub fn check_build_threads(&self) -> crate::Result<()> {
        if self.build_threads == self.spec.build_threads() {
            return Ok(());
        }
        Err(crate::Error::Other(format!(
            "{}: its build on {} thread(s) ran on {} (Embree builds on the most threads any live Embree device asked for): the timing would be wrong",
            self.name(),
            self.spec.build_threads(),
            self.build_threads
        )))
    }
}

impl AsRef<dyn Backend> for Built {
    fn as_ref(&self) -> &(dyn Backend + 'static) {
        self.backend.as_ref()
    }
}

impl std::ops::Deref for Built {
    type Target = dyn Backend;
    fn deref(&self) -> &(dyn Backend + 'static) {
        self.backend.as_ref()
    }
}

/// Builds the backend `spec` names over `mesh` (a scene, or raw arrays with
/// degenerate triangles kept, as the stress suites want), and times it: from
/// the triangles to a ready structure (gathering, device creation, buffer
/// copies, the build and any collapse to a wide tree).
pub fn build_backend<'a>(spec: &BackendSpec, mesh: impl Into<MeshRef<'a>>) -> crate::Result<Built> {
    let mesh = mesh.into();
    let start = Instant::now();
    let mut build_threads = spec.build_threads();
    let backend: Box<dyn Backend> = match *spec {
        BackendSpec::Naive { intersector } => {
            Box::new(Naive::from_triangles(mesh.triangle_vertices()).with_intersector(intersector))
        }
        BackendSpec::Bvh {
            params,
            intersector,
            query,
        } => Box::new(
            BvhBackend::new(&mesh, &params)?
                .with_intersector(intersector)
                .with_query(query)?,
        ),
        #[cfg(feature = "embree")]
        BackendSpec::Embree {
            quality,
            robust,
            threads,
            query,
        } => {
            let embree = super::embree::EmbreeBackend::from_mesh(
                mesh.positions,
                mesh.triangles,
                quality,
                robust,
                threads,
            )?;
            build_threads = embree.build_threads();
            Box::new(embree.with_query(query)?)
        }
        #[cfg(not(feature = "embree"))]
        BackendSpec::Embree { .. } => return Err(super::embree::unavailable()),
        BackendSpec::Library { library, threads } => build_library(&library, &mesh, threads)?,
    };
    Ok(Built {
        spec: *spec,
        backend,
        build_time: start.elapsed(),
        build_threads,
    })
}

/// Builds the backend `spec` names over `scene`, and times it: a flat
/// scene as [`build_backend`]; an instanced scene with instances, where the
/// backend has them (raylab's two-level tree for `bvh`, Embree's instance
/// geometry for `embree`), else an error naming `--flatten`.
pub fn build_scene_backend(spec: &BackendSpec, scene: &Scene) -> crate::Result<Built> {
    if !scene.is_instanced() {
        return build_backend(spec, scene);
    }
    let start = Instant::now();
    let mut build_threads = spec.build_threads();
    let backend: Box<dyn Backend> = match *spec {
        BackendSpec::Bvh {
            params,
            intersector,
            query,
        } => Box::new(super::bvh::two_level::TwoLevel::new(
            scene,
            &params,
            intersector,
            query,
        )?),
        #[cfg(feature = "embree")]
        BackendSpec::Embree {
            quality,
            robust,
            threads,
            query,
        } => {
            let embree = super::embree::EmbreeInstanced::new(scene, quality, robust, threads)?;
            build_threads = embree.build_threads();
            Box::new(embree.with_query(query)?)
        }
        _ => {
            return Err(crate::Error::usage(
                "--backend",
                format!(
                    "{} cannot trace instances ({} places meshes by instances): use bvh or embree, or --flatten to trace one triangle list",
                    spec.name(),
                    scene.name
                ),
            ))
        }
    };
    Ok(Built {
        spec: *spec,
        backend,
        build_time: start.elapsed(),
        build_threads,
    })
}

/// Another library's BVH over `mesh` (an error naming the cargo feature
/// when this raylab was built without it).
#[allow(unused_variables)] // without the library features
fn build_library(
    library: &Library,
    mesh: &MeshRef,
    threads: usize,
) -> crate::Result<Box<dyn Backend>> {
    Ok(match *library {
        #[cfg(feature = "tinybvh")]
        Library::Tinybvh { layout, hq } => Box::new(super::library::tinybvh::TinybvhBackend::new(
            mesh, layout, hq,
        )?),
        #[cfg(feature = "obvhs")]
        Library::Obvhs { layout, quality } => Box::new(super::library::obvhs::ObvhsBackend::new(
            mesh, layout, quality, threads,
        )?),
        #[cfg(feature = "bvh-crate")]
        Library::BvhCrate => Box::new(super::library::bvh_crate::BvhCrateBackend::new(
            mesh, threads,
        )),
        #[allow(unreachable_patterns)]
        _ => return Err(super::library::unavailable(library)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_derive_from_the_spec() {
        let sah = BuildParams::sah();
        let cases = [
            (BackendSpec::naive(), "naive"),
            (
                BackendSpec::naive().with_intersector(Intersector::Watertight),
                "naive-watertight",
            ),
            (BackendSpec::bvh(BuildParams::median()), "bvh-median"),
            (BackendSpec::bvh(sah.with_width(4)), "bvh4-sah"),
            (
                BackendSpec::bvh(sah.with_width(8)).with_intersector(Intersector::Watertight),
                "bvh8-sah-watertight",
            ),
            (
                BackendSpec::bvh(BuildParams::for_builder(BuilderKind::EmbreeHigh)),
                "bvh-embree-high",
            ),
            (BackendSpec::embree(2), "embree-medium"),
            (
                BackendSpec::Embree {
                    quality: Quality::High,
                    robust: true,
                    threads: 1,
                    query: Query::Single,
                },
                "embree-high-robust",
            ),
        ];
        for (spec, name) in cases {
            assert_eq!(spec.name(), name);
        }
        // Embree keeps its own test whatever is asked.
        let e = BackendSpec::embree(1);
        assert_eq!(e.with_intersector(Intersector::Watertight), e);
    }

    #[test]
    fn every_name_parses_back_to_its_spec() {
        let all = BackendSpec::all();
        let mut names = std::collections::HashSet::new();
        let mut short = std::collections::HashSet::new();
        for spec in &all {
            assert_eq!(spec.name().parse(), Ok(*spec), "{}", spec.name());
            assert_eq!(
                spec.short_name().parse(),
                Ok(*spec),
                "{}",
                spec.short_name()
            );
            assert!(names.insert(spec.name()), "{} twice", spec.name());
            assert!(
                short.insert(spec.short_name()),
                "{} twice",
                spec.short_name()
            );
        }
        assert!(all.contains(&BackendSpec::DEFAULT));
        assert_eq!(BackendSpec::DEFAULT.name(), "bvh8-sah");
        for kind in BackendKind::ALL {
            let spec = BackendSpec::default_for(kind, 1);
            assert!(all.contains(&spec), "{}", spec.name());
        }
        for (short, full) in [
            ("embree", "embree-medium"),
            ("embree-high-packet8", "embree-high-packet8"),
            ("tinybvh", "tinybvh-bvh8"),
            ("tinybvh-hq", "tinybvh-bvh8-hq"),
            ("obvhs", "obvhs-cwbvh-medium"),
            ("obvhs-bvh2", "obvhs-bvh2-medium"),
        ] {
            let spec: BackendSpec = short.parse().unwrap();
            assert_eq!(
                (spec.name().as_str(), spec.short_name().as_str()),
                (full, short)
            );
        }
        for bad in [
            "",
            "bvh",
            "bvh2-sah",
            "bvh16-sah",
            "bvh-sah-opt-opt",
            "bvh-sah-watertight-opt",
            "embree-medium-medium",
            "bvh-sah-packet8",
            "bvh8-sah-single",
            "naive-packet8",
            "tinybvh-packet8",
            "bvh-crate-hq",
            "obvhs-high-bvh2",
            "Naive",
        ] {
            let err = bad.parse::<BackendSpec>().unwrap_err();
            assert!(
                err.contains(&format!("'{bad}'")) && !err.contains('\n'),
                "{err}"
            );
        }
        let err = "bvh-sah-packet8".parse::<BackendSpec>().unwrap_err();
        assert!(err.contains("no packet8 path"), "{err}");
    }

    #[test]
    fn build_threads_follow_the_spec() {
        for kind in BackendKind::ALL {
            let spec = BackendSpec::default_for(kind, 3);
            assert_eq!(spec.kind(), kind);
            // The naive scan builds nothing; tinybvh-rs builds on one thread.
            let serial = matches!(kind, BackendKind::Naive | BackendKind::Tinybvh);
            assert_eq!(spec.build_threads(), if serial { 1 } else { 3 });
            let five = spec.with_build_threads(5);
            assert_eq!(five.build_threads(), if serial { 1 } else { 5 });
            assert_eq!(five.kind(), kind);
        }
    }
}
