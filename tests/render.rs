//! The shared render loop on the built-in scenes: what a user sees, and that
//! every schedule and thread count gives the same bits.

mod common;

use common::{project, settings};
use glam::Vec3;
use raylab::accel::naive::Naive;
use raylab::progress::Progress;
use raylab::render::{render, AoMode, Frame, Schedule};
use raylab::scene::builtin::{builtin, BUILTIN_SCENES};

fn render_scene(
    name: &str,
    w: u32,
    h: u32,
    ao: AoMode,
    schedule: Schedule,
    threads: usize,
) -> Frame {
    let scene = builtin(name).unwrap();
    let backend = Naive::new(&scene);
    render(
        &scene,
        &backend,
        &settings(w, h, ao),
        schedule,
        threads,
        &Progress::new(),
    )
    .unwrap()
    .0
}

fn at(f: &Frame, x: u32, y: u32) -> Vec3 {
    f.pixels[(y * f.width + x) as usize]
}

fn luminance(c: Vec3) -> f32 {
    c.dot(Vec3::new(0.2126, 0.7152, 0.0722))
}

#[test]
fn every_builtin_scene_renders_lit_with_red_and_green_walls_and_shadows() {
    let (w, h) = (64, 48);
    for (name, _) in BUILTIN_SCENES {
        let f = render_scene(name, w, h, AoMode::Paper, Schedule::Serial, 1);
        let lit = f.pixels.iter().filter(|p| luminance(**p) > 0.05).count();
        assert!(lit > f.pixels.len() / 3, "{name}: only {lit} lit pixels");
        assert!(
            f.pixels.iter().all(|p| p.is_finite()),
            "{name}: non-finite pixel"
        );

        let (lx, ly) = project(Vec3::new(-1.0, 1.2, -0.3), w, h);
        let red = at(&f, lx + 1, ly);
        assert!(
            red.x > 2.0 * red.y && red.x > 2.0 * red.z,
            "{name}: left wall {red}"
        );
        let (rx, ry) = project(Vec3::new(1.0, 1.2, -0.3), w, h);
        let green = at(&f, rx - 1, ry);
        assert!(
            green.y > 1.5 * green.x && green.y > 1.5 * green.z,
            "{name}: right wall {green}"
        );

        // Floor (or water) across the image: lit, and not uniformly so.
        let (_, fy) = project(Vec3::new(0.0, 0.0, 0.2), w, h);
        let floor: Vec<f32> = (14..w - 14).map(|x| luminance(at(&f, x, fy))).collect();
        let (lo, hi) = floor
            .iter()
            .fold((f32::MAX, 0f32), |(a, b), &l| (a.min(l), b.max(l)));
        assert!(hi > 0.02 && lo < 0.7 * hi, "{name}: floor range {lo}..{hi}");
    }
}

#[test]
fn blocks_cast_shadows_on_the_floor() {
    let (w, h) = (64, 48);
    let with = render_scene("cornell-original", w, h, AoMode::Off, Schedule::Serial, 1);
    let without = render_scene("cornell-empty", w, h, AoMode::Off, Schedule::Serial, 1);
    // A floor point just behind the tall block, hidden from the light by it.
    let (x, y) = project(Vec3::new(-0.75, 0.0, -0.8), w, h);
    assert!(luminance(at(&with, x, y)) < 0.8 * luminance(at(&without, x, y)));
}

#[test]
fn all_schedules_and_thread_counts_give_identical_images() {
    let reference = render_scene(
        "cornell-sphere",
        64,
        48,
        AoMode::Cosine(4),
        Schedule::Serial,
        1,
    );
    for schedule in Schedule::ALL {
        for threads in [1, 2, 4] {
            let f = render_scene(
                "cornell-sphere",
                64,
                48,
                AoMode::Cosine(4),
                schedule,
                threads,
            );
            assert!(
                f == reference,
                "{schedule:?} with {threads} threads differs"
            );
        }
    }
}

#[test]
fn paper_ao_darkens_corners_and_nothing_else_brightens() {
    let (w, h) = (64, 48);
    let off = render_scene("cornell-empty", w, h, AoMode::Off, Schedule::Serial, 1);
    let paper = render_scene("cornell-empty", w, h, AoMode::Paper, Schedule::Serial, 1);
    for (a, b) in off.pixels.iter().zip(&paper.pixels) {
        assert!(
            b.cmple(*a + Vec3::splat(1e-6)).all(),
            "AO brightened a pixel: {a} -> {b}"
        );
    }
    // The back-left-bottom corner loses ambient light; the back wall's middle does not.
    let (cx, cy) = project(Vec3::new(-0.97, 0.03, -1.0), w, h);
    assert!(luminance(at(&paper, cx, cy)) < luminance(at(&off, cx, cy)) - 1e-3);
    let (mx, my) = project(Vec3::new(0.0, 1.0, -1.0), w, h);
    assert_eq!(at(&paper, mx, my), at(&off, mx, my));
}

#[test]
fn ray_counts_follow_the_ao_mode() {
    let scene = builtin("cornell-empty").unwrap();
    let backend = Naive::new(&scene);
    let count = |ao| {
        render(
            &scene,
            &backend,
            &settings(32, 24, ao),
            Schedule::Serial,
            1,
            &Progress::new(),
        )
        .unwrap()
        .1
    };
    let off = count(AoMode::Off);
    assert_eq!(off.primary_rays, 32 * 24);
    assert_eq!(off.ao_rays, 0);
    let cos = count(AoMode::Cosine(3));
    // Every visible point of the closed-back box casts 3 AO rays; misses cast none.
    assert_eq!(cos.ao_rays % 3, 0);
    assert!(cos.ao_rays > 0);
    let paper = count(AoMode::Paper);
    // Walls are axis-aligned: 5 of the 14 directions lie above each.
    assert_eq!(paper.ao_rays / 5, cos.ao_rays / 3);
}

#[test]
fn scene_without_lights_still_renders() {
    let scene = raylab::scene::obj::load_obj_str(
        "v -1 0 -1\nv 1 0 -1\nv 1 2 -1\nv -1 2 -1\nf 1 2 3 4\n",
        std::path::Path::new("wall.obj"),
        std::path::Path::new("."),
    )
    .unwrap();
    let backend = Naive::new(&scene);
    let (f, stats) = render(
        &scene,
        &backend,
        &settings(32, 24, AoMode::Paper),
        Schedule::Serial,
        1,
        &Progress::new(),
    )
    .unwrap();
    assert_eq!(stats.shadow_rays, 0);
    assert!(
        luminance(at(&f, 16, 12)) > 0.1,
        "headlight should light the wall"
    );
}
