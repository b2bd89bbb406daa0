//! The bench's charts, drawn with `plotters` twice: SVG (for zooming and papers)
//! and PNG (for the report and quick looks). Text needs a TrueType font, read
//! once from the system (DejaVu Sans from `fonts-dejavu-core`, or `RAYLAB_FONT`).

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::extras::{AoErrorPoint, BuilderPoint, GrowthPoint, ScalingPoint};
use super::measure::Measurement;
use super::tables::speedup;
use super::trace::TracePoint;
use crate::error::{Error, Result};
use crate::stress::LeakRow;

type DrawResult = std::result::Result<(), Box<dyn std::error::Error>>;

const FONT: &str = "sans-serif";
const FONT_PATHS: [&str; 4] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

/// Registers a system font for chart text, once; the error names what to install.
pub fn init_font() -> Result<()> {
    static DONE: OnceLock<std::result::Result<(), String>> = OnceLock::new();
    DONE.get_or_init(|| {
        let candidates: Vec<PathBuf> = std::env::var_os("RAYLAB_FONT")
            .map(PathBuf::from)
            .into_iter()
            .chain(FONT_PATHS.iter().map(PathBuf::from))
            .collect();
        for path in &candidates {
            if let Ok(bytes) = std::fs::read(path) {
                // plotters keeps the font for the life of the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font(FONT, FontStyle::Normal, bytes).is_ok() {
                    return Ok(());
                }
            }
        }
        Err(format!(
            "charts need a TrueType font: none of {} could be read (install fonts-dejavu-core, or set RAYLAB_FONT to a .ttf file)",
            FONT_PATHS[0]
        ))
    })
    .clone()
    .map_err(Error::Other)
}

/// The series legend, in the same style on every chart.
fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .label_font((FONT, 13))
        .draw()?;
    Ok(())
}

/// Width of the strip [`side_legend`] draws in.
const SIDE_LEGEND: u32 = 190;

/// How a legend entry's swatch is drawn.
#[derive(Clone, Copy)]
enum Swatch {
    Bar,
    Dot,
}

/// A legend in a strip of its own beside the plot (many series: inside the plot
/// it covered bars and points).
fn side_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, RGBAColor)],
    swatch: Swatch,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let style = TextStyle::from((FONT, 13).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    for (i, (name, c)) in entries.iter().enumerate() {
        let y = 50 + 19 * i as i32;
        match swatch {
            Swatch::Bar => area.draw(&Rectangle::new([(8, y - 5), (20, y + 5)], c.filled()))?,
            Swatch::Dot => area.draw(&Circle::new((14, y), 5, c.filled()))?,
        }
        area.draw(&Text::new(name.clone(), (28, y), style.clone()))?;
    }
    Ok(())
}

/// A labelled line through `points` with a dot on each.
fn line_with_points<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    points: &[(f64, f64)],
    c: RGBAColor,
    label: &str,
) -> DrawResult
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    CT: plotters::coord::CoordTranslate<From = (f64, f64)>,
{
    chart
        .draw_series(LineSeries::new(points.to_vec(), c.stroke_width(2)))?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
    chart.draw_series(points.iter().map(|p| Circle::new(*p, 4, c.filled())))?;
    Ok(())
}

/// Draws `$draw(area, $data)` as `$name.svg` and `$name.png` in `$dir`.
macro_rules! save_chart {
    ($dir:expr, $name:expr, $size:expr, $draw:ident, $data:expr) => {
        save($dir, $name, $size, |a| $draw(a, $data), |a| $draw(a, $data))
    };
}

