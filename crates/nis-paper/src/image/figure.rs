//! The figures of `nis fit-image`, as PNG bytes: a target and a learned density side by side in
//! false colour, the learning curves (KL and variance against step, drawn with `plotters`), and
//! the comparison montage of the benchmark (one row per target, one column per model, as in
//! Müller et al. 2019, Figure 3).
//!
//! Text (titles, tick labels) needs a TrueType font. None is bundled: the first of a few common
//! system fonts (or the file named by `NIS_FONT`) is used, and without one the figures are drawn
//! without text; the numbers are in the JSON and Markdown outputs anyway.

use std::io::Cursor;
use std::sync::OnceLock;

use ::image::codecs::png::{CompressionType, FilterType as PngFilter, PngEncoder};
use ::image::{Rgb, RgbImage};
use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::image::CurvePoint;

/// System fonts tried, in order, after `NIS_FONT`.
const FONT_PATHS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/System/Library/Fonts/Supplemental/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

/// Smallest value shown on the logarithmic axes (KL and variance can reach 0 or round below).
const LOG_FLOOR: f64 = 1e-4;

/// Picks one metric from a curve point.
type Metric = fn(&CurvePoint) -> f64;

/// Series colours of the learning curves, one per model.
const SERIES: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
];

/// Whether a font is registered with plotters (done once, on first use).
pub(crate) fn has_font() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(|| {
        let env = std::env::var("NIS_FONT").ok();
        let candidates = env.iter().map(String::as_str).chain(FONT_PATHS);
        for path in candidates {
            if let Ok(bytes) = std::fs::read(path) {
                // plotters keeps fonts for the life of the program.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return true;
                }
            }
        }
        false
    })
}

pub(crate) fn figure_error(e: impl std::fmt::Display) -> Error {
    Error::Figure(e.to_string())
}

/// Draws the legend of the labelled series of `chart` at `position` (text of `size` px), on a
/// translucent white box; nothing without a font (the series carry no labels then).
pub(crate) fn draw_legend<'a, DB, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    size: u32,
) -> Result<()>
where
    DB: DrawingBackend + 'a,
    CT: CoordTranslate,
{
    if !has_font() {
        return Ok(());
    }
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", size))
        .draw()
        .map_err(figure_error)
}

/// Encodes an RGB image as PNG bytes, compressed hard (figures go into the repository).
pub fn png_bytes(image: &RgbImage) -> Result<Vec<u8>> {
    let mut bytes = Vec::new();
    let encoder = PngEncoder::new_with_quality(
        Cursor::new(&mut bytes),
        CompressionType::Best,
        PngFilter::Adaptive,
    );
    image.write_with_encoder(encoder).map_err(figure_error)?;
    Ok(bytes)
}

