//! Charts and false-colour images for `lfr compare`.
//!
//! * [`error_vs_time`] draws PSNR against wall time (log axis) for the path-tracing ladder and
//!   each reconstruction, as an 800x520 PNG and the same chart as SVG.
//! * [`false_colour`] maps a scalar image (e.g. per-pixel error) through viridis into a PNG.
//! * [`colour_bar`] draws the matching horizontal viridis legend.
//!
//! Every file goes through [`tracer::output::write_atomically`], so a failed write never leaves
//! a half-written file under the final name.
//!
//! Fonts: plotters is built with `ab_glyph` only, so bitmap text needs a TrueType font that is
//! loaded at run time (`LFR_FONT`, then a few common system paths) and registered once as
//! `"sans-serif"`. Without one the PNG chart is drawn without any text and a single warning is
//! printed; the SVG writes `<text>` elements and keeps its text either way.

use std::path::Path;
use std::sync::OnceLock;

use anyhow::{anyhow, bail, Context};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use plotters::style::{register_font, FontStyle};

/// One series of the error-vs-time chart.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    pub label: String,
    /// (wall time in seconds, PSNR in dB).
    pub points: Vec<(f64, f64)>,
}

/// Size of the PNG chart in pixels (the SVG uses the same size in user units).
const CHART_SIZE: (u32, u32) = (800, 520);
/// Size of the colour-bar PNG in pixels.
const BAR_SIZE: (u32, u32) = (320, 40);
/// Font family the TrueType font is registered under; `TextStyle`s must use the same name.
const FAMILY: &str = "sans-serif";
/// Times (s) outside this range are drawn at its edge.
const TIME_LIMITS: (f64, f64) = (1e-9, 1e9);
/// PSNRs (dB) beyond ± this are drawn at ± this.
const PSNR_LIMIT: f64 = 1e4;
/// Colour of non-finite values in false-colour images.
const MAGENTA: [u8; 3] = [255, 0, 255];

/// The first curve (the path-tracing ladder) is black; the others cycle through these.
const PALETTE: [RGBColor; 9] = [
    RGBColor(214, 39, 40),   // red
    RGBColor(31, 119, 180),  // blue
    RGBColor(255, 127, 14),  // orange
    RGBColor(44, 160, 44),   // green
    RGBColor(148, 103, 189), // purple
    RGBColor(140, 86, 75),   // brown
    RGBColor(227, 119, 194), // pink
    RGBColor(23, 190, 207),  // cyan
    RGBColor(188, 189, 34),  // olive
];

const FONT_PATHS: [&str; 4] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

/// Whether a font is registered under [`FAMILY`]. Looks for one on the first call only.
fn font_available() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(load_font)
}

fn load_font() -> bool {
    let from_env = std::env::var_os("LFR_FONT").filter(|v| !v.is_empty());
    if let Some(path) = &from_env {
        if try_register(Path::new(path)) {
            return true;
        }
        let shown = Path::new(path).display();
        eprintln!("warning: LFR_FONT={shown} is not a readable TrueType/OpenType font; trying system fonts");
    }
    if FONT_PATHS.iter().any(|p| try_register(Path::new(p))) {
        return true;
    }
    eprintln!(
        "warning: no TrueType font found (set LFR_FONT or install DejaVu Sans); \
         PNG charts are drawn without text"
    );
    false
}

fn try_register(path: &Path) -> bool {
    let Ok(bytes) = std::fs::read(path) else {
        return false;
    };
    // plotters keeps `&'static` font data; this happens at most a few times per process.
    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    register_font(FAMILY, FontStyle::Normal, bytes).is_ok()
}

fn font(size: f64) -> TextStyle<'static> {
    (FAMILY, size).into_font().color(&BLACK)
}

/// Draws `curves` as PSNR (dB) against wall time (s, log axis) into `png` (800x520) and `svg`.
///
/// Points with a non-finite or non-positive time or a non-finite PSNR are dropped, absurd values
/// (times outside 1 ns to 1e9 s, |PSNR| above 1e4 dB) are pinned to those limits, points are
/// joined in order of time, and curves left without points are not drawn (nor listed in the
/// legend). The first curve is drawn in black.
pub fn error_vs_time(curves: &[Curve], title: &str, png: &Path, svg: &Path) -> anyhow::Result<()> {
    let series = clean_curves(curves);
    let ranges = chart_ranges(&series);
    let (w, h) = CHART_SIZE;

    let text = font_available();
    let rgb = render_chart_png(&series, ranges, title, text)?;
    let svg_text = render_chart_svg(&series, ranges, title)?;

    write_png(png, w, h, &rgb)?;
    tracer::output::write_atomically(svg, |tmp| std::fs::write(tmp, svg_text.as_bytes()).map_err(|e| e.to_string()))?;
    Ok(())
}