/// Draws one chart as `dir/name.svg` and `dir/name.png`; returns the PNG's name.
fn save(
    dir: &Path,
    name: &str,
    size: (u32, u32),
    svg: impl FnOnce(DrawingArea<SVGBackend<'_>, Shift>) -> DrawResult,
    png: impl FnOnce(DrawingArea<BitMapBackend<'_>, Shift>) -> DrawResult,
) -> Result<String> {
    init_font()?;
    let fail = |e: Box<dyn std::error::Error>| Error::Other(format!("chart {name}: {e}"));
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, size).into_drawing_area();
        svg(root).map_err(fail)?;
    }
    crate::render::output::write_text(&dir.join(format!("{name}.svg")), &text)?;
    let mut pixels = vec![255u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        png(root).map_err(fail)?;
    }
    let file = format!("{name}.png");
    crate::render::output::write_png(&dir.join(&file), size.0, size.1, &pixels)?;
    Ok(file)
}

fn color(i: usize) -> RGBAColor {
    Palette99::pick(i).to_rgba()
}

/// A range covering `values` on a log axis, with some room either side.
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| *v > 0.0 && v.is_finite())
        .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return 0.1..10.0;
    }
    let hi = if hi <= lo { lo * 10.0 } else { hi };
    lo / 1.5..hi * 1.5
}

/// Labels of a log axis: only 1, 2 and 5 times a power of ten, so they never crowd.
fn log_label(v: &f64) -> String {
    if !(*v > 0.0) {
        return String::new();
    }
    let exp = v.log10().floor();
    let mantissa = v / 10f64.powf(exp);
    let nice = [1.0, 2.0, 5.0, 10.0]
        .iter()
        .any(|m| (mantissa - m).abs() < 1e-6 * m);
    if !nice {
        return String::new();
    }
    if (1e-2..1e5).contains(v) {
        let s = format!("{v:.2}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

fn lin_range(values: impl Iterator<Item = f64>, include_zero: bool) -> std::ops::Range<f64> {
    let (mut lo, mut hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return 0.0..1.0;
    }
    if include_zero {
        lo = lo.min(0.0);
    }
    if hi - lo < 1e-12 {
        hi = lo + 1.0;
    }
    let pad = (hi - lo) * 0.08;
    (if include_zero && lo >= 0.0 {
        lo
    } else {
        lo - pad
    })..hi + pad
}

/// Speedup over the baseline per scene and view, one bar per variant (log scale).
pub struct SpeedupData<'a> {
    pub ms: &'a [Measurement],
    pub ao: String,
}

pub fn speedup_chart(dir: &Path, data: &SpeedupData) -> Result<String> {
    let name = format!("speedup-ao-{}", data.ao.replace(':', "-"));
    save_chart!(dir, &name, (1390, 560), draw_speedup, data)
}

fn draw_speedup<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, d: &SpeedupData) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let here: Vec<&Measurement> = d.ms.iter().filter(|m| m.ao == d.ao).collect();
    let mut groups: Vec<(String, String, usize)> = Vec::new();
    let mut variants: Vec<String> = Vec::new();
    for m in &here {
        if !groups.iter().any(|(s, v, _)| *s == m.scene && *v == m.view) {
            groups.push((m.scene.clone(), m.view.clone(), m.triangles));
        }
        if !variants.contains(&m.variant) {
            variants.push(m.variant.clone());
        }
    }
    let series = variants
        .into_iter()
        .map(|variant| {
            let values = groups
                .iter()
                .map(|(scene, view, _)| {
                    let m = here
                        .iter()
                        .find(|m| m.variant == variant && m.scene == *scene && m.view == *view)?;
                    speedup(d.ms, m)
                })
                .collect();
            (variant, values)
        })
        .collect();
    let values: Vec<f64> = here.iter().filter_map(|m| speedup(d.ms, m)).collect();
    let y = log_range(values.iter().copied().chain([1.0]));
    let speedup_label = |v: &f64| {
        let l = log_label(v);
        if l.is_empty() {
            l
        } else {
            format!("{l}x")
        }
    };
    draw_bars(
        root,
        &Bars {
            caption: format!(
                "Speedup over {} (total time, median), AO {}",
                super::tables::baseline_name(d.ms),
                d.ao
            ),
            y_desc: "speedup (log)",
            groups: groups
                .iter()
                .map(|(scene, view, tris)| (short(scene), format!("{tris} tris {view}")))
                .collect(),
            series,
            y: (y.start.min(0.5))..y.end,
            y_label: &speedup_label,
        },
    )
}

