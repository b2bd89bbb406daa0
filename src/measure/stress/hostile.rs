//! The hostile suite: randomly mutated OBJ/MTL text, loaded; each must give a
//! valid scene or a one-line error, never a panic.

use std::path::Path;

use serde::Serialize;

use crate::error::Result;
use crate::rng::Rng;

/// What the loader did with mutated files.
#[derive(Clone, Debug, Default, Serialize)]
pub struct HostileReport {
    pub cases: usize,
    pub loaded: usize,
    pub rejected: usize,
    pub panics: usize,
    /// Errors whose message is not a single line.
    pub multi_line_errors: usize,
    /// Loaded scenes with out-of-range indices or non-finite values (must be 0).
    pub invalid_scenes: usize,
}

const BASE_OBJ: &str = "mtllib box.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvn 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
usemtl white\nf 1/1/1 2/2/1 3/3/1 4/1/1\nv 0 1 0\nv 1 1 0\nv 0 1 1\nusemtl light\nf -3 -2 -1\ng rest\ns 1\nf 1 2 5\n";
const BASE_MTL: &str = "newmtl white\nKa 0.1 0.1 0.1\nKd 0.7 0.7 0.7\nNs 10\nnewmtl light\nKd 0.8 0.8 0.8\nKe 10 10 10\nKs 0.5 0.5 0.5\n";
const NASTY: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "1e39",
    "-1e39",
    "0",
    "-0",
    "4294967296",
    "-4294967297",
    "18446744073709551616",
    "-1",
    "99999999999",
    "1/",
    "//",
    "/1/",
    "1//1//1",
    "\u{0}",
    "\u{feff}",
    "#",
    "f",
    "v",
    "\t",
    "1e-45",
    "",
];

/// A random mutation of `base`: deleted, inserted and replaced characters,
/// nasty tokens, truncation, duplicated lines.
pub fn mutate(base: &str, rng: &mut Rng) -> String {
    let mut text: Vec<char> = base.chars().collect();
    let pick = |rng: &mut Rng, n: usize| (rng.next_f32() * n as f32) as usize % n.max(1);
    for _ in 0..1 + pick(rng, 4) {
        if text.is_empty() {
            break;
        }
        let at = pick(rng, text.len());
        match pick(rng, 6) {
            0 => {
                text.remove(at);
            }
            1 => text.insert(at, char::from_u32(pick(rng, 0x3000) as u32).unwrap_or('?')),
            2 => {
                for (k, c) in NASTY[pick(rng, NASTY.len())].chars().enumerate() {
                    text.insert(at + k, c);
                }
            }
            3 => text.truncate(at),
            4 => {
                let s: String = text.iter().collect();
                let mut words: Vec<String> = s.split(' ').map(str::to_string).collect();
                let w = pick(rng, words.len());
                words[w] = NASTY[pick(rng, NASTY.len())].to_string();
                text = words.join(" ").chars().collect();
            }
            _ => {
                let s: String = text.iter().collect();
                let lines: Vec<&str> = s.lines().collect();
                if !lines.is_empty() {
                    let line = lines[pick(rng, lines.len())].to_string();
                    text.extend(format!("\n{line}\n").chars());
                }
            }
        }
    }
    text.into_iter().collect()
}

/// Loads `cases` mutated OBJ files (every third with a mutated MTL) from a
/// scratch folder, counting outcomes; a panic is caught and counted.
pub fn hostile_suite(cases: usize, seed: u64) -> Result<HostileReport> {
    let dir = std::env::temp_dir().join(format!("raylab-stress-{}-{seed}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| crate::Error::io(&dir, e))?;
    let mut rng = Rng::for_pixel(0, seed, 0x4057);
    let mut report = HostileReport {
        cases,
        ..HostileReport::default()
    };
    // Silence the panic message of a caught panic: the count is the result.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for case in 0..cases {
        let obj = mutate(BASE_OBJ, &mut rng);
        let mtl = if case % 3 == 0 {
            mutate(BASE_MTL, &mut rng)
        } else {
            BASE_MTL.to_string()
        };
        if std::fs::write(dir.join("box.mtl"), &mtl).is_err() {
            continue;
        }
        match std::panic::catch_unwind(|| {
            crate::scene::obj::load_obj_str(&obj, Path::new("hostile.obj"), &dir)
        }) {
            Err(_) => report.panics += 1,
            Ok(Err(e)) => {
                report.rejected += 1;
                report.multi_line_errors += (e.to_string().lines().count() != 1) as usize;
            }
            Ok(Ok(scene)) => {
                report.loaded += 1;
                let valid = scene.triangle_count() > 0
                    && scene.positions.iter().all(|p| p.is_finite())
                    && scene
                        .triangles
                        .iter()
                        .flatten()
                        .all(|&i| (i as usize) < scene.positions.len())
                    && scene
                        .material_ids
                        .iter()
                        .all(|&m| (m as usize) < scene.materials.len())
                    && scene
                        .materials
                        .iter()
                        .all(|m| m.kd.is_finite() && m.ke.is_finite() && m.ns.is_finite());
                report.invalid_scenes += !valid as usize;
            }
        }
        let mtl_only = mutate(BASE_MTL, &mut rng);
        if std::panic::catch_unwind(|| crate::scene::obj::parse_mtl(&mtl_only, Path::new("m.mtl")))
            .is_err()
        {
            report.panics += 1;
        }
    }
    std::panic::set_hook(hook);
    std::fs::remove_dir_all(&dir).ok();
    Ok(report)
}