/// A curve ready to draw: its colour, label and cleaned, time-sorted points.
struct Series {
    label: String,
    colour: RGBColor,
    points: Vec<(f64, f64)>,
}

fn curve_colour(index: usize) -> RGBColor {
    if index == 0 {
        BLACK
    } else {
        PALETTE[(index - 1) % PALETTE.len()]
    }
}

fn clean_curves(curves: &[Curve]) -> Vec<Series> {
    curves
        .iter()
        .enumerate()
        .filter_map(|(i, c)| {
            let mut points: Vec<(f64, f64)> =
                c.points.iter().copied().filter(|&(t, p)| t.is_finite() && t > 0.0 && p.is_finite()).collect();
            if points.is_empty() {
                return None;
            }
            // Pin absurd values to the edge of what the axes can show (plotters' log axis loops
            // forever when the range spans more than f64 can hold).
            for (t, p) in &mut points {
                *t = t.clamp(TIME_LIMITS.0, TIME_LIMITS.1);
                *p = p.clamp(-PSNR_LIMIT, PSNR_LIMIT);
            }
            points.sort_by(|a, b| a.0.total_cmp(&b.0));
            Some(Series { label: c.label.clone(), colour: curve_colour(i), points })
        })
        .collect()
}

type Ranges = ((f64, f64), (f64, f64));

/// Axis ranges with some padding; never empty, never degenerate, always positive on x.
fn chart_ranges(series: &[Series]) -> Ranges {
    let all = || series.iter().flat_map(|s| s.points.iter().copied());
    if all().next().is_none() {
        return ((0.1, 100.0), (0.0, 50.0));
    }
    let (tmin, tmax) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (t, _)| (a.min(t), b.max(t)));
    let (pmin, pmax) = all().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), (_, p)| (a.min(p), b.max(p)));
    (time_range(tmin, tmax), psnr_range(pmin, pmax))
}

fn time_range(tmin: f64, tmax: f64) -> (f64, f64) {
    let span = (tmax / tmin).ln();
    let pad = if span.is_finite() { (0.06 * span).max(0.1) } else { 0.1 };
    let lo = (tmin.ln() - pad).exp().max(f64::MIN_POSITIVE);
    let hi = (tmax.ln() + pad).exp().min(f64::MAX);
    // plotters' log axis places ticks from the first power of ten in range upwards (computed as
    // below): if there is none, start the axis just below one so that ticks cover the range.
    if 10f64.powf((lo.ln() / std::f64::consts::LN_10).ceil()) <= hi {
        return (lo, hi);
    }
    let below = 10f64.powf(lo.log10().floor());
    ((below * 0.999).max(f64::MIN_POSITIVE), hi)
}

fn psnr_range(pmin: f64, pmax: f64) -> (f64, f64) {
    let span = pmax - pmin;
    if !span.is_finite() {
        return (pmin, pmax);
    }
    if span <= 1e-9 * pmax.abs().max(1.0) {
        let pad = 1.0f64.max(pmax.abs() * 1e-3);
        return (pmin - pad, pmax + pad);
    }
    (pmin - 0.08 * span, pmax + 0.08 * span)
}

fn render_chart_png(series: &[Series], ranges: Ranges, title: &str, text: bool) -> anyhow::Result<Vec<u8>> {
    let (w, h) = CHART_SIZE;
    let mut rgb = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        draw_chart(&root, series, ranges, title, text).map_err(|e| anyhow!("drawing the PNG chart: {e}"))?;
        root.present().map_err(|e| anyhow!("drawing the PNG chart: {e}"))?;
    }
    Ok(rgb)
}

