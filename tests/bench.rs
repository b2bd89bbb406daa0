//! `raylab bench --quick` as CI runs it: the whole matrix and every part, with
//! the files checked for content (rows, columns, parsable JSON, decodable
//! charts), and the HTML report opened in headless Chromium when it is installed
//! (CI installs it and sets RAYLAB_REQUIRE_CHROMIUM=1 so that it cannot be skipped).

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

use common::{assert_one_line_error, assert_success, raylab, temp_dir};

/// Runs the quick bench once for all tests of this file; returns its folder and stdout.
fn quick_report() -> &'static (PathBuf, String) {
    static REPORT: OnceLock<(PathBuf, String)> = OnceLock::new();
    REPORT.get_or_init(|| {
        let dir = temp_dir("quick").join("report");
        let out = raylab(&["bench", "--quick", "-q", "--out", dir.to_str().unwrap()]);
        let stdout = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(
            out.status.success(),
            "bench --quick failed: {}\n{stdout}",
            String::from_utf8_lossy(&out.stderr)
        );
        (dir, stdout)
    })
}

fn embree() -> bool {
    raylab::accel::embree::AVAILABLE
}

/// Variants that `--variants all` runs in this build.
fn variants() -> usize {
    raylab::bench::variants::VARIANTS
        .iter()
        .filter(|v| embree() || v.kind != raylab::accel::BackendKind::Embree)
        .count()
}

#[test]
fn quick_bench_writes_tables_with_every_cell() {
    let (dir, stdout) = quick_report();
    assert!(
        stdout.contains("### AO off: speedup over naive-serial"),
        "{stdout}"
    );
    assert!(stdout.contains("### AO paper: speedup over naive-serial"));
    assert!(stdout.contains("#### bvh-median-pbuild-tiles, AO paper"));
    assert!(stdout.contains("### Mrays/s per thread by ray kind"));

    let csv = std::fs::read_to_string(dir.join("bench.csv")).unwrap();
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<String>> = lines
        .map(|l| {
            // The view is the one quoted field ("(0,1,3)").
            let (a, rest) = l.split_once('"').unwrap();
            let (view, b) = rest.split_once('"').unwrap();
            let mut f: Vec<String> = a
                .trim_end_matches(',')
                .split(',')
                .map(String::from)
                .collect();
            f.push(view.to_string());
            f.extend(b.trim_start_matches(',').split(',').map(String::from));
            f
        })
        .collect();
    // 4 scenes x 2 views x 2 AO modes x every variant.
    assert_eq!(rows.len(), 4 * 2 * 2 * variants());
    for r in &rows {
        assert_eq!(r.len(), header.len(), "{r:?}");
        let total: f64 = r[col("total_ms_median")].parse().unwrap();
        let build: f64 = r[col("build_ms_median")].parse().unwrap();
        let render: f64 = r[col("render_ms_median")].parse().unwrap();
        assert!(
            total > 0.0 && (total - build - render).abs() < 1e-3 * total + 1e-3,
            "{r:?}"
        );
        let speedup: f64 = r[col("speedup")].parse().unwrap();
        if r[col("variant")] == "naive-serial" {
            assert!((speedup - 1.0).abs() < 1e-9);
        }
        assert!(speedup > 0.0);
        assert_eq!(r[col("deterministic")], "true");
        let primary: f64 = r[col("primary_mrays_per_thread_s")].parse().unwrap();
        assert!(primary > 0.0, "{r:?}");
    }
    // Same hits, same image: naive and both BVHs give identical pictures.
    for scene in ["cornell-original", "cornell-water"] {
        let hashes: Vec<&String> = rows
            .iter()
            .filter(|r| {
                r[col("scene")] == scene
                    && r[col("ao")] == "paper"
                    && r[col("view")] == "(0,1,3)"
                    && !r[col("backend")].starts_with("embree")
                    // The other libraries have their own arithmetic too.
                    && !["tinybvh", "obvhs", "bvh-crate"]
                        .iter()
                        .any(|l| r[col("backend")].starts_with(l))
            })
            .map(|r| &r[col("image_hash")])
            .collect();
        assert!(hashes.len() >= 12);
        assert!(
            hashes.iter().all(|h| *h == hashes[0]),
            "{scene}: {hashes:?}"
        );
    }

    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["measurements"].as_array().unwrap().len(), rows.len());
    assert!(json["machine"]["cpu"]
        .as_str()
        .is_some_and(|s| !s.is_empty()));
    assert!(json["machine"]["embree_version"].is_string());
    assert_eq!(json["baseline"], "naive-serial");
    let md = std::fs::read_to_string(dir.join("bench.md")).unwrap();
    assert!(md.contains("| naive-serial | (0,1,3) | 1.00x |"), "{md}");
    // The trace part's build table, with the own builds over Embree's.
    assert!(md.contains("| build ms, 1 thr |"), "{md}");
    if embree() {
        assert!(md.contains("| /Embree, 1 thr |"), "{md}");
        assert!(md.contains("| cornell-water | bvh8-sah |"), "{md}");
    }
}