/// A scene name short enough to sit under a bar: without the `cornell-`
/// prefix, and `mesh:N` with a power of ten as `mesh 1eK`.
fn short(scene: &str) -> String {
    if let Some(n) = scene
        .strip_prefix("mesh:")
        .and_then(|n| n.parse::<u64>().ok())
    {
        let k = n.checked_ilog10().unwrap_or(0);
        if 10u64.pow(k) == n {
            return format!("mesh 1e{k}");
        }
    }
    scene.strip_prefix("cornell-").unwrap_or(scene).to_string()
}

/// A grouped bar chart on a log axis: one group per entry of `groups` (two
/// label lines under it), one coloured bar per series in each group where
/// the series has a value.
struct Bars<'a> {
    caption: String,
    y_desc: &'a str,
    groups: Vec<(String, String)>,
    series: Vec<(String, Vec<Option<f64>>)>,
    y: std::ops::Range<f64>,
    y_label: &'a dyn Fn(&f64) -> String,
}

fn draw_bars<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, b: &Bars) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let y = b.y.clone();
    let (width, _) = root.dim_in_pixel();
    let (plot, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND));
    let mut chart = ChartBuilder::on(&plot)
        .caption(&b.caption, (FONT, 22))
        .margin(12)
        .x_label_area_size(50)
        .y_label_area_size(60)
        .build_cartesian_2d(0f64..b.groups.len().max(1) as f64, y.clone().log_scale())?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .x_label_formatter(&|_| String::new())
        .y_desc(b.y_desc)
        .y_label_formatter(b.y_label)
        .draw()?;
    let width = 0.8 / b.series.len().max(1) as f64;
    for (si, (_, values)) in b.series.iter().enumerate() {
        let c = color(si);
        let bars: Vec<Rectangle<(f64, f64)>> = values
            .iter()
            .enumerate()
            .filter_map(|(gi, v)| {
                let x0 = gi as f64 + 0.1 + si as f64 * width;
                Some(Rectangle::new(
                    [(x0, y.start), (x0 + width * 0.9, (*v)?)],
                    c.filled(),
                ))
            })
            .collect();
        chart.draw_series(bars)?;
    }
    let entries: Vec<(String, RGBAColor)> = b
        .series
        .iter()
        .enumerate()
        .map(|(i, (name, _))| (name.clone(), color(i)))
        .collect();
    side_legend(&side, &entries, Swatch::Bar)?;
    for (gi, (first, second)) in b.groups.iter().enumerate() {
        let (px, py) = chart.backend_coord(&(gi as f64 + 0.5, y.start));
        let style = TextStyle::from((FONT, 13).into_font()).pos(Pos::new(HPos::Center, VPos::Top));
        plot.draw(&Text::new(first.clone(), (px, py + 6), style.clone()))?;
        plot.draw(&Text::new(second.clone(), (px, py + 23), style))?;
    }
    root.present()?;
    Ok(())
}

/// Query throughput per scene and ray kind on one thread count, one bar per
/// backend (log scale), so each of raylab's trees stands beside Embree.
pub struct TraceData<'a> {
    pub points: &'a [TracePoint],
    pub threads: usize,
}

pub fn trace_chart(dir: &Path, data: &TraceData) -> Result<String> {
    let name = format!("trace-{}t", data.threads);
    save_chart!(dir, &name, (1390, 560), draw_trace, data)
}