fn render_chart_svg(series: &[Series], ranges: Ranges, title: &str) -> anyhow::Result<String> {
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, CHART_SIZE).into_drawing_area();
        draw_chart(&root, series, ranges, title, true).map_err(|e| anyhow!("drawing the SVG chart: {e}"))?;
        root.present().map_err(|e| anyhow!("drawing the SVG chart: {e}"))?;
    }
    Ok(svg)
}

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// Draws the whole chart. With `text` false nothing that needs a font is drawn. With `text`
/// true, only text drawing is used, never text measurement except where a fallback exists, so
/// the SVG backend works without a registered font.
fn draw_chart<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    series: &[Series],
    ((xlo, xhi), (ylo, yhi)): Ranges,
    title: &str,
    text: bool,
) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let (w, _) = root.dim_in_pixel();
    if text && !title.is_empty() {
        root.draw_text(title, &font(22.0).pos(Pos::new(HPos::Center, VPos::Top)), (w as i32 / 2, 10))?;
    }

    let mut builder = ChartBuilder::on(root);
    builder.margin(12).margin_right(24);
    if text {
        builder.margin_top(44).x_label_area_size(48).y_label_area_size(64);
    }
    let mut chart = builder.build_cartesian_2d((xlo..xhi).log_scale(), ylo..yhi)?;

    let y_decimals = decimals_for_step((yhi - ylo) / 10.0);
    let x_fmt = |v: &f64| format_number(*v);
    let y_plain = ylo.abs().max(yhi.abs()) < 1e5;
    let y_fmt = |v: &f64| if y_plain { format!("{v:.y_decimals$}") } else { format_number(*v) };
    let mut mesh = chart.configure_mesh();
    mesh.bold_line_style(BLACK.mix(0.15))
        .light_line_style(BLACK.mix(0.05))
        // on the log axis this gives light lines at 2..9 x 10^k rather than a hundred per decade
        .x_max_light_lines(5)
        .y_max_light_lines(2)
        .axis_style(BLACK.mix(0.7))
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt);
    if text {
        mesh.x_desc("time (s, log scale)")
            .y_desc("PSNR (dB, higher is better)")
            .label_style(font(14.0))
            .axis_desc_style(font(16.0));
    }
    mesh.draw()?;

    for s in series {
        chart.draw_series(LineSeries::new(s.points.iter().copied(), s.colour.stroke_width(2)))?;
        chart.draw_series(s.points.iter().map(|&p| Circle::new(p, 3, s.colour.filled())))?;
    }

    let area = chart.plotting_area().strip_coord_spec();
    let (pw, ph) = area.dim_in_pixel();
    area.draw(&Rectangle::new([(0, 0), (pw as i32 - 1, ph as i32 - 1)], BLACK.mix(0.7)))?;
    if text {
        draw_legend(&area, series)?;
    }
    Ok(())
}

/// A legend box in the lower right of the plotting area. Text widths come from the font when one
/// is registered and from an estimate otherwise (the SVG needs no font to show its text).
fn draw_legend<DB: DrawingBackend>(area: &DrawingArea<DB, Shift>, series: &[Series]) -> DrawResult<DB> {
    if series.is_empty() {
        return Ok(());
    }
    const ROW: i32 = 20;
    const PAD: i32 = 8;
    const SAMPLE: i32 = 26;
    let style = font(14.0);
    let text_width = series
        .iter()
        .map(|s| match area.estimate_text_size(&s.label, &style) {
            Ok((w, _)) => w as i32,
            Err(_) => 7 * s.label.chars().count() as i32,
        })
        .max()
        .unwrap_or(0);
    let (pw, ph) = area.dim_in_pixel();
    let bw = PAD + SAMPLE + 8 + text_width + PAD;
    let bh = 2 * PAD + ROW * series.len() as i32;
    let x0 = (pw as i32 - bw - 10).max(0);
    let y0 = (ph as i32 - bh - 10).max(0);

    area.draw(&Rectangle::new([(x0, y0), (x0 + bw, y0 + bh)], WHITE.mix(0.85).filled()))?;
    area.draw(&Rectangle::new([(x0, y0), (x0 + bw, y0 + bh)], BLACK.mix(0.5)))?;
    let style = style.pos(Pos::new(HPos::Left, VPos::Center));
    for (i, s) in series.iter().enumerate() {
        let cy = y0 + PAD + ROW * i as i32 + ROW / 2;
        let (sx0, sx1) = (x0 + PAD, x0 + PAD + SAMPLE);
        area.draw(&PathElement::new(vec![(sx0, cy), (sx1, cy)], s.colour.stroke_width(2)))?;
        area.draw(&Circle::new(((sx0 + sx1) / 2, cy), 3, s.colour.filled()))?;
        area.draw_text(&s.label, &style, (sx1 + 8, cy))?;
    }
    Ok(())
}