#[test]
fn quick_bench_runs_every_experiment() {
    let (dir, _) = quick_report();
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("bench.json")).unwrap()).unwrap();
    let len = |k: &str| json[k].as_array().map_or(0, Vec::len);
    // Thread scaling: each parallel variant on 1..N threads and 2N.
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let scaling_variants = if embree() { 5 } else { 3 };
    assert_eq!(len("scaling"), scaling_variants * (threads + 1));
    for p in json["scaling"].as_array().unwrap() {
        if p["threads"] == 1 {
            assert!((p["speedup"].as_f64().unwrap() - 1.0).abs() < 1e-9);
        }
    }
    // Cost growth: 2 mesh sizes x (naive, median, sah, sah 4-wide, sah 8-wide, embree).
    assert_eq!(len("growth"), 2 * if embree() { 6 } else { 5 });
    // AO error: paper and cosine:1,4,16 on two scenes; more samples, less error.
    let ao = json["ao_error"].as_array().unwrap();
    assert_eq!(ao.len(), 2 * 4);
    for scene in ["cornell-sphere", "cornell-water"] {
        let rmse = |mode: &str| {
            ao.iter()
                .find(|p| p["scene"] == scene && p["ao"] == mode)
                .and_then(|p| p["rmse"].as_f64())
                .unwrap()
        };
        assert!(rmse("cosine:1") > rmse("cosine:4"));
        assert!(rmse("cosine:4") > rmse("cosine:16"));
        assert!(rmse("paper") > 0.0);
    }
    // Trace: 4 scenes x 4 ray kinds x thread counts (1 and N) x the distinct
    // non-naive structures (median, sah, sah 4-wide, and 8-wide: sah, the
    // ladder's lbvh and sbvh-opt; Embree MEDIUM, LOW and HIGH) on every query
    // path each has (8-wide: single, packets of 8 and 16; Embree: single, packets of
    // 4, 8 and 16, and the stream API where it exists), and the six
    // structures of the other libraries (single rays only).
    let trace_threads = if threads > 1 { 2 } else { 1 };
    let embree_paths = if embree() {
        3 * raylab::accel::BackendSpec::embree(1).queries().len()
    } else {
        0
    };
    let backends = 3 + 3 * 3 + embree_paths + 6;
    assert_eq!(len("trace"), 4 * 4 * trace_threads * backends);
    for p in json["trace"].as_array().unwrap() {
        assert!(p["mrays"]["median"].as_f64().unwrap() > 0.0, "{p}");
        // Builds are timed on each thread count of the trace.
        assert!(p["build_ms"].as_f64().is_some_and(|ms| ms > 0.0), "{p}");
        // raylab's own answers are the reference's bit for bit.
        if p["family"] == "raylab" {
            assert_eq!(p["differing"], 0, "{p}");
        }
    }
    // Every builder, Embree's three when built in, on the last two scenes.
    assert_eq!(len("builders"), 2 * if embree() { 7 } else { 4 });
    // The ladder: 3 rungs of raylab's tree and of Embree's scene, every scene.
    let structures = if embree() { 2 } else { 1 };
    assert_eq!(len("ladder"), 4 * 3 * structures);
    // Every CPU BVH side by side: raylab's two tests and its high rung,
    // Embree plain, robust and at its high quality, six layouts of the
    // other libraries, on every scene; raylab's watertight path is never
    // wrong against the exact reference.
    let libraries = if embree() { 12 } else { 9 };
    assert_eq!(len("libraries"), 4 * libraries);
    // Rows are named by structure (the path per kind is in `paths`).
    let watertight = "bvh8-sah-watertight";
    let mut watertight_rows = 0;
    for p in json["libraries"].as_array().unwrap() {
        assert!(p["failed"].is_null(), "{p}");
        assert!(p["rays"].as_u64().unwrap() > 0, "{p}");
        if p["backend"] == watertight {
            assert_eq!(p["wrong"], 0, "{p}");
            watertight_rows += 1;
        }
    }
    assert_eq!(watertight_rows, 4, "one {watertight} row per scene");
    let high = json["libraries"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|p| p["backend"] == "embree-high")
        .count();
    assert_eq!(
        high,
        if embree() { 4 } else { 0 },
        "Embree's high quality too"
    );
    for p in json["ladder"].as_array().unwrap() {
        assert!(p["render_ms"]["median"].as_f64().unwrap() > 0.0, "{p}");
        assert!(p["build_ms_1t"]["median"].as_f64().unwrap() > 0.0, "{p}");
        // Every rung traced every kind of the recorded rays on each thread
        // count; its render's rays take some time.
        for rates in ["trace_mrays_1t", "trace_mrays_nt"] {
            let rates = p[rates].as_array().unwrap();
            assert_eq!(rates.len(), 4, "{p}");
            assert!(rates.iter().all(|r| r.as_f64().unwrap() > 0.0), "{p}");
        }
        assert!(p["trace_ms_nt"].as_f64().unwrap() > 0.0, "{p}");
        assert!(p["build_pairs"].as_u64().unwrap() >= 1, "{p}");
        if p["structure"] == "raylab" && embree() {
            // Paired with Embree's same rung: a ratio per thread count.
            for ratio in ["build_over_embree_1t", "build_over_embree_nt"] {
                assert!(p[ratio].as_f64().unwrap() > 0.0, "{p}");
            }
        } else {
            assert!(p["build_over_embree_1t"].is_null(), "{p}");
        }
        if p["structure"] == "raylab" {
            assert_eq!(p["differing"], 0, "{p}");
            assert!(p["sah_ns_per_ray"].as_f64().unwrap() > 0.0, "{p}");
            let refs = p["references_per_triangle"].as_f64().unwrap();
            let split = p["rung"] == "high";
            assert!(refs == 1.0 || (split && refs > 1.0 && refs <= 2.0), "{p}");
        }
    }
    assert!(len("leaks") >= 4 * 6);
    assert_eq!(len("validation"), 4 * 2);
    for v in json["validation"].as_array().unwrap() {
        assert_eq!(v["genuine"], 0, "{v}");
    }
}