/// The false-colour map (black → purple → orange → yellow, after matplotlib's "inferno") at
/// t ∈ [0, 1] (clamped).
pub fn false_colour(t: f64) -> Rgb<u8> {
    const STOPS: [[f64; 3]; 6] = [
        [0.0, 0.0, 4.0],
        [40.0, 11.0, 84.0],
        [101.0, 21.0, 110.0],
        [188.0, 55.0, 84.0],
        [249.0, 142.0, 9.0],
        [252.0, 255.0, 164.0],
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let s = t * (STOPS.len() - 1) as f64;
    let k = (s.floor() as usize).min(STOPS.len() - 2);
    let a = s - k as f64;
    let c = |i: usize| (STOPS[k][i] * (1.0 - a) + STOPS[k + 1][i] * a).round() as u8;
    Rgb([c(0), c(1), c(2)])
}

/// A density tabulated on an nx×ny grid (row-major, row 0 at the top) as a false-colour image
/// of `side`×`side` pixels (nearest cell), `scale` mapping to the top of the colour map.
pub fn density_image(values: &[f64], nx: usize, ny: usize, scale: f64, side: u32) -> RgbImage {
    RgbImage::from_fn(side, side, |u, v| {
        let i = (u as usize * nx / side as usize).min(nx - 1);
        let j = (v as usize * ny / side as usize).min(ny - 1);
        false_colour(values[j * nx + i] / scale)
    })
}

/// Draws `text` at pixel (x, y) of `image`: black, or white on a black box when `boxed` (to
/// stay legible over a density). Nothing without a font.
fn label(
    image: &mut RgbImage,
    text: &str,
    (x, y): (i32, i32),
    size: f64,
    boxed: bool,
) -> Result<()> {
    if !has_font() {
        return Ok(());
    }
    let (w, h) = image.dimensions();
    let root = BitMapBackend::with_buffer(image.as_mut(), (w, h)).into_drawing_area();
    let font = ("sans-serif", size).into_font();
    let colour = if boxed {
        let (tw, th) = root
            .estimate_text_size(text, &font.clone().into_text_style(&root))
            .map_err(figure_error)?;
        let corner = (x + tw as i32 + 3, y + th as i32 + 3);
        root.draw(&Rectangle::new([(x - 3, y - 3), corner], BLACK.filled()))
            .map_err(figure_error)?;
        &WHITE
    } else {
        &BLACK
    };
    root.draw_text(text, &font.color(colour), (x, y))
        .map_err(figure_error)?;
    root.present().map_err(figure_error)
}

/// Pastes `tile` into `image` with its top-left corner at (x, y).
fn paste(image: &mut RgbImage, tile: &RgbImage, x: u32, y: u32) {
    for (u, v, p) in tile.enumerate_pixels() {
        image.put_pixel(x + u, y + v, *p);
    }
}

/// The target p and the learned q side by side on one colour scale (the maximum of p), with a
/// title row: "target" | "learned (model)".
pub fn side_by_side(p: &[f64], q: &[f64], nx: usize, ny: usize, model: &str) -> Result<RgbImage> {
    const SIDE: u32 = 384;
    const GAP: u32 = 8;
    const TITLE: u32 = 28;
    let scale = p.iter().cloned().fold(0.0, f64::max);
    let mut image = RgbImage::from_pixel(2 * SIDE + 3 * GAP, SIDE + TITLE + GAP, Rgb([255; 3]));
    paste(
        &mut image,
        &density_image(p, nx, ny, scale, SIDE),
        GAP,
        TITLE,
    );
    paste(
        &mut image,
        &density_image(q, nx, ny, scale, SIDE),
        2 * GAP + SIDE,
        TITLE,
    );
    label(&mut image, "target", (GAP as i32, 4), 20.0, false)?;
    let title = format!("learned: {model}");
    label(
        &mut image,
        &title,
        ((2 * GAP + SIDE) as i32, 4),
        20.0,
        false,
    )?;
    Ok(image)
}

/// A white drawing area over an RGB `buffer` of `size` pixels, with `title` across its top when
/// a font is available (the frame every plot here starts from).
pub fn canvas<'a>(
    buffer: &'a mut [u8],
    size: (u32, u32),
    title: Option<&str>,
) -> Result<DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>> {
    let root = BitMapBackend::with_buffer(buffer, size).into_drawing_area();
    root.fill(&WHITE).map_err(figure_error)?;
    match title {
        Some(title) if has_font() => root.titled(title, ("sans-serif", 22)).map_err(figure_error),
        _ => Ok(root),
    }
}