/// Decimal places that resolve steps of `step`.
fn decimals_for_step(step: f64) -> usize {
    if step.is_nan() || step <= 0.0 || step.is_infinite() {
        return 1;
    }
    (-step.log10().floor()).clamp(0.0, 6.0) as usize
}

/// A short human-readable number: plain with up to three decimals, scientific when tiny or huge.
fn format_number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let a = v.abs();
    if (1e-3..1e5).contains(&a) {
        let s = format!("{v:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    } else {
        let s = format!("{v:.2e}");
        match s.split_once('e') {
            Some((m, e)) => format!("{}e{e}", m.trim_end_matches('0').trim_end_matches('.')),
            None => s,
        }
    }
}

/// Viridis at `t` in [0, 1].
fn viridis(t: f32) -> [u8; 3] {
    let c: RGBColor = ViridisRGB.get_color(t.clamp(0.0, 1.0));
    [c.0, c.1, c.2]
}

/// Where `v` falls on a scale from 0 to `max`, clamped to [0, 1]; `None` for non-finite values.
/// A `max` that is not a positive finite number saturates every positive value.
fn scale(v: f32, max: f32) -> Option<f32> {
    if !v.is_finite() {
        return None;
    }
    let t = if max > 0.0 && max.is_finite() {
        v / max
    } else if v > 0.0 {
        1.0
    } else {
        0.0
    };
    Some(t.clamp(0.0, 1.0))
}

/// Writes `values` (row-major, `width` x `height`) as a PNG: value/max through viridis, with
/// non-finite values in magenta.
pub fn false_colour(values: &[f32], width: u32, height: u32, max: f32, path: &Path) -> anyhow::Result<()> {
    let expected = (width as usize).checked_mul(height as usize).context("image size overflows")?;
    if values.len() != expected {
        bail!("false colour image {}: {} values for {width}x{height} pixels", path.display(), values.len());
    }
    if expected == 0 {
        bail!("false colour image {}: empty image ({width}x{height})", path.display());
    }
    let rgb: Vec<u8> = values.iter().flat_map(|&v| scale(v, max).map_or(MAGENTA, viridis)).collect();
    write_png(path, width, height, &rgb)
}

/// Writes a small horizontal viridis legend (320x40 PNG) for [`false_colour`] images scaled to
/// `max`. With a font available, "0", `label` and `max` are written under the bar.
pub fn colour_bar(max: f32, label: &str, path: &Path) -> anyhow::Result<()> {
    let (w, h) = BAR_SIZE;
    let text = font_available();
    let margin = 4u32;
    let bar_bottom = if text { 22 } else { h - margin };
    let mut rgb = vec![255u8; (w * h * 3) as usize];
    let bar_w = w - 2 * margin;
    for y in margin..bar_bottom {
        for x in margin..w - margin {
            let t = (x - margin) as f32 / (bar_w - 1) as f32;
            let i = ((y * w + x) * 3) as usize;
            rgb[i..i + 3].copy_from_slice(&viridis(t));
        }
    }
    if text {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        let draw = || -> DrawResult<BitMapBackend> {
            let y = bar_bottom as i32 + 2;
            let style = |h| font(14.0).pos(Pos::new(h, VPos::Top));
            root.draw_text("0", &style(HPos::Left), (margin as i32, y))?;
            root.draw_text(&format_number(max as f64), &style(HPos::Right), ((w - margin) as i32, y))?;
            if !label.is_empty() {
                root.draw_text(label, &style(HPos::Center), (w as i32 / 2, y))?;
            }
            root.present()
        };
        draw().map_err(|e| anyhow!("drawing the colour bar: {e}"))?;
    }
    write_png(path, w, h, &rgb)
}