#[test]
fn quick_bench_draws_charts_and_images() {
    let (dir, _) = quick_report();
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let trace_n = format!("trace-{threads}t");
    let mut charts = vec![
        "speedup-ao-off",
        "speedup-ao-paper",
        "trace-1t",
        "thread-scaling",
        "cost-growth",
        "ao-error",
        "builders",
        "ladder",
        "leaks",
    ];
    if threads > 1 {
        charts.push(&trace_n);
    }
    charts.sort();
    for c in charts {
        let png = image::open(dir.join("charts").join(format!("{c}.png")))
            .unwrap_or_else(|e| panic!("{c}.png: {e}"))
            .to_rgb8();
        assert!(png.width() >= 800 && png.height() >= 500, "{c}");
        // A drawn chart: mostly white, with some coloured (not grey) pixels.
        let coloured = png
            .pixels()
            .filter(|p| {
                let [r, g, b] = p.0;
                r.max(g).max(b) - r.min(g).min(b) > 60
            })
            .count();
        assert!(coloured > 200, "{c}: {coloured} coloured pixels");
        let svg = std::fs::read_to_string(dir.join("charts").join(format!("{c}.svg"))).unwrap();
        assert!(svg.contains("<svg") && svg.contains("</svg>"), "{c}.svg");
    }
    for scene in ["cornell-empty", "cornell-water"] {
        for img in ["naive-serial", "bvh-sah-serial", "difference"] {
            let p = dir.join("images").join(format!("{scene}-{img}.png"));
            let i = image::open(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()));
            assert_eq!((i.width(), i.height()), (96, 72));
        }
    }
    let html = std::fs::read_to_string(dir.join("index.html")).unwrap();
    for needle in [
        "charts/speedup-ao-paper.png",
        "charts/ao-error.svg",
        "images/cornell-water-difference.png",
        "<h2 id=\"tables\">",
        "data-images-ok",
    ] {
        assert!(html.contains(needle), "index.html lacks {needle}");
    }
    // Every chart the run drew is on the page (the trace charts were left out).
    for entry in std::fs::read_dir(dir.join("charts")).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().to_string();
        if name.ends_with(".png") {
            assert!(
                html.contains(&format!("charts/{name}")),
                "index.html lacks charts/{name}"
            );
        }
    }
    // Every image the page references exists, by relative path, and is
    // shown once (the two trace charts were once on the page 528 times each).
    let srcs = raylab::bench::html::image_sources(&html);
    for src in &srcs {
        assert!(dir.join(src).is_file(), "missing {src}");
    }
    assert_eq!(
        raylab::bench::html::first_duplicate(srcs.iter().copied()),
        None,
        "an image is shown more than once"
    );
    // The report leads with its answer; summary.md is dated, with the
    // machine and the command.
    let md = std::fs::read_to_string(dir.join("bench.md")).unwrap();
    let summary_at = md.find("### Summary").expect("bench.md has a summary");
    assert!(summary_at < md.find("### AO off").unwrap(), "summary first");
    assert!(md.contains("### What was wrong"), "{md}");
    assert!(html.find("id=\"summary\"").unwrap() < html.find("id=\"speedups\"").unwrap());
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(
        summary.starts_with("## Where things stand\n\n20"),
        "{summary}"
    );
    assert!(
        summary.contains("Command: `raylab bench --quick -q --out "),
        "{summary}"
    );
    assert!(summary.contains("| cornell-water | primary |"), "{summary}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["format"].as_u64(), Some(2));
    assert!(json["command"]
        .as_str()
        .unwrap()
        .starts_with("raylab bench --quick"));
    assert_eq!(json["date"].as_str().unwrap().len(), 10);
    assert_eq!(json["summary"]["rows"].as_array().unwrap().len(), 4 * 4);
    let listed: Vec<&str> = json["charts"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c.as_str().unwrap())
        .collect();
    assert_eq!(
        raylab::bench::html::first_duplicate(listed.iter().copied()),
        None,
        "bench.json lists a chart twice: {listed:?}"
    );
    // Every chart drawn is listed, and each has its PNG and SVG.
    let drawn = std::fs::read_dir(dir.join("charts"))
        .unwrap()
        .filter(|e| {
            e.as_ref()
                .unwrap()
                .file_name()
                .to_string_lossy()
                .ends_with(".png")
        })
        .count();
    assert_eq!(listed.len(), drawn, "{listed:?}");
    // A page of a few charts and renders, not a thousand.
    assert!(srcs.len() < 60, "{} images on the page", srcs.len());
}