fn draw_trace<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, d: &TraceData) -> DrawResult
where
    DB::ErrorType: 'static,
{
    let here: Vec<&TracePoint> = d.points.iter().filter(|p| p.threads == d.threads).collect();
    let mut groups: Vec<(String, String)> = Vec::new();
    let mut backends: Vec<String> = Vec::new();
    for p in &here {
        if !groups.iter().any(|(s, k)| *s == p.scene && *k == p.kind) {
            groups.push((p.scene.clone(), p.kind.clone()));
        }
        if !backends.contains(&p.backend) {
            backends.push(p.backend.clone());
        }
    }
    let series = backends
        .into_iter()
        .map(|backend| {
            let values = groups
                .iter()
                .map(|(scene, kind)| {
                    here.iter()
                        .find(|p| p.backend == backend && p.scene == *scene && p.kind == *kind)
                        .map(|p| p.mrays.median)
                })
                .collect();
            (backend, values)
        })
        .collect();
    draw_bars(
        root,
        &Bars {
            caption: format!(
                "Query throughput without shading, {} thread{} (median Mrays/s)",
                d.threads,
                if d.threads == 1 { "" } else { "s" }
            ),
            y_desc: "Mrays/s (log)",
            groups: groups
                .iter()
                .map(|(scene, kind)| (short(scene), kind.clone()))
                .collect(),
            series,
            y: log_range(here.iter().map(|p| p.mrays.median)),
            y_label: &log_label,
        },
    )
}

pub fn scaling_chart(dir: &Path, points: &[ScalingPoint]) -> Result<String> {
    save_chart!(dir, "thread-scaling", (800, 520), draw_scaling, points)
}

fn draw_scaling<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[ScalingPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let max_t = pts.iter().map(|p| p.threads).max().unwrap_or(1) as f64;
    let max_s = pts.iter().map(|p| p.speedup).fold(max_t, f64::max);
    let scene = pts.first().map_or("", |p| p.scene.as_str());
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("Thread scaling of the render, {scene}"), (FONT, 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(55)
        .build_cartesian_2d(0.5f64..max_t + 0.5, 0f64..max_s * 1.1)?;
    chart
        .configure_mesh()
        .x_desc("render threads")
        .y_desc("speedup over 1 thread")
        .draw()?;
    chart
        .draw_series(LineSeries::new(
            [(1.0, 1.0), (max_t, max_t)],
            BLACK.mix(0.4).stroke_width(1),
        ))?
        .label("ideal")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.4)));
    let mut variants: Vec<&str> = Vec::new();
    for p in pts {
        if !variants.contains(&p.variant.as_str()) {
            variants.push(&p.variant);
        }
    }
    for (i, v) in variants.iter().enumerate() {
        let c = color(i);
        let line: Vec<(f64, f64)> = pts
            .iter()
            .filter(|p| p.variant == *v)
            .map(|p| (p.threads as f64, p.speedup))
            .collect();
        line_with_points(&mut chart, &line, c, v)?;
    }
    legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    root.present()?;
    Ok(())
}

pub fn growth_chart(dir: &Path, points: &[GrowthPoint]) -> Result<String> {
    save_chart!(dir, "cost-growth", (1200, 520), draw_growth, points)
}

