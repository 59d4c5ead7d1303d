//! The figure of one cell: relative error against wall time of every run, log-log, a colour per
//! method and a line per seed, honest runs as circles and confidently wrong ones as crosses, the
//! targets as dashed lines.

use plotters::prelude::*;

use super::{CellResult, Contender};
use crate::error::Result;
use crate::image::figure::{canvas, draw_legend, figure_error, has_font, png_bytes};

/// Each contender's colour, the same in every plot.
fn colour(contender: Contender) -> RGBColor {
    match contender {
        Contender::Nis => RGBColor(31, 119, 180),
        Contender::Vegas => RGBColor(255, 127, 14),
        Contender::Uniform => RGBColor(127, 127, 127),
        Contender::VegasPackage => RGBColor(44, 160, 44),
        Contender::NisCodes => RGBColor(148, 103, 189),
        Contender::NisTarget => RGBColor(23, 190, 207),
        Contender::VegasTarget => RGBColor(214, 39, 40),
    }
}

/// The PNG bytes of the cell's plot.
pub fn png(cell: &CellResult, targets: &[f64]) -> Result<Vec<u8>> {
    const W: u32 = 800;
    const H: u32 = 520;
    let runs = || cell.ladders.iter().flat_map(|l| l.runs.iter());
    let finite = |v: f64| v.is_finite() && v > 0.0;
    let xs = || runs().map(|r| r.seconds).filter(|v| finite(*v));
    let ys = || {
        runs()
            .map(|r| r.rel_err())
            .chain(targets.iter().copied())
            .filter(|v| finite(*v))
    };
    let (x0, x1) = (xs().fold(f64::INFINITY, f64::min), xs().fold(0.0, f64::max));
    let (y0, y1) = (ys().fold(f64::INFINITY, f64::min), ys().fold(0.0, f64::max));
    let (x0, x1) = if x0 < x1 {
        (x0 / 1.5, x1 * 1.5)
    } else {
        (1e-3, 1.0)
    };
    let (y0, y1) = if y0 < y1 {
        (y0 / 1.5, y1 * 1.5)
    } else {
        (1e-5, 1.0)
    };
    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let root = canvas(&mut buffer, (W, H), None)?;
        let mut builder = ChartBuilder::on(&root);
        builder.margin(14);
        if has_font() {
            builder
                .caption(
                    format!(
                        "{} d={}: relative error against wall time",
                        cell.name, cell.dim
                    ),
                    ("sans-serif", 18),
                )
                .x_label_area_size(40)
                .y_label_area_size(64);
        }
        let mut chart = builder
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(figure_error)?;
        let mut mesh = chart.configure_mesh();
        if has_font() {
            mesh.x_desc("wall time of the run (s)")
                .y_desc("std_err / |value|")
                .x_label_formatter(&|v| format!("{v:.0e}"))
                .y_label_formatter(&|v| format!("{v:.0e}"));
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(figure_error)?;
        for &t in targets {
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, t), (x1, t)],
                    6,
                    4,
                    BLACK.mix(0.6).stroke_width(1),
                ))
                .map_err(figure_error)?;
        }
        for contender in Contender::ALL.iter() {
            let colour = colour(*contender);
            let mut labelled = false;
            for l in cell.ladders.iter().filter(|l| l.contender == *contender) {
                let points: Vec<(f64, f64, bool)> = l
                    .runs
                    .iter()
                    .filter(|r| finite(r.seconds) && finite(r.rel_err()))
                    .map(|r| (r.seconds, r.rel_err(), r.honest(cell.exact)))
                    .collect();
                let line = chart
                    .draw_series(LineSeries::new(
                        points.iter().map(|p| (p.0, p.1)),
                        colour.stroke_width(2),
                    ))
                    .map_err(figure_error)?;
                if has_font() && !labelled {
                    labelled = true;
                    line.label(contender.name()).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
                    });
                }
                chart
                    .draw_series(points.iter().map(|&(x, y, honest)| {
                        if honest {
                            Circle::new((x, y), 4, colour.filled()).into_dyn()
                        } else {
                            Cross::new((x, y), 6, colour.stroke_width(2)).into_dyn()
                        }
                    }))
                    .map_err(figure_error)?;
            }
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight, 14)?;
        root.present().map_err(figure_error)?;
    }
    let image =
        image::RgbImage::from_raw(W, H, buffer).ok_or_else(|| figure_error("plot buffer size"))?;
    png_bytes(&image)
}