/// The learning curves: D_KL(p‖q) (left) and Var(f/q)/F² (right) against training step, on
/// logarithmic axes, one line per named series.
pub fn curves(title: &str, series: &[(String, Vec<CurvePoint>)]) -> Result<RgbImage> {
    const W: u32 = 1100;
    const H: u32 = 420;
    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let root = canvas(&mut buffer, (W, H), Some(title))?;
        let panels = root.split_evenly((1, 2));
        let last_step = series
            .iter()
            .flat_map(|(_, c)| c.iter().map(|p| p.step))
            .max()
            .unwrap_or(1)
            .max(1);
        let pick: [(&str, Metric); 2] = [
            ("KL divergence (nats)", |p| p.metrics.kl),
            ("variance of f/q, relative", |p| p.metrics.rel_var),
        ];
        for (panel, (name, value)) in panels.iter().zip(pick) {
            let values = || series.iter().flat_map(|(_, c)| c.iter().map(value));
            let top = values().fold(LOG_FLOOR, f64::max) * 2.0;
            let bottom = values().fold(top, f64::min).max(LOG_FLOOR) / 2.0;
            let mut builder = ChartBuilder::on(panel);
            builder.margin(12);
            if has_font() {
                builder
                    .caption(name, ("sans-serif", 18))
                    .x_label_area_size(36)
                    .y_label_area_size(60);
            }
            let mut chart = builder
                .build_cartesian_2d(0..last_step, (bottom..top).log_scale())
                .map_err(figure_error)?;
            let mut mesh = chart.configure_mesh();
            if has_font() {
                mesh.x_desc("training step");
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(figure_error)?;
            for (k, (model, curve)) in series.iter().enumerate() {
                let colour = SERIES[k % SERIES.len()];
                let points = curve.iter().map(|p| (p.step, value(p).max(LOG_FLOOR)));
                let line = chart
                    .draw_series(LineSeries::new(points, colour.stroke_width(2)))
                    .map_err(figure_error)?;
                if has_font() {
                    line.label(model.as_str()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
                }
            }
            draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 14)?;
        }
        root.present().map_err(figure_error)?;
    }
    RgbImage::from_raw(W, H, buffer).ok_or_else(|| figure_error("plot buffer size"))
}

/// One panel of [`error_time`]: a scene's name, its equal-time budget in seconds and, per
/// method, its (wall seconds, MAPE) points.
pub type ErrorTimePanel = (String, f64, Vec<(String, Vec<(f64, f64)>)>);

