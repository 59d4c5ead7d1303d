//! Where in the image an error is: each image's MAPE (the metric of `nis compare`) split over a
//! grid of regions, as the share of the whole image's error each region holds, and the MAPE
//! over the pixels whose reference is in each quartile of brightness.
//!
//! ```text
//! cargo run --release -p nis-render --example error_regions -- REFERENCE.exr A.exr B.exr …
//! ```

use nis_render::compare::METRIC_EPSILON;
use nis_render::film::Image;

const GRID: u32 = 4;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    let Some((reference, images)) = paths.split_first() else {
        return Err("usage: error_regions REFERENCE.exr IMAGE.exr …".into());
    };
    let reference = Image::read_exr(reference.as_ref())?;
    let (w, h) = (reference.width, reference.height);
    let value = |img: &Image, x, y| {
        let p = img.get(x, y);
        f64::from(p.x + p.y + p.z) / 3.0
    };
    let mut brightness: Vec<f64> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| value(&reference, x, y))
        .collect();
    brightness.sort_by(f64::total_cmp);
    let quartile = |b: f64| brightness.partition_point(|&v| v < b) * 4 / brightness.len();
    for path in images {
        let image = Image::read_exr(path.as_ref())?;
        let mut cells = vec![0.0f64; (GRID * GRID) as usize];
        let (mut by_quartile, mut counts) = ([0.0f64; 4], [0usize; 4]);
        for y in 0..h {
            for x in 0..w {
                let b = value(&reference, x, y);
                let (pa, pb) = (image.get(x, y), reference.get(x, y));
                let e = (0..3)
                    .map(|c| {
                        let (a, r) = (f64::from(pa[c]), f64::from(pb[c]));
                        (a - r).abs() / (r.abs() + METRIC_EPSILON)
                    })
                    .sum::<f64>()
                    / 3.0;
                cells[((y * GRID / h) * GRID + x * GRID / w) as usize] += e;
                let q = quartile(b).min(3);
                by_quartile[q] += e;
                counts[q] += 1;
            }
        }
        let total: f64 = cells.iter().sum();
        println!("{path}: MAPE {:.4}", total / f64::from(w * h));
        for row in cells.chunks(GRID as usize) {
            let shares: Vec<String> = row
                .iter()
                .map(|c| format!("{:5.1}%", 100.0 * c / total))
                .collect();
            println!("  {}", shares.join(" "));
        }
        let q: Vec<String> = by_quartile
            .iter()
            .zip(counts)
            .map(|(e, n)| format!("{:.3}", e / n.max(1) as f64))
            .collect();
        println!(
            "  MAPE by reference brightness quartile (dark to bright): {}",
            q.join(" ")
        );
    }
    Ok(())
}
