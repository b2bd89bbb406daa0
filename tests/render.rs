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
fn scene_without_emitters_gets_the_default_light_with_shadows() {
    // A floor with a small block on it, no emitters.
    let mut scene = raylab::scene::obj::load_obj_str(
        "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 3 2\nf 1 4 3\n\
         v -0.2 0.4 -0.2\nv 0.2 0.4 -0.2\nv 0.2 0.4 0.2\nv -0.2 0.4 0.2\nf 5 7 6\nf 5 8 7\n",
        std::path::Path::new("floor.obj"),
        std::path::Path::new("."),
    )
    .unwrap();
    assert!(scene.lights.is_empty());
    scene.set_extra_light(None, glam::Vec3::Y);
    assert!(scene.lights.extra.is_some());
    assert!(scene
        .warnings
        .iter()
        .any(|w| w.contains("default area light")));
    let backend = Naive::new(&scene);
    let settings = settings_looking_down(48, 48);
    let (f, stats) = render(
        &scene,
        &backend,
        &settings,
        Schedule::Serial,
        1,
        &Progress::new(),
    )
    .unwrap();
    assert!(stats.shadow_rays > 0, "the default light casts shadow rays");
    // The floor is lit; under the block (seen past its edge) lies its shadow.
    let lit = luminance(at(&f, 4, 24));
    assert!(lit > 0.1, "floor should be lit: {lit}");
    let (dark, _) = (0..48u32)
        .flat_map(|y| (0..48u32).map(move |x| (x, y)))
        .map(|(x, y)| (luminance(at(&f, x, y)), (x, y)))
        .fold((f32::MAX, (0, 0)), |a, b| if b.0 < a.0 { b } else { a });
    assert!(
        dark < 0.5 * lit,
        "a shadow darker than the lit floor: {dark} vs {lit}"
    );
}

/// Looking down at the origin from (0.3, 3, 0.9), wide enough to see the floor's
/// edges.
fn settings_looking_down(w: u32, h: u32) -> raylab::render::RenderSettings {
    let mut s = settings(w, h, AoMode::Off);
    s.camera = raylab::camera::Camera::new(
        glam::Vec3::new(0.3, 3.0, 0.9),
        glam::Vec3::ZERO,
        glam::Vec3::Y,
        45.0,
        w,
        h,
    )
    .unwrap();
    s
}

#[test]
fn emitters_shine_from_their_front_face_only_unless_two_sided() {
    // A floor under an emitting quad 0.5 above it whose winding faces up (away
    // from the floor): one-sided, the floor gets no light from it.
    let obj = |facing_down: bool| {
        let light = if facing_down {
            "f 5 6 7\nf 5 7 8\n"
        } else {
            "f 5 7 6\nf 5 8 7\n"
        };
        format!(
            "mtllib none.mtl\nv -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\nf 1 3 2\nf 1 4 3\n\
             v -0.3 0.5 -0.3\nv 0.3 0.5 -0.3\nv 0.3 0.5 0.3\nv -0.3 0.5 0.3\nusemtl light\n{light}"
        )
    };
    let dir = common::temp_dir("one-sided");
    std::fs::write(dir.join("none.mtl"), "newmtl light\nKd 0 0 0\nKe 5 5 5\n").unwrap();
    let floor_light = |facing_down: bool, two_sided: bool, samples: u32| {
        let scene = raylab::scene::obj::load_obj_str(
            &obj(facing_down),
            std::path::Path::new("light.obj"),
            &dir,
        )
        .unwrap();
        assert_eq!(scene.lights.triangles.len(), 2);
        let mut s = settings_looking_down(32, 32);
        s.two_sided_lights = two_sided;
        s.light_samples = samples;
        let (f, _) = render(
            &scene,
            &Naive::new(&scene),
            &s,
            Schedule::Serial,
            1,
            &Progress::new(),
        )
        .unwrap();
        // Floor pixels beside the light, averaged.
        (4..9u32)
            .flat_map(|x| (14..19u32).map(move |y| (x, y)))
            .map(|(x, y)| luminance(at(&f, x, y)))
            .sum::<f32>()
            / 25.0
    };
    let ambient_only = floor_light(true, false, 0);
    let down = floor_light(true, false, 16);
    let up = floor_light(false, false, 16);
    let up_two = floor_light(false, true, 16);
    assert!(
        down > ambient_only + 0.02,
        "the light facing the floor lights it: {down}"
    );
    assert_eq!(
        up, ambient_only,
        "a light facing away adds nothing to the floor"
    );
    // Two-sided, the back face lights the floor as the front face did (other
    // triangles, so other samples: equal within the noise).
    let direct = down - ambient_only;
    assert!(
        (up_two - down).abs() < 0.1 * direct,
        "two-sided: {up_two} vs {down}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// A flat export in centimetres: the field of `plane:N` scaled by 100 (a
/// 100 m ground in the plane y = 0, light included), seen from about 130 m.
fn field_in_centimetres() -> raylab::scene::Scene {
    let field = builtin("plane:20000").unwrap();
    let positions: Vec<Vec3> = field.positions.iter().map(|p| *p * 100.0).collect();
    raylab::scene::Scene::new(
        "field in cm",
        positions,
        None,
        field.triangles.clone(),
        field.material_ids.clone(),
        field.materials.clone(),
    )
    .unwrap()
}

#[test]
fn secondary_rays_leave_a_far_flat_field_without_hitting_it() {
    use raylab::accel::bvh::{BuildParams, BvhBackend};
    use raylab::camera::Camera;
    use raylab::measure::validate::{judge_spawns, recorded_rays};
    let scene = field_in_centimetres();
    let backend = BvhBackend::new(&scene.triangle_vertices(), &BuildParams::sah()).unwrap();
    let mut s = settings(128, 96, AoMode::Cosine(4));
    s.ao_dist = 800.0;
    s.camera = Camera::new(
        Vec3::new(0.0, 6000.0, 9000.0),
        Vec3::ZERO,
        Vec3::Y,
        60.0,
        128,
        96,
    )
    .unwrap();
    let recorded = recorded_rays(&scene, &backend, &s).unwrap();
    let spawns = judge_spawns(&scene, &recorded.spawns);
    assert!(spawns.surfaces > 4000, "{spawns:?}");
    assert_eq!(spawns.behind, 0, "{spawns:?}");
    // Nothing stands on the field: every AO ray and every shadow ray to the
    // light above it is open (rays from o + t d found the field again).
    let blocked = |rays: &[raylab::geometry::Ray]| {
        rays.iter()
            .filter(|r| raylab::accel::Backend::occluded(&backend, r))
            .count()
    };
    assert!(recorded.ao.len() > 16_000 && recorded.shadow.len() > 4000);
    assert_eq!(blocked(&recorded.ao), 0);
    assert_eq!(blocked(&recorded.shadow), 0);
}