/// Error against wall-clock time, one panel per scene: MAPE against seconds on logarithmic
/// axes, one line with markers per method, and a grey vertical line at the scene's equal-time
/// budget, so the time at which one method overtakes another can be read off.
pub fn error_time(title: &str, panels: &[ErrorTimePanel]) -> Result<RgbImage> {
    const H: u32 = 440;
    let w = 360 * panels.len().max(1) as u32 + 40;
    let mut buffer = vec![255u8; (w * H * 3) as usize];
    {
        let root = canvas(&mut buffer, (w, H), Some(title))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (area, (scene, budget, series)) in areas.iter().zip(panels) {
            let all = || series.iter().flat_map(|(_, c)| c.iter().copied());
            let t_lo = all().map(|p| p.0).fold(*budget, f64::min).max(1e-3) / 1.5;
            let t_hi = all().map(|p| p.0).fold(*budget, f64::max) * 1.5;
            let m_hi = all().map(|p| p.1).fold(LOG_FLOOR, f64::max) * 1.5;
            let m_lo = all().map(|p| p.1).fold(m_hi, f64::min).max(LOG_FLOOR) / 1.5;
            let mut builder = ChartBuilder::on(area);
            builder.margin(12);
            if has_font() {
                builder
                    .caption(scene, ("sans-serif", 18))
                    .x_label_area_size(36)
                    .y_label_area_size(56);
            }
            let mut chart = builder
                .build_cartesian_2d((t_lo..t_hi).log_scale(), (m_lo..m_hi).log_scale())
                .map_err(figure_error)?;
            let mut mesh = chart.configure_mesh();
            if has_font() {
                mesh.x_desc("wall seconds")
                    .y_desc("MAPE")
                    .x_labels(6)
                    .y_labels(6)
                    .x_label_formatter(&|t| format!("{t:.3}"))
                    .y_label_formatter(&|m| format!("{m:.3}"));
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(figure_error)?;
            chart
                .draw_series(LineSeries::new(
                    [(*budget, m_lo), (*budget, m_hi)],
                    BLACK.mix(0.35).stroke_width(1),
                ))
                .map_err(figure_error)?;
            for (k, (method, curve)) in series.iter().enumerate() {
                let colour = SERIES[k % SERIES.len()];
                let points: Vec<(f64, f64)> = curve
                    .iter()
                    .map(|&(t, m)| (t.max(t_lo), m.max(m_lo)))
                    .collect();
                let line = chart
                    .draw_series(LineSeries::new(
                        points.iter().copied(),
                        colour.stroke_width(2),
                    ))
                    .map_err(figure_error)?;
                if has_font() {
                    line.label(method.as_str()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
                }
                chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                    .map_err(figure_error)?;
            }
            draw_legend(&mut chart, SeriesLabelPosition::LowerLeft, 13)?;
        }
        root.present().map_err(figure_error)?;
    }
    RgbImage::from_raw(w, H, buffer).ok_or_else(|| figure_error("plot buffer size"))
}

/// One row of the montage: a target's name, its tabulated density p and each model's q (all
/// on the same nx×ny grid).
pub struct MontageRow {
    /// The target's name (row label).
    pub name: String,
    /// Cells per side of the grid: (nx, ny).
    pub size: (usize, usize),
    /// The normalised target p.
    pub p: Vec<f64>,
    /// Each model's learned density q, in column order.
    pub q: Vec<Vec<f64>>,
}

/// The comparison montage: one row per target, the target in the first column and each model
/// (named in `models`) in the next, every row on the colour scale of its target's maximum;
/// each tile is `tile`×`tile` pixels.
pub fn montage(models: &[String], rows: &[MontageRow], tile: u32) -> Result<RgbImage> {
    const GAP: u32 = 6;
    const HEADER: u32 = 26;
    let columns = models.len() as u32 + 1;
    let width = columns * (tile + GAP) + GAP;
    let height = HEADER + rows.len() as u32 * (tile + GAP) + GAP;
    let mut image = RgbImage::from_pixel(width, height, Rgb([255; 3]));
    for (r, row) in rows.iter().enumerate() {
        let (nx, ny) = row.size;
        let scale = row.p.iter().cloned().fold(0.0, f64::max);
        let y = HEADER + r as u32 * (tile + GAP);
        let tiles = std::iter::once(&row.p).chain(&row.q);
        for (c, values) in tiles.enumerate() {
            let x = GAP + c as u32 * (tile + GAP);
            paste(
                &mut image,
                &density_image(values, nx, ny, scale, tile),
                x,
                y,
            );
        }
        label(
            &mut image,
            &row.name,
            ((GAP + 4) as i32, (y + 4) as i32),
            (tile as f64 / 12.0).clamp(10.0, 16.0),
            true,
        )?;
    }
    let names = std::iter::once("target").chain(models.iter().map(String::as_str));
    for (c, name) in names.enumerate() {
        let x = GAP + c as u32 * (tile + GAP);
        label(
            &mut image,
            name,
            (x as i32, 4),
            (tile as f64 / 10.0).clamp(10.0, 18.0),
            false,
        )?;
    }
    Ok(image)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::GridMetrics;

    #[test]
    fn false_colour_runs_from_black_to_pale_yellow() {
        assert_eq!(false_colour(0.0), Rgb([0, 0, 4]));
        assert_eq!(false_colour(1.0), Rgb([252, 255, 164]));
        assert_eq!(false_colour(f64::NAN), Rgb([0, 0, 4]));
        assert_eq!(false_colour(7.0), false_colour(1.0));
    }

    #[test]
    fn figures_encode_as_png() {
        let p = vec![0.0, 1.0, 2.0, 1.0];
        let img = side_by_side(&p, &[1.0; 4], 2, 2, "pq32 L=2").unwrap();
        assert!(png_bytes(&img).unwrap().starts_with(b"\x89PNG"));
        let curve = |k: f64| {
            (0..5)
                .map(|s| CurvePoint {
                    step: s * 10,
                    metrics: GridMetrics {
                        kl: k / (s + 1) as f64,
                        rel_var: 0.0,
                    },
                })
                .collect()
        };
        let img = curves("t", &[("a".into(), curve(1.0)), ("b".into(), curve(2.0))]).unwrap();
        assert!(png_bytes(&img).unwrap().starts_with(b"\x89PNG"));
        let row = MontageRow {
            name: "r".into(),
            size: (2, 2),
            p: p.clone(),
            q: vec![p.clone(), vec![1.0; 4]],
        };
        let img = montage(&["a".into(), "b".into()], &[row], 100).unwrap();
        assert_eq!(img.dimensions().0, 3 * (100 + 6) + 6);
    }
}