fn write_png(path: &Path, width: u32, height: u32, rgb: &[u8]) -> anyhow::Result<()> {
    tracer::output::write_atomically(path, |tmp| {
        image::save_buffer_with_format(tmp, rgb, width, height, image::ExtendedColorType::Rgb8, image::ImageFormat::Png)
            .map_err(|e| format!("cannot write PNG: {e}"))
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn curves() -> Vec<Curve> {
        vec![
            Curve { label: "path tracing".into(), points: vec![(0.5, 20.0), (1.0, 23.0), (2.0, 26.0), (4.0, 29.0)] },
            Curve { label: "box filter".into(), points: vec![(0.6, 24.0)] },
            Curve { label: "cross bilateral".into(), points: vec![(0.8, 26.5), (0.7, 25.0)] },
        ]
    }

    fn check_png(path: &Path) {
        let img = image::open(path).expect("PNG decodes");
        assert_eq!((img.width(), img.height()), CHART_SIZE);
    }

    #[test]
    fn plot_png_and_svg() {
        let dir = tempfile::tempdir().unwrap();
        let (png, svg) = (dir.path().join("out/chart.png"), dir.path().join("out/chart.svg"));
        error_vs_time(&curves(), "Cornell box: error vs time", &png, &svg).unwrap();
        check_png(&png);
        let text = std::fs::read_to_string(&svg).unwrap();
        for needle in ["path tracing", "box filter", "cross bilateral", "Cornell box: error vs time", "PSNR"] {
            assert!(text.contains(needle), "SVG lacks {needle:?}");
        }
        let left: Vec<_> = std::fs::read_dir(dir.path().join("out")).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(left.len(), 2, "{left:?}");
    }

    #[test]
    fn plot_png_has_curves_in_colour() {
        let dir = tempfile::tempdir().unwrap();
        let (png, svg) = (dir.path().join("c.png"), dir.path().join("c.svg"));
        error_vs_time(&curves(), "t", &png, &svg).unwrap();
        let img = image::open(&png).unwrap().to_rgb8();
        let red = PALETTE[0];
        assert!(img.pixels().any(|p| p.0 == [red.0, red.1, red.2]), "second curve not drawn in its colour");
        assert!(img.pixels().any(|p| p.0 == [0, 0, 0]), "ladder not drawn in black");
    }

    #[test]
    fn plot_bad_points_are_dropped() {
        let dir = tempfile::tempdir().unwrap();
        let (png, svg) = (dir.path().join("b.png"), dir.path().join("b.svg"));
        let bad = vec![
            Curve {
                label: "ladder".into(),
                points: vec![
                    (f64::NAN, 20.0),
                    (0.0, 21.0),
                    (-1.0, 22.0),
                    (f64::INFINITY, 23.0),
                    (1.0, f64::NAN),
                    (2.0, f64::INFINITY),
                    (3.0, 30.0),
                ],
            },
            Curve { label: "nothing".into(), points: vec![(0.0, f64::NAN)] },
        ];
        error_vs_time(&bad, "bad", &png, &svg).unwrap();
        check_png(&png);
        let text = std::fs::read_to_string(&svg).unwrap();
        assert!(text.contains("ladder") && !text.contains("nothing"));
    }

    #[test]
    fn plot_empty_curves() {
        let dir = tempfile::tempdir().unwrap();
        let (png, svg) = (dir.path().join("e.png"), dir.path().join("e.svg"));
        error_vs_time(&[], "empty", &png, &svg).unwrap();
        check_png(&png);
        let empty = vec![Curve { label: "a".into(), points: vec![] }, Curve { label: "b".into(), points: vec![] }];
        error_vs_time(&empty, "empty", &png, &svg).unwrap();
        check_png(&png);
        assert!(std::fs::read_to_string(&svg).unwrap().contains("PSNR"));
    }

    #[test]
    fn plot_degenerate_and_extreme_ranges() {
        let dir = tempfile::tempdir().unwrap();
        let (png, svg) = (dir.path().join("d.png"), dir.path().join("d.svg"));
        let cases: Vec<Vec<(f64, f64)>> = vec![
            vec![(1.0, 30.0)],
            vec![(3.0, 30.0), (3.0, 30.0)],
            vec![(2.0, 30.0), (5.0, 30.0)],
            vec![(0.0021, 10.0), (0.0023, 10.5)],
            vec![(1e-9, -5.0), (1e6, 150.0)],
            vec![(f64::MIN_POSITIVE, 1e-300), (f64::MAX, 1e300)],
        ];
        for points in cases {
            let c = [Curve { label: "x".into(), points: points.clone() }];
            error_vs_time(&c, "d", &png, &svg).unwrap_or_else(|e| panic!("{points:?}: {e}"));
            check_png(&png);
        }
    }

    #[test]
    fn plot_ranges_are_sane() {
        let s = |pts: Vec<(f64, f64)>| clean_curves(&[Curve { label: String::new(), points: pts }]);
        for pts in [vec![(1.0, 30.0)], vec![(3.0, 30.0), (3.0, 30.0)], vec![(2.0, 30.0), (5.0, 31.0)]] {
            let ((xlo, xhi), (ylo, yhi)) = chart_ranges(&s(pts.clone()));
            assert!(0.0 < xlo && xlo < xhi && xhi.is_finite() && ylo < yhi, "{pts:?}");
            for (t, p) in pts {
                assert!(xlo < t && t < xhi && ylo < p && p < yhi);
            }
            // a power of ten lies in the x range, so the log axis has ticks
            let k = (xlo.ln() / std::f64::consts::LN_10).ceil();
            assert!(10f64.powf(k) <= xhi, "{xlo}..{xhi}");
        }
        // plotters' log axis needs a finite ratio hi/lo (it loops forever otherwise)
        let ((xlo, xhi), _) = chart_ranges(&s(vec![(f64::MIN_POSITIVE, 1.0), (f64::MAX, 2.0)]));
        assert!((xhi / xlo).is_finite());
        let ((xlo, xhi), (ylo, yhi)) = chart_ranges(&[]);
        assert!(0.0 < xlo && xlo < xhi && ylo < yhi);
    }

    #[test]
    fn plot_without_font_draws_no_text() {
        let series = clean_curves(&curves());
        let ranges = chart_ranges(&series);
        let rgb = render_chart_png(&series, ranges, "title", false).unwrap();
        assert_eq!(rgb.len(), (CHART_SIZE.0 * CHART_SIZE.1 * 3) as usize);
        // the svg draws its text without measuring it (no font needed)
        let svg = render_chart_svg(&series, ranges, "title").unwrap();
        assert!(svg.contains("box filter"));
    }

    #[test]
    fn plot_format_number() {
        assert_eq!(format_number(1.0), "1");
        assert_eq!(format_number(0.30000000000000004), "0.3");
        assert_eq!(format_number(250.0), "250");
        assert_eq!(format_number(0.0002), "2e-4");
        assert_eq!(format_number(1.5e6), "1.5e6");
        assert_eq!(format_number(0.0), "0");
    }

    #[test]
    fn plot_false_colour_ramp() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ramp.png");
        false_colour(&[0.0, 0.2, 0.4, 0.6, 0.8, 1.0], 3, 2, 1.0, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (3, 2));
        assert_eq!(img.get_pixel(0, 0).0, viridis(0.0));
        assert_eq!(img.get_pixel(2, 1).0, viridis(1.0));
        let v0: RGBColor = ViridisRGB.get_color(0.0f32);
        let v1: RGBColor = ViridisRGB.get_color(1.0f32);
        assert_eq!(img.get_pixel(0, 0).0, [v0.0, v0.1, v0.2]);
        assert_eq!(img.get_pixel(2, 1).0, [v1.0, v1.1, v1.2]);
        assert_ne!(v0, v1);
    }

    #[test]
    fn plot_false_colour_clamps_and_flags_non_finite() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("nan.png");
        false_colour(&[f32::NAN, -1.0, 5.0, f32::INFINITY], 2, 2, 2.0, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.get_pixel(0, 0).0, MAGENTA);
        assert_eq!(img.get_pixel(1, 0).0, viridis(0.0));
        assert_eq!(img.get_pixel(0, 1).0, viridis(1.0));
        assert_eq!(img.get_pixel(1, 1).0, MAGENTA);
        // a zero max (e.g. a perfect reconstruction) does not turn everything magenta
        false_colour(&[0.0, 0.0], 2, 1, 0.0, &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.get_pixel(1, 0).0, viridis(0.0));
    }

    #[test]
    fn plot_false_colour_wrong_length() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wrong.png");
        assert!(false_colour(&[0.0; 5], 3, 2, 1.0, &path).is_err());
        assert!(false_colour(&[], 0, 0, 1.0, &path).is_err());
        assert!(!path.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn plot_colour_bar() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bar.png");
        colour_bar(0.25, "absolute error", &path).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), BAR_SIZE);
        assert_eq!(img.get_pixel(4, 10).0, viridis(0.0));
        assert_eq!(img.get_pixel(BAR_SIZE.0 - 5, 10).0, viridis(1.0));
        colour_bar(f32::NAN, "", &path).unwrap();
    }
}
