//! An instanced backend's hits numbered as the flattened scene numbers its
//! triangles ([`crate::scene::Scene::flattened`]), so that `validate` can
//! compare a two-level structure with any backend over the flattened list
//! (and judge it with the exact reference over the same triangles).

use std::sync::Arc;

use super::{Backend, Built};
use crate::error::{Error, Result};
use crate::geometry::{Hit, Ray};
use crate::scene::instancing::Instancing;
use crate::scene::Scene;

struct FlatNumbered {
    inner: Box<dyn Backend>,
    instancing: Arc<Instancing>,
}

impl Backend for FlatNumbered {
    fn intersect(&self, ray: &Ray) -> Option<Hit> {
        self.inner.intersect(ray).map(|h| Hit {
            // In range: checked when made.
            tri: self.instancing.flat_index(&h) as u32,
            inst: 0,
            ..h
        })
    }

    fn occluded(&self, ray: &Ray) -> bool {
        self.inner.occluded(ray)
    }

    fn memory_bytes(&self) -> Option<usize> {
        self.inner.memory_bytes()
    }

    fn flushes_denormals(&self) -> bool {
        self.inner.flushes_denormals()
    }
}

/// `built` (a structure over the instanced `scene`) answering with the
/// flattened scene's triangle numbers; fails for a scene without instances
/// or one whose flattened list cannot be numbered in 32 bits.
pub fn numbered_as_flattened(built: Built, scene: &Scene) -> Result<Built> {
    let Some(instancing) = scene.instancing.clone() else {
        return Err(Error::Scene {
            name: scene.name.clone(),
            msg: "has no instances".into(),
        });
    };
    if instancing.placed_triangles() > u64::from(u32::MAX) {
        return Err(Error::Scene {
            name: scene.name.clone(),
            msg: format!(
                "places {} triangles: past 2^32, its flattened list cannot be numbered",
                instancing.placed_triangles()
            ),
        });
    }
    let Built {
        spec,
        backend,
        build_time,
        build_threads,
    } = built;
    Ok(Built {
        spec,
        backend: Box::new(FlatNumbered {
            inner: backend,
            instancing,
        }),
        build_time,
        build_threads,
    })
}
