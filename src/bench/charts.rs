//! The bench's charts, drawn with `plotters` twice: SVG (for zooming and papers)
//! and PNG (for the report and quick looks). Text needs a TrueType font, read
//! once from the system (DejaVu Sans from `fonts-dejavu-core`, or `RAYLAB_FONT`).
//! What every chart shares lives here (font, legends, axes, saving, the
//! grouped bar chart); each part's own chart is in its file under
//! [`super::parts`].

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::combinators::{LogCoord, WithKeyPoints};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::bench::family::Family;
use crate::error::{Error, Result};

pub(super) type DrawResult = std::result::Result<(), Box<dyn std::error::Error>>;

pub(super) const FONT: &str = "sans-serif";
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
pub(super) fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
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
pub(super) const SIDE_LEGEND: u32 = 190;

/// How a legend entry's swatch is drawn.
#[derive(Clone, Copy)]
pub(super) enum Swatch {
    Bar,
    Dot,
}

/// A legend in a strip of its own beside the plot (many series: inside the plot
/// it covered bars and points).
pub(super) fn side_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, RGBAColor)],
    swatch: Swatch,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    // Rows of 19 pixels, closer (and their text smaller) where that many
    // would run off the strip.
    let (_, height) = area.dim_in_pixel();
    let (step, size) = legend_rows(entries.len(), height);
    let style = TextStyle::from((FONT, size).into_font()).pos(Pos::new(HPos::Left, VPos::Center));
    let half = (step / 4).clamp(2, 5);
    for (i, (name, c)) in entries.iter().enumerate() {
        let y = 50 + step * i as i32;
        match swatch {
            Swatch::Bar => {
                area.draw(&Rectangle::new([(8, y - half), (20, y + half)], c.filled()))?
            }
            Swatch::Dot => area.draw(&Circle::new((14, y), half as u32, c.filled()))?,
        }
        area.draw(&Text::new(name.clone(), (28, y), style.clone()))?;
    }
    Ok(())
}

/// Side-legend entries for series coloured by their position, as
/// [`color`] colours them: the `i`th name in `color(i)`.
pub(super) fn palette_entries<S: ToString>(names: &[S]) -> Vec<(String, RGBAColor)> {
    names
        .iter()
        .enumerate()
        .map(|(i, name)| (name.to_string(), color(i)))
        .collect()
}

/// The row step and font size of a side legend of `entries` rows in a strip
/// `height` pixels tall (starting 50 pixels down): 19 and 13 where they
/// fit, else the rows share the height, down to 8 pixels and size 8.
fn legend_rows(entries: usize, height: u32) -> (i32, u32) {
    let room = height.saturating_sub(60) as i32;
    let step = (room / entries.max(1) as i32).clamp(8, 19);
    (step, (step as u32 * 13 / 19).clamp(8, 13))
}

/// A labelled line through `points` with a dot on each.
pub(super) fn line_with_points<'a, DB, CT>(
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

/// Draws `$draw(area, $data)` as `$dir/$name.svg` and `.png` (see [`save`]).
macro_rules! save_chart {
    ($dir:expr, $name:expr, $size:expr, $draw:ident, $data:expr) => {
        $crate::bench::charts::save($dir, $name, $size, |a| $draw(a, $data), |a| $draw(a, $data))
    };
}
pub(crate) use save_chart;

/// Draws one chart as `dir/name.svg` and `dir/name.png`; returns the PNG's name.
pub(super) fn save(
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
    crate::output::write_text(&dir.join(format!("{name}.svg")), &text)?;
    let mut pixels = vec![255u8; size.0 as usize * size.1 as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, size).into_drawing_area();
        png(root).map_err(fail)?;
    }
    let file = format!("{name}.png");
    crate::output::write_png(&dir.join(&file), size.0, size.1, &pixels)?;
    Ok(file)
}

pub(super) fn color(i: usize) -> RGBAColor {
    Palette99::pick(i).to_rgba()
}

/// A family's colour, the same on every chart: raylab blue, Embree orange,
/// each library a hue of its own.
pub(super) fn family_color(family: Family) -> RGBAColor {
    let (r, g, b) = match family {
        Family::Raylab => (31, 119, 180),
        Family::Embree => (255, 127, 14),
        Family::Tinybvh => (44, 160, 44),
        Family::Obvhs => (148, 103, 189),
        Family::BvhCrate => (140, 86, 75),
    };
    RGBColor(r, g, b).to_rgba()
}