fn chromium() -> Option<PathBuf> {
    [
        "/usr/bin/chromium",
        "/usr/bin/chromium-browser",
        "/usr/bin/google-chrome",
    ]
    .iter()
    .map(PathBuf::from)
    .find(|p| p.is_file())
}

fn run_chromium(exe: &Path, profile: &Path, extra: &[&str], page: &Path) -> Output {
    Command::new(exe)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--virtual-time-budget=10000",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .args(extra)
        .arg(format!("file://{}", page.display()))
        .output()
        .expect("run chromium")
}

#[test]
fn report_opens_in_headless_chromium() {
    let Some(exe) = chromium() else {
        assert!(
            std::env::var_os("RAYLAB_REQUIRE_CHROMIUM").is_none(),
            "RAYLAB_REQUIRE_CHROMIUM is set but no Chromium is installed"
        );
        eprintln!("skipped: no Chromium (apt install chromium)");
        return;
    };
    let (dir, _) = quick_report();
    let page = dir.join("index.html").canonicalize().unwrap();
    let work = temp_dir("chromium");
    // The page's own check: every <img> decoded with a non-zero size.
    let dom = run_chromium(&exe, &work.join("p1"), &["--dump-dom"], &page);
    let dom = String::from_utf8_lossy(&dom.stdout);
    assert!(
        dom.contains("data-images-ok=\"true\""),
        "images did not all load: {}",
        dom.split("id=\"check\"")
            .nth(1)
            .unwrap_or("no check element")
            .chars()
            .take(300)
            .collect::<String>()
    );
    // It counts them: as many as the page has, each once.
    let html = std::fs::read_to_string(&page).unwrap();
    let n = raylab::bench::html::image_sources(&html).len();
    assert!(
        dom.contains(&format!("{n} images loaded, each once")),
        "the page's check did not count {n} images"
    );
    let shot = work.join("shot.png");
    let out = run_chromium(
        &exe,
        &work.join("p2"),
        &[
            "--window-size=1300,2400",
            &format!("--screenshot={}", shot.display()),
        ],
        &page,
    );
    assert!(
        shot.is_file(),
        "no screenshot: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let img = image::open(&shot).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (1300, 2400));
    // Charts were drawn into the page: many coloured pixels, not a blank or error page.
    let coloured = img
        .pixels()
        .filter(|p| {
            let [r, g, b] = p.0;
            r.max(g).max(b) - r.min(g).min(b) > 60
        })
        .count();
    assert!(
        coloured > 5000,
        "screenshot looks empty: {coloured} coloured pixels"
    );
    std::fs::remove_dir_all(&work).ok();
}

/// The page's check fails when an image is on the page twice, though each
/// loads.
#[test]
fn the_page_check_fails_on_duplicate_images() {
    use raylab::bench::html::{figure, page, Section};
    let Some(exe) = chromium() else {
        assert!(
            std::env::var_os("RAYLAB_REQUIRE_CHROMIUM").is_none(),
            "RAYLAB_REQUIRE_CHROMIUM is set but no Chromium is installed"
        );
        eprintln!("skipped: no Chromium (apt install chromium)");
        return;
    };
    let work = temp_dir("duplicates");
    image::RgbImage::from_pixel(8, 8, image::Rgb([200, 30, 30]))
        .save(work.join("a.png"))
        .unwrap();
    let check = |body: String, name: &str| {
        let file = work.join(name);
        let html = page(
            "T",
            &[],
            &[Section {
                id: "s".into(),
                title: "S".into(),
                body,
            }],
        );
        std::fs::write(&file, html).unwrap();
        let dom = run_chromium(
            &exe,
            &work.join(format!("p-{name}")),
            &["--dump-dom"],
            &file,
        );
        String::from_utf8_lossy(&dom.stdout).to_string()
    };
    let once = check(figure("a.png", None, "a"), "once.html");
    assert!(once.contains("data-images-ok=\"true\""), "{once}");
    let twice = check(
        format!(
            "{}{}",
            figure("a.png", None, "a"),
            figure("a.png", None, "a")
        ),
        "twice.html",
    );
    assert!(twice.contains("data-images-ok=\"false\""), "{twice}");
    assert!(
        twice.contains("images shown more than once: a.png"),
        "{twice}"
    );
    std::fs::remove_dir_all(&work).ok();
}

#[test]
fn bad_bench_flags_fail_with_one_line() {
    let d = temp_dir("flags");
    let out = d.join("r");
    let out = out.to_str().unwrap();
    let cases: [(&[&str], &str); 7] = [
        (
            &["bench", "--variants", "naive-serial,warp-drive"],
            "--variants",
        ),
        (&["bench", "--views", "1,2"], "--views"),
        (&["bench", "--views", "0,1,0"], "--views"),
        (&["bench", "--parts", "tables,magic"], "--parts"),
        (&["bench", "--max-variant-s", "0"], "--max-variant-s"),
        (&["bench", "--size", "0x5"], "--size"),
        (&["bench", "no-such-scene"], "no-such-scene"),
    ];
    for (args, needle) in cases {
        let mut args = args.to_vec();
        args.extend(["--quick", "-q", "--out", out]);
        assert_one_line_error(&args, needle);
    }
    // An output folder that cannot be made: a file stands where it should be.
    let file = d.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let o = raylab(&[
        "bench",
        "--quick",
        "-q",
        "--parts",
        "leaks",
        "--out",
        file.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.trim_end().lines().count() == 1 && err.contains("a-file"),
        "{err}"
    );
    std::fs::remove_dir_all(&d).ok();
}

#[test]
fn a_chosen_part_and_variants_run_alone() {
    let d = temp_dir("parts");
    let out = d.join("r");
    let o = raylab(&[
        "bench",
        "cornell-empty",
        "--variants",
        "bvh-sah-serial,naive-serial",
        "--views",
        "0,1,3;1,1,3",
        "--ao",
        "off",
        "--parts",
        "tables",
        "--reps",
        "3",
        "--size",
        "32x24",
        "--json",
        "-q",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_success(&o);
    let json: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let ms = json["measurements"].as_array().unwrap();
    assert_eq!(ms.len(), 2 * 2);
    assert_eq!(ms[0]["variant"], "naive-serial");
    assert_eq!(ms[2]["view"], "(1,1,3)");
    for m in ms {
        assert_eq!(m["total_ms"]["n"], 3);
    }
    assert!(json["scaling"].as_array().unwrap().is_empty());
    assert!(out.join("charts/speedup-ao-off.png").is_file());
    assert!(!out.join("charts/leaks.png").exists());
    std::fs::remove_dir_all(&d).ok();
}