fn draw_growth<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, pts: &[GrowthPoint]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(600);
    let mut backends: Vec<&str> = Vec::new();
    for p in pts {
        if !backends.contains(&p.backend.as_str()) {
            backends.push(&p.backend);
        }
    }
    let x = log_range(pts.iter().map(|p| p.triangles as f64));
    for (area, title, ydesc, get) in [
        (
            &left,
            "Build time against triangles",
            "build ms (log)",
            (|p: &GrowthPoint| p.build_ms.max(1e-3)) as fn(&GrowthPoint) -> f64,
        ),
        (
            &right,
            "Render time per ray against triangles",
            "ns per ray on one thread (log)",
            |p: &GrowthPoint| p.ns_per_ray,
        ),
    ] {
        let y = log_range(pts.iter().map(get));
        let mut chart = ChartBuilder::on(area)
            .caption(title, (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(x.clone().log_scale(), y.log_scale())?;
        chart
            .configure_mesh()
            .x_desc("triangles (log)")
            .y_desc(ydesc)
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        for (i, b) in backends.iter().enumerate() {
            let c = color(i);
            let line: Vec<(f64, f64)> = pts
                .iter()
                .filter(|p| p.backend == *b)
                .map(|p| (p.triangles as f64, get(p)))
                .collect();
            line_with_points(&mut chart, &line, c, b)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
    }
    root.present()?;
    Ok(())
}

pub fn ao_error_chart(dir: &Path, points: &[AoErrorPoint]) -> Result<String> {
    save_chart!(dir, "ao-error", (1200, 520), draw_ao_error, points)
}

fn draw_ao_error<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[AoErrorPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let mut scenes: Vec<&str> = Vec::new();
    for p in pts {
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    let areas = root.split_evenly((1, scenes.len().max(1)));
    for (area, scene) in areas.iter().zip(&scenes) {
        let here: Vec<&AoErrorPoint> = pts.iter().filter(|p| p.scene == *scene).collect();
        let x = log_range(here.iter().map(|p| p.render_ms.median));
        let y = log_range(here.iter().map(|p| p.rmse.max(1e-6)));
        let mut chart = ChartBuilder::on(area)
            .caption(format!("AO error against time, {scene}"), (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(65)
            .build_cartesian_2d(x.log_scale(), y.log_scale())?;
        chart
            .configure_mesh()
            .x_desc("render ms (log)")
            .y_desc("RMSE vs cosine reference (log)")
            .x_label_formatter(&log_label)
            .y_label_formatter(&log_label)
            .draw()?;
        let cosine: Vec<(f64, f64, u32)> = here
            .iter()
            .filter(|p| p.ao.starts_with("cosine"))
            .map(|p| (p.render_ms.median, p.rmse.max(1e-6), p.samples))
            .collect();
        let c = color(0);
        chart
            .draw_series(LineSeries::new(
                cosine.iter().map(|(x, y, _)| (*x, *y)),
                c.stroke_width(2),
            ))?
            .label("cosine:N (random, unbiased)")
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2)));
        chart.draw_series(cosine.iter().map(|(x, y, n)| {
            EmptyElement::at((*x, *y))
                + Circle::new((0, 0), 4, c.filled())
                + Text::new(format!("{n}"), (6, -14), (FONT, 12).into_font())
        }))?;
        let red = RGBAColor(200, 30, 30, 1.0);
        chart
            .draw_series(here.iter().filter(|p| p.ao == "paper").map(|p| {
                EmptyElement::at((p.render_ms.median, p.rmse.max(1e-6)))
                    + TriangleMarker::new((0, 0), 8, red.filled())
                    + Text::new(
                        format!("paper, {:.1} dB", p.psnr_db),
                        (8, 4),
                        (FONT, 12).into_font(),
                    )
            }))?
            .label("paper (14 fixed directions)")
            .legend(move |(x, y)| TriangleMarker::new((x + 8, y), 6, red.filled()));
        legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    }
    root.present()?;
    Ok(())
}

pub fn builders_chart(dir: &Path, points: &[BuilderPoint]) -> Result<String> {
    save_chart!(dir, "builders", (1390, 520), draw_builders, points)
}

fn draw_builders<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    pts: &[BuilderPoint],
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let (width, _) = root.dim_in_pixel();
    let (panels, side) = root.split_horizontally(width.saturating_sub(SIDE_LEGEND));
    let (left, right) = panels.split_horizontally((width.saturating_sub(SIDE_LEGEND)) / 2);
    let mut builders: Vec<&str> = Vec::new();
    let mut scenes: Vec<&str> = Vec::new();
    for p in pts {
        if !builders.contains(&p.builder.as_str()) {
            builders.push(&p.builder);
        }
        if !scenes.contains(&p.scene.as_str()) {
            scenes.push(&p.scene);
        }
    }
    type Axis = fn(&BuilderPoint) -> f64;
    for (area, title, xdesc, ydesc, fx, fy) in [
        (
            &left,
            "SAH cost against build time",
            "build ms (log)",
            "SAH cost",
            (|p: &BuilderPoint| p.build_ms.max(1e-3)) as Axis,
            (|p: &BuilderPoint| p.sah_cost) as Axis,
        ),
        (
            &right,
            "Nodes per ray against render time",
            "render ms (log)",
            "nodes visited per ray",
            (|p: &BuilderPoint| p.render_ms.median) as Axis,
            (|p: &BuilderPoint| p.nodes_per_ray) as Axis,
        ),
    ] {
        let mut chart = ChartBuilder::on(area)
            .caption(title, (FONT, 20))
            .margin(12)
            .x_label_area_size(45)
            .y_label_area_size(55)
            .build_cartesian_2d(
                log_range(pts.iter().map(fx)).log_scale(),
                lin_range(pts.iter().map(fy), true),
            )?;
        chart
            .configure_mesh()
            .x_desc(xdesc)
            .y_desc(ydesc)
            .x_label_formatter(&log_label)
            .draw()?;
        for (i, b) in builders.iter().enumerate() {
            let c = color(i);
            chart.draw_series(pts.iter().filter(|p| p.builder == *b).map(|p| {
                let si = scenes.iter().position(|s| *s == p.scene).unwrap_or(0);
                let marker: DynElement<DB, (f64, f64)> = if si % 2 == 0 {
                    Circle::new((fx(p), fy(p)), 5, c.filled()).into_dyn()
                } else {
                    TriangleMarker::new((fx(p), fy(p)), 6, c.filled()).into_dyn()
                };
                marker
            }))?;
        }
    }
    let entries: Vec<(String, RGBAColor)> = builders
        .iter()
        .enumerate()
        .map(|(i, b)| (b.to_string(), color(i)))
        .collect();
    side_legend(&side, &entries, Swatch::Dot)?;
    let note = format!(
        "circles: {}   triangles: {}",
        scenes.first().copied().unwrap_or(""),
        scenes.get(1).copied().unwrap_or("-")
    );
    root.draw(&Text::new(note, (20, 500), (FONT, 13).into_font()))?;
    root.present()?;
    Ok(())
}

pub fn leaks_chart(dir: &Path, rows: &[LeakRow]) -> Result<String> {
    save_chart!(dir, "leaks", (900, 520), draw_leaks, rows)
}

fn draw_leaks<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, rows: &[LeakRow]) -> DrawResult
where
    DB::ErrorType: 'static,
{
    root.fill(&WHITE)?;
    let method = |r: &LeakRow| {
        if r.embree {
            r.backend.clone()
        } else {
            format!(
                "{} ({})",
                r.backend.split("-watertight").next().unwrap_or(""),
                r.intersector
            )
        }
    };
    let mut methods: Vec<String> = Vec::new();
    for r in rows {
        let m = method(r);
        if !methods.contains(&m) {
            methods.push(m);
        }
    }
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Leak rate against speed, per intersection method",
            (FONT, 20),
        )
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(
            log_range(rows.iter().map(|r| r.ns_per_ray)).log_scale(),
            lin_range(rows.iter().map(|r| r.leak_rate * 100.0), true),
        )?;
    chart
        .configure_mesh()
        .x_desc("ns per closest-hit query (log)")
        .x_label_formatter(&log_label)
        .y_desc("rays through the mesh (%)")
        .draw()?;
    for (i, m) in methods.iter().enumerate() {
        let c = color(i);
        chart
            .draw_series(
                rows.iter()
                    .filter(|r| method(r) == *m)
                    .map(|r| Circle::new((r.ns_per_ray, r.leak_rate * 100.0), 5, c.filled())),
            )?
            .label(m.as_str())
            .legend(move |(x, y)| Circle::new((x + 6, y), 5, c.filled()));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    root.present()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn bar_labels_are_short() {
        assert_eq!(super::short("cornell-water"), "water");
        assert_eq!(super::short("mesh:100000"), "mesh 1e5");
        assert_eq!(super::short("mesh:1"), "mesh 1e0");
        assert_eq!(super::short("mesh:123456"), "mesh:123456");
        assert_eq!(super::short("mesh:0"), "mesh:0");
        assert_eq!(super::short("/some/scene.obj"), "/some/scene.obj");
    }
}
