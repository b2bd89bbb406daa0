//! Hostile OBJ/MTL text: thousands of random mutations of a valid file (deleted,
//! inserted and replaced bytes, huge, negative, NaN and overflowing numbers,
//! truncation). The loader must return an error or a valid scene, never panic.

mod common;

use std::path::Path;

use common::TestRng;
use raylab::scene::obj::{load_obj_str, parse_mtl};

const BASE_OBJ: &str = "mtllib box.mtl\n\
v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nvn 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\n\
usemtl white\nf 1/1/1 2/2/1 3/3/1 4/1/1\n\
v 0 1 0\nv 1 1 0\nv 0 1 1\nusemtl light\nf -3 -2 -1\ng rest\ns 1\nf 1 2 5\n";

const BASE_MTL: &str = "newmtl white\nKa 0.1 0.1 0.1\nKd 0.7 0.7 0.7\nNs 10\n\
newmtl light\nKd 0.8 0.8 0.8\nKe 10 10 10\nKs 0.5 0.5 0.5\n";

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

fn mutate(base: &str, rng: &mut TestRng) -> String {
    let mut text: Vec<char> = base.chars().collect();
    let edits = 1 + (rng.next_f32() * 4.0) as usize;
    for _ in 0..edits {
        let at = (rng.next_f32() * text.len().max(1) as f32) as usize % text.len().max(1);
        match (rng.next_f32() * 6.0) as u32 {
            0 => {
                text.remove(at.min(text.len().saturating_sub(1)));
            }
            1 => text.insert(
                at,
                char::from_u32((rng.next_f32() * 0x3000 as f32) as u32).unwrap_or('?'),
            ),
            2 => {
                let nasty = NASTY[(rng.next_f32() * NASTY.len() as f32) as usize % NASTY.len()];
                for (k, c) in nasty.chars().enumerate() {
                    text.insert(at + k, c);
                }
            }
            3 => text.truncate(at),
            4 => {
                // Replace a token with a nasty one.
                let s: String = text.iter().collect();
                let mut words: Vec<String> = s.split(' ').map(str::to_string).collect();
                let w = (rng.next_f32() * words.len() as f32) as usize % words.len();
                words[w] =
                    NASTY[(rng.next_f32() * NASTY.len() as f32) as usize % NASTY.len()].to_string();
                text = words.join(" ").chars().collect();
            }
            _ => {
                // Duplicate a line.
                let s: String = text.iter().collect();
                let lines: Vec<&str> = s.lines().collect();
                let l = lines[(rng.next_f32() * lines.len() as f32) as usize % lines.len().max(1)];
                text.extend(format!("\n{l}\n").chars());
            }
        }
        if text.is_empty() {
            break;
        }
    }
    text.into_iter().collect()
}

#[test]
fn mutated_obj_and_mtl_never_panic_and_never_load_invalid_scenes() {
    let dir = std::env::temp_dir().join(format!("raylab-hostile-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut rng = TestRng(2024);
    let (mut ok, mut err) = (0, 0);
    for case in 0..3000 {
        let obj = mutate(BASE_OBJ, &mut rng);
        let mtl = if case % 3 == 0 {
            mutate(BASE_MTL, &mut rng)
        } else {
            BASE_MTL.to_string()
        };
        std::fs::write(dir.join("box.mtl"), &mtl).unwrap();
        let result =
            std::panic::catch_unwind(|| load_obj_str(&obj, Path::new("hostile.obj"), &dir));
        let Ok(result) = result else {
            panic!("case {case} panicked on OBJ:\n{obj}\n--- MTL:\n{mtl}");
        };
        match result {
            Ok(scene) => {
                ok += 1;
                assert!(scene.triangle_count() > 0, "case {case}");
                assert!(scene.positions.iter().all(|p| p.is_finite()), "case {case}");
                assert!(
                    scene
                        .triangles
                        .iter()
                        .flatten()
                        .all(|&i| (i as usize) < scene.positions.len()),
                    "case {case}"
                );
                assert!(
                    scene
                        .material_ids
                        .iter()
                        .all(|&m| (m as usize) < scene.materials.len()),
                    "case {case}"
                );
                for m in &scene.materials {
                    assert!(
                        m.kd.is_finite() && m.ke.is_finite() && m.ns.is_finite(),
                        "case {case}: {m:?}"
                    );
                }
            }
            Err(e) => {
                err += 1;
                let msg = e.to_string();
                assert_eq!(
                    msg.lines().count(),
                    1,
                    "case {case}: multi-line error {msg:?}"
                );
            }
        }
        let mtl_only = std::panic::catch_unwind(|| {
            parse_mtl(&mutate(BASE_MTL, &mut TestRng(case)), Path::new("m.mtl"))
        });
        assert!(mtl_only.is_ok(), "case {case}: parse_mtl panicked");
    }
    std::fs::remove_dir_all(&dir).ok();
    // Both outcomes must occur, or the mutations test nothing.
    assert!(ok > 100 && err > 100, "ok {ok}, err {err}");
}