/// The `i`-th of `n` shades of a family's colour (darker to lighter), so
/// that backends of one family look alike and stay apart.
pub(super) fn family_shade(family: Family, i: usize, n: usize) -> RGBAColor {
    let RGBAColor(r, g, b, a) = family_color(family);
    if n <= 1 {
        return RGBAColor(r, g, b, a);
    }
    // From 30% darker to 45% lighter.
    let t = i as f64 / (n - 1) as f64 * 0.75 - 0.3;
    let mix = |c: u8| {
        let c = c as f64;
        (if t < 0.0 {
            c * (1.0 + t)
        } else {
            c + (255.0 - c) * t
        })
        .round() as u8
    };
    RGBAColor(mix(r), mix(g), mix(b), a)
}

/// One series per family of `items` (in [`Family::ALL`]'s order), each
/// group's value the best (largest) of that family's items there, and the
/// legend naming how many items each family's best is of (`raylab (best
/// of 30 variants)`): a bar per variant made some 45 bars per group, in
/// colours too close to tell apart.
pub(super) fn best_per_family<T>(
    items: &[T],
    groups: usize,
    family: impl Fn(&T) -> Family,
    item_name: impl Fn(&T) -> &str,
    value: impl Fn(&T, usize) -> Option<f64>,
    what: &str,
) -> Vec<Series> {
    Family::ALL
        .into_iter()
        .filter_map(|f| {
            let mine: Vec<&T> = items.iter().filter(|i| family(i) == f).collect();
            if mine.is_empty() {
                return None;
            }
            let names = distinct(mine.iter().map(|i| item_name(i))).len();
            let values = (0..groups)
                .map(|g| {
                    mine.iter()
                        .filter_map(|i| value(i, g))
                        .filter(|v| v.is_finite())
                        .max_by(f64::total_cmp)
                })
                .collect();
            let name = if names == 1 {
                f.label().to_string()
            } else {
                format!("{} (best of {names} {what})", f.label())
            };
            Some(Series {
                name,
                color: family_color(f),
                values,
            })
        })
        .collect()
}

/// A range covering `values` on a log axis, with some room either side.
pub(super) fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values
        .filter(|v| *v > 0.0 && v.is_finite())
        .fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)));
    if lo > hi {
        return 0.1..10.0;
    }
    let hi = if hi <= lo { lo * 10.0 } else { hi };
    lo / 1.5..hi * 1.5
}

/// A log axis over `range`, ticked and labelled where [`log_ticks`] says,
/// with light grid lines at every whole multiple of each power of ten.
/// plotters' own log ticks start at the first power of ten inside the range,
/// so everything below it went unlabelled (the ladder's build axes, 1.5-10
/// ms, had one label, at 10).
pub(super) fn log_axis(range: std::ops::Range<f64>) -> WithKeyPoints<LogCoord<f64>> {
    let ticks = log_ticks(&range);
    let light = multiples_of_powers(&range, &WHOLE_MULTIPLES[1..]);
    range
        .log_scale()
        .with_key_points(ticks)
        .with_light_points(light)
}

/// The whole multiples of a power of ten below the next one.
const WHOLE_MULTIPLES: [f64; 9] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0];

/// The most ticks a log axis gets before it keeps only the powers of ten.
const MOST_LOG_TICKS: usize = 10;

/// A log axis's ticks: 1, 2 and 5 times each power of ten inside `range`;
/// only the powers (every second, third, ... one) where those would be more
/// than [`MOST_LOG_TICKS`]; every whole multiple where the range is so
/// narrow that fewer than two of 1, 2 and 5 fall in it.
pub(super) fn log_ticks(range: &std::ops::Range<f64>) -> Vec<f64> {
    let nice = multiples_of_powers(range, &[1.0, 2.0, 5.0]);
    if nice.len() < 2 {
        return multiples_of_powers(range, &WHOLE_MULTIPLES);
    }
    if nice.len() <= MOST_LOG_TICKS {
        return nice;
    }
    let powers = multiples_of_powers(range, &[1.0]);
    let step = powers.len().div_ceil(MOST_LOG_TICKS);
    powers.into_iter().step_by(step).collect()
}

/// Each of `multiples` times each power of ten, in ascending order, where
/// inside `range`.
fn multiples_of_powers(range: &std::ops::Range<f64>, multiples: &[f64]) -> Vec<f64> {
    if !(range.start > 0.0 && range.end > range.start && range.end.is_finite()) {
        return Vec::new();
    }
    let (first, last) = (
        range.start.log10().floor() as i32,
        range.end.log10().ceil() as i32,
    );
    (first..=last)
        .flat_map(|exp| multiples.iter().map(move |m| m * 10f64.powi(exp)))
        .filter(|v| range.contains(v))
        .collect()
}

/// Labels of a log axis's ticks ([`log_ticks`]: whole multiples of a power
/// of ten); anything else gets none.
pub(super) fn log_label(v: &f64) -> String {
    if !(*v > 0.0) {
        return String::new();
    }
    let exp = v.log10().floor();
    let mantissa = v / 10f64.powf(exp);
    if (mantissa - mantissa.round()).abs() > 1e-6 * mantissa {
        return String::new();
    }
    if (1e-2..1e5).contains(v) {
        let s = format!("{v:.2}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

pub(super) fn lin_range(
    values: impl Iterator<Item = f64>,
    include_zero: bool,
) -> std::ops::Range<f64> {
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

/// A scene name short enough to sit under a bar: without the `cornell-`
/// prefix, `mesh:N` with a power of ten as `mesh 1eK`, a file by its name
/// without folders and extension.
pub(super) fn short(scene: &str) -> String {
    if let Some(n) = scene
        .strip_prefix("mesh:")
        .and_then(|n| n.parse::<u64>().ok())
    {
        let k = n.checked_ilog10().unwrap_or(0);
        if 10u64.pow(k) == n {
            return format!("mesh 1e{k}");
        }
    }
    if scene.contains('/') || scene.contains('.') {
        // A file: its name without folders or extension (a chart's label
        // has room for a word, not a path).
        let path = std::path::Path::new(scene);
        if let Some(stem) = path.file_stem() {
            return stem.to_string_lossy().into_owned();
        }
    }
    scene.strip_prefix("cornell-").unwrap_or(scene).to_string()
}

/// One series of a [`Bars`] chart: its name and colour, and a value (or
/// none) per group.
pub(super) struct Series {
    pub(super) name: String,
    pub(super) color: RGBAColor,
    pub(super) values: Vec<Option<f64>>,
}

/// A grouped bar chart on a log axis: one group per entry of `groups` (two
/// label lines under it), one coloured bar per series in each group where
/// the series has a value.
pub(super) struct Bars<'a> {
    pub(super) caption: String,
    pub(super) y_desc: &'a str,
    pub(super) groups: Vec<(String, String)>,
    pub(super) series: Vec<Series>,
    pub(super) y: std::ops::Range<f64>,
    pub(super) y_label: &'a dyn Fn(&f64) -> String,
}

pub(super) fn draw_bars<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, b: &Bars) -> DrawResult
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
        .build_cartesian_2d(0f64..b.groups.len().max(1) as f64, log_axis(y.clone()))?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(0)
        .x_label_formatter(&|_| String::new())
        .y_desc(b.y_desc)
        .y_label_formatter(b.y_label)
        .draw()?;
    let width = 0.8 / b.series.len().max(1) as f64;
    for (si, s) in b.series.iter().enumerate() {
        let c = s.color;
        let bars: Vec<Rectangle<(f64, f64)>> = s
            .values
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
    let entries: Vec<(String, RGBAColor)> =
        b.series.iter().map(|s| (s.name.clone(), s.color)).collect();
    side_legend(&side, &entries, Swatch::Bar)?;
    // Under each group its second label; under each run of groups that
    // share a first label (a scene's ray kinds or views), that label once.
    // Each is shrunk to fit its room: long scene names and many groups
    // made neighbouring labels overlap.
    let x_px = |x: f64| chart.backend_coord(&(x, y.start));
    let group_px = (x_px(1.0).0 - x_px(0.0).0).max(1) as u32;
    let style = |size: u32| {
        TextStyle::from((FONT, size).into_font()).pos(Pos::new(HPos::Center, VPos::Top))
    };
    let width_at = |text: &str, size: u32| {
        plot.estimate_text_size(text, &style(size))
            .map_or(0, |(w, _)| w)
    };
    for (gi, (_, second)) in b.groups.iter().enumerate() {
        let (px, py) = x_px(gi as f64 + 0.5);
        let size = label_size(|size| width_at(second, size), group_px);
        plot.draw(&Text::new(second.clone(), (px, py + 6), style(size)))?;
    }
    let mut start = 0;
    while start < b.groups.len() {
        let first = &b.groups[start].0;
        let end = start
            + b.groups[start..]
                .iter()
                .take_while(|g| g.0 == *first)
                .count();
        let (px, py) = x_px((start + end) as f64 / 2.0);
        let room = group_px * (end - start) as u32;
        let size = label_size(|size| width_at(first, size), room);
        plot.draw(&Text::new(first.clone(), (px, py + 23), style(size)))?;
        start = end;
    }
    root.present()?;
    Ok(())
}

/// The font size, from 13 down to 7, at which a label is narrower than
/// `room` pixels (as `width_at` measures it), less a small gap; 7 when none
/// is.
fn label_size(width_at: impl Fn(u32) -> u32, room: u32) -> u32 {
    (7..=13)
        .rev()
        .find(|&size| width_at(size) + 4 <= room)
        .unwrap_or(7)
}

/// The distinct values of `items`, in first-seen order (the scenes or
/// series of a chart).
pub(super) fn distinct<'a>(items: impl Iterator<Item = &'a str>) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for i in items {
        if !out.contains(&i) {
            out.push(i);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn log_ranges_leave_room_around_the_values() {
        let r = super::log_range([22.0, 79.0].into_iter());
        assert!((r.start - 22.0 / 1.5).abs() < 1e-9 && (r.end - 79.0 * 1.5).abs() < 1e-9);
        // One value: a decade above it.
        let r = super::log_range([3.0, f64::NAN, -1.0].into_iter());
        assert!((r.start - 2.0).abs() < 1e-9 && (r.end - 45.0).abs() < 1e-9);
    }

    fn close(a: &[f64], b: &[f64]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-9 * y)
    }

    #[test]
    fn log_ticks_label_below_the_first_power_of_ten() {
        // The ladder's two-thread build axis: plotters ticked only 10.
        let t = super::log_ticks(&(1.5..10.5));
        assert!(close(&t, &[2.0, 5.0, 10.0]), "{t:?}");
        // No power of ten inside: 20 and 50 still labelled.
        let t = super::log_ticks(&(20.0..60.0));
        assert!(close(&t, &[20.0, 50.0]), "{t:?}");
        // Narrower than 1-2-5 can tick: every whole multiple.
        let t = super::log_ticks(&(2.1..4.9));
        assert!(close(&t, &[3.0, 4.0]), "{t:?}");
        // Many decades (the libraries' wrong-hit axis): powers only.
        let t = super::log_ticks(&(0.0667..1500.0));
        assert!(close(&t, &[0.1, 1.0, 10.0, 100.0, 1000.0]), "{t:?}");
        // More powers than fit (twelve, 1e9 being outside): every second one.
        let t = super::log_ticks(&(1e-3..1e9));
        assert!(close(&t, &[1e-3, 1e-1, 1e1, 1e3, 1e5, 1e7]), "{t:?}");
        // Every tick gets a label.
        for r in [1.5..10.5, 2.1..4.9, 0.0667..1500.0, 0.003..0.04] {
            for v in super::log_ticks(&r) {
                assert!(!super::log_label(&v).is_empty(), "{v} in {r:?}");
            }
        }
        assert_eq!(super::log_label(&2.5), "");
        assert_eq!(super::log_label(&0.02), "0.02");
        assert_eq!(super::log_label(&3e5), "3e5");
    }

    #[test]
    fn labels_shrink_to_fit_their_room() {
        // A label 6 pixels wide per point of font size.
        let width = |size: u32| 6 * size;
        assert_eq!(super::label_size(width, 200), 13);
        assert_eq!(super::label_size(width, 6 * 10 + 4), 10);
        assert_eq!(super::label_size(width, 6 * 10 + 3), 9);
        assert_eq!(super::label_size(width, 10), 7);
    }

    #[test]
    fn legends_of_many_series_fit_their_strip() {
        assert_eq!(super::legend_rows(8, 560), (19, 13));
        // 31 series in a 560-pixel chart: rows of 16 pixels end at 530.
        let (step, size) = super::legend_rows(31, 560);
        assert!(50 + step * 30 <= 560 - 10, "step {step}");
        assert!((8..13).contains(&size));
        assert_eq!(super::legend_rows(500, 560), (8, 8));
    }

    #[test]
    fn bar_labels_are_short() {
        assert_eq!(super::short("cornell-water"), "water");
        assert_eq!(super::short("mesh:100000"), "mesh 1e5");
        assert_eq!(super::short("mesh:1"), "mesh 1e0");
        assert_eq!(super::short("mesh:123456"), "mesh:123456");
        assert_eq!(super::short("mesh:0"), "mesh:0");
        assert_eq!(super::short("/some/scene.obj"), "scene");
        assert_eq!(
            super::short(
                "/usr/share/assimp/models/glTF2/2CylinderEngine-glTF-Binary/2CylinderEngine.glb"
            ),
            "2CylinderEngine"
        );
    }
}
