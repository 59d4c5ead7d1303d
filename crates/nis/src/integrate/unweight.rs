//! Unweighted samples: points distributed as |f|/∫|f|, made from a trained sampler's weighted ones
//! by rejection (von Neumann): keep a point with probability min(1, |w|/w_max).
//!
//! The true maximum weight is unknown and, for a flow, set by rare outliers; rejecting against it
//! would waste almost every point. As in event generators, a *robust* maximum is used instead: the
//! smallest w_max whose overweight mass Σ max(0, |w| − w_max) is at most `overweight` of Σ|w| in a
//! calibration batch. Accepted points whose |w| exceeds w_max keep the excess as a weight
//! |w|/w_max > 1, so the sample stays exact as a weighted sample and is unweighted up to that share.

use std::io::Write;
use std::path::Path;

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::nis::NisIntegrator;
use super::Integrand;
use crate::error::{Error, Result};
use crate::flow::Density;
use crate::io::AtomicFile;

/// Unweighted points with their (rare) residual weights.
#[derive(Clone, Debug)]
pub struct Unweighted {
    /// Coordinates per point.
    pub dim: usize,
    /// Row-major points, `n × dim`.
    pub points: Vec<f64>,
    /// Per point: sign(f) · max(1, |w|/w_max) — ±1 except for overweight points.
    pub weights: Vec<f64>,
    /// The robust maximum weight.
    pub w_max: f64,
    /// Accepted / proposed.
    pub efficiency: f64,
    /// Share of Σ|w| above w_max in the calibration batch.
    pub overweight: f64,
}

/// How a draw of unweighted points went (the points themselves went to a sink).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct UnweightStats {
    /// The robust maximum weight.
    pub w_max: f64,
    /// Accepted / proposed.
    pub efficiency: f64,
    /// Share of Σ|w| above w_max in the calibration batch.
    pub overweight: f64,
}

impl NisIntegrator {
    /// Draws `n` unweighted points of the target the flow learned (|f| of a scalar integrand)
    /// from this trained integrator, continuing its unweighting stream. `overweight` is the
    /// tolerated share of weight mass above the robust maximum (e.g. 1e-3).
    pub fn unweighted(
        &mut self,
        f: &dyn Integrand,
        n: usize,
        overweight: f64,
    ) -> Result<Unweighted> {
        let dim = self.flow().dim();
        let (mut points, mut weights) = (Vec::with_capacity(n * dim), Vec::with_capacity(n));
        let stats = self.unweighted_each(f, n, overweight, &mut |p, w| {
            points.extend_from_slice(p);
            weights.push(w);
            Ok(())
        })?;
        Ok(Unweighted {
            dim,
            points,
            weights,
            w_max: stats.w_max,
            efficiency: stats.efficiency,
            overweight: stats.overweight,
        })
    }

    /// The same points as [`NisIntegrator::unweighted`], handed one by one (point, residual
    /// weight) to `sink` as they are accepted, in bounded memory: for writing 10⁸ points to a
    /// file with a [`SampleWriter`]. An error of the sink stops the draw and is returned.
    pub fn unweighted_each(
        &mut self,
        f: &dyn Integrand,
        n: usize,
        overweight: f64,
        sink: &mut dyn FnMut(&[f64], f64) -> Result<()>,
    ) -> Result<UnweightStats> {
        let mut rng = self.take_unweight_rng();
        let u = unweighted_from(self, f, n, overweight, &mut rng, sink);
        self.put_unweight_rng(rng);
        u
    }
}

fn unweighted_from(
    nis: &mut NisIntegrator,
    f: &dyn Integrand,
    n: usize,
    overweight: f64,
    rng: &mut Pcg64Mcg,
    sink: &mut dyn FnMut(&[f64], f64) -> Result<()>,
) -> Result<UnweightStats> {
    if !(0.0..0.5).contains(&overweight) {
        return Err(Error::Config(format!(
            "overweight share must be in [0, 0.5), got {overweight}"
        )));
    }
    let dim = nis.flow().dim();
    let batch = 1 << 16;
    // Calibration: the robust maximum from one batch of weights.
    let (_, w) = nis.target_weights(f, batch, rng)?;
    let mut a: Vec<f64> = w.iter().map(|v| v.abs()).collect();
    a.sort_by(|x, y| y.total_cmp(x));
    let total: f64 = a.iter().sum();
    if total == 0.0 {
        return Err(Error::Config(
            "the integrand was zero at every calibration point: nothing to sample".into(),
        ));
    }
    // Walk down from the largest weight while the mass above the candidate stays within budget.
    let (mut w_max, mut above) = (a[0], 0.0);
    for k in 1..a.len() {
        // Raising the cut to a[k] adds k·(a[k−1] − a[k]) of overweight mass.
        let extra = k as f64 * (a[k - 1] - a[k]);
        if above + extra > overweight * total {
            w_max = a[k - 1] - (overweight * total - above) / k as f64;
            break;
        }
        above += extra;
        w_max = a[k];
    }
    let over = a.iter().map(|v| (v - w_max).max(0.0)).sum::<f64>() / total;
    let (mut accepted, mut proposed) = (0usize, 0usize);
    while accepted < n {
        let (x, w) = nis.target_weights(f, batch, rng)?;
        proposed += w.len();
        for (p, &wi) in x.chunks_exact(dim).zip(&w) {
            if accepted < n && rng.random::<f64>() * w_max < wi.abs() {
                sink(p, wi.signum() * (wi.abs() / w_max).max(1.0))?;
                accepted += 1;
            }
        }
        nis.report(accepted as u64, n as u64, "unweighting");
        if proposed > 1000 * n.max(1000) {
            return Err(Error::Config(format!(
                "unweighting efficiency below 1e-3 ({accepted} of {proposed} accepted): train longer"
            )));
        }
    }
    Ok(UnweightStats {
        w_max,
        efficiency: n as f64 / proposed as f64,
        overweight: over,
    })
}

impl Unweighted {
    /// CSV: a header `x0,…,x{d−1},weight`, one point per line.
    pub fn to_csv(&self) -> String {
        let bytes = self.encode(SampleFormat::Csv);
        String::from_utf8(bytes).expect("CSV is ASCII")
    }

    /// Binary: the magic `NISSMPL1`, dimension (u32 LE), count (u64 LE), then per point its
    /// `dim` coordinates and its weight as f64 LE.
    pub fn to_binary(&self) -> Vec<u8> {
        self.encode(SampleFormat::Binary)
    }

    fn encode(&self, format: SampleFormat) -> Vec<u8> {
        let mut b = Vec::new();
        let n = self.weights.len() as u64;
        format
            .write_header(&mut b, self.dim, n, false)
            .expect("a Vec takes every write");
        for (p, &w) in self.points.chunks_exact(self.dim).zip(&self.weights) {
            format
                .write_point(&mut b, p, w, None)
                .expect("a Vec takes every write");
        }
        b
    }
}

/// The file formats of unweighted points (see [`Unweighted::to_csv`], [`Unweighted::to_binary`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SampleFormat {
    Csv,
    Binary,
}

impl SampleFormat {
    /// CSV for a `.csv` path, the binary format for anything else.
    pub fn for_path(path: &Path) -> SampleFormat {
        if path.extension().is_some_and(|e| e == "csv") {
            SampleFormat::Csv
        } else {
            SampleFormat::Binary
        }
    }

    /// The header of `n` points of dimension `dim`, with a channel column when `channels`.
    fn write_header(
        self,
        out: &mut impl Write,
        dim: usize,
        n: u64,
        channels: bool,
    ) -> std::io::Result<()> {
        match self {
            SampleFormat::Csv => {
                for i in 0..dim {
                    write!(out, "x{i},")?;
                }
                out.write_all(if channels {
                    b"weight,channel\n"
                } else {
                    b"weight\n"
                })
            }
            SampleFormat::Binary => {
                out.write_all(if channels { b"NISSMPL2" } else { b"NISSMPL1" })?;
                out.write_all(&(dim as u32).to_le_bytes())?;
                out.write_all(&n.to_le_bytes())
            }
        }
    }

    /// One point, its weight and, in a file with a channel column, its channel.
    fn write_point(
        self,
        out: &mut impl Write,
        point: &[f64],
        weight: f64,
        channel: Option<usize>,
    ) -> std::io::Result<()> {
        match self {
            SampleFormat::Csv => {
                for v in point {
                    write!(out, "{v:.17e},")?;
                }
                match channel {
                    Some(k) => writeln!(out, "{weight},{k}"),
                    None => writeln!(out, "{weight}"),
                }
            }
            SampleFormat::Binary => {
                for v in point.iter().chain(std::iter::once(&weight)) {
                    out.write_all(&v.to_le_bytes())?;
                }
                match channel {
                    Some(k) => out.write_all(&(k as u64).to_le_bytes()),
                    None => Ok(()),
                }
            }
        }
    }
}

/// Writes `n` unweighted points to a file as they come, atomically: the file appears, complete,
/// only at [`SampleWriter::finish`]; dropped before, it leaves no file and no temporary behind.
///
/// ```
/// use nis::integrate::unweight::{SampleFormat, SampleWriter};
/// let path = std::env::temp_dir().join(format!("nis-doc-samples-{}.csv", std::process::id()));
/// let mut out = SampleWriter::create(&path, SampleFormat::for_path(&path), 2, 1)?;
/// out.push(&[0.25, 0.5], 1.0)?;
/// out.finish()?;
/// assert_eq!(std::fs::read_to_string(&path)?.lines().count(), 2);
/// # std::fs::remove_file(&path)?;
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub struct SampleWriter {
    file: AtomicFile,
    format: SampleFormat,
    dim: usize,
    expected: u64,
    written: u64,
    /// Whether every point carries its channel ([`SampleWriter::create_with_channels`]).
    channels: bool,
}

impl SampleWriter {
    /// Starts a file for `n` points of dimension `dim` (the binary header records `n`).
    pub fn create(path: &Path, format: SampleFormat, dim: usize, n: u64) -> Result<SampleWriter> {
        SampleWriter::start(path, format, dim, n, false)
    }

    /// Starts a file for `n` events of a multi-channel integrator, each with its channel: a
    /// column `channel` in CSV; in binary the magic `NISSMPL2` and, after each point's weight,
    /// its channel as u64 LE.
    pub fn create_with_channels(
        path: &Path,
        format: SampleFormat,
        dim: usize,
        n: u64,
    ) -> Result<SampleWriter> {
        SampleWriter::start(path, format, dim, n, true)
    }

    fn start(
        path: &Path,
        format: SampleFormat,
        dim: usize,
        n: u64,
        channels: bool,
    ) -> Result<SampleWriter> {
        let mut file = AtomicFile::create(path)?;
        format
            .write_header(&mut file, dim, n, channels)
            .map_err(|e| io_error(path, e))?;
        Ok(SampleWriter {
            file,
            format,
            dim,
            expected: n,
            written: 0,
            channels,
        })
    }

    /// Appends one point and its residual weight.
    pub fn push(&mut self, point: &[f64], weight: f64) -> Result<()> {
        self.write(point, weight, None)
    }

    /// Appends one event, its residual weight and its channel.
    pub fn push_event(&mut self, point: &[f64], weight: f64, channel: usize) -> Result<()> {
        self.write(point, weight, Some(channel))
    }

    fn write(&mut self, point: &[f64], weight: f64, channel: Option<usize>) -> Result<()> {
        if channel.is_some() != self.channels {
            return Err(Error::Config(format!(
                "sample file {}: a point {} a channel, the file was made {} a channel column",
                self.file.path().display(),
                if channel.is_some() { "with" } else { "without" },
                if self.channels { "with" } else { "without" },
            )));
        }
        if point.len() != self.dim || self.written == self.expected {
            return Err(Error::Config(format!(
                "sample file for {} points of dimension {}: got point {} of dimension {}",
                self.expected,
                self.dim,
                self.written + 1,
                point.len()
            )));
        }
        self.written += 1;
        let path = self.file.path().to_path_buf();
        self.format
            .write_point(&mut self.file, point, weight, channel)
            .map_err(|e| io_error(&path, e))
    }

    /// Installs the file, once all `n` points are in.
    pub fn finish(self) -> Result<()> {
        if self.written != self.expected {
            return Err(Error::Config(format!(
                "sample file for {} points: only {} were written",
                self.expected, self.written
            )));
        }
        self.file.commit()
    }
}

fn io_error(path: &Path, source: std::io::Error) -> Error {
    Error::Io {
        path: path.to_path_buf(),
        source,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrate::nis::NisConfig;
    use crate::integrate::Integrator;

    #[test]
    fn unweighted_points_follow_the_integrand() {
        // f(x) = 2x₀ on [0,1]²: the x₀-marginal of unweighted points has mean 2/3, variance 1/18.
        let f = |x: &[f64]| 2.0 * x[0];
        let config = NisConfig::builder().batch(1024).build().unwrap();
        let mut nis = NisIntegrator::new(2, NisConfig { seed: 1, ..config }).unwrap();
        nis.integrate(&f, 100_000).unwrap();
        nis.set_seed(2);
        let n = 20_000;
        let u = nis.unweighted(&f, n, 1e-3).unwrap();
        assert_eq!(u.weights.len(), n);
        assert!(u.overweight <= 1.001e-3 && u.efficiency > 0.1);
        let mean = u.points.chunks(2).map(|p| p[0]).sum::<f64>() / n as f64;
        // 5σ with σ = √(1/18)/√n.
        assert!(
            (mean - 2.0 / 3.0).abs() < 5.0 * (1.0f64 / 18.0 / n as f64).sqrt(),
            "mean {mean}"
        );
        let csv = u.to_csv();
        assert!(csv.starts_with("x0,x1,weight\n") && csv.lines().count() == n + 1);
        let bin = u.to_binary();
        assert_eq!(bin.len(), 8 + 4 + 8 + n * 3 * 8);
        assert!(nis.unweighted(&f, 10, 0.7).is_err());
    }

    #[test]
    fn streamed_sample_files_equal_the_collected_ones() {
        let f = |x: &[f64]| 1.0 + x[0] * x[1];
        let config = NisConfig::builder().batch(1024).seed(3).build().unwrap();
        let mut a = NisIntegrator::new(2, config.clone()).unwrap();
        a.integrate(&f, 20_000).unwrap();
        let mut b = NisIntegrator::new(2, config).unwrap();
        b.integrate(&f, 20_000).unwrap();
        let n = 3000;
        let u = a.unweighted(&f, n, 1e-3).unwrap();
        let dir = std::env::temp_dir().join(format!("nis-unweight-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for (name, expected) in [("s.csv", u.to_csv().into_bytes()), ("s.bin", u.to_binary())] {
            let path = dir.join(name);
            let mut out =
                SampleWriter::create(&path, SampleFormat::for_path(&path), 2, n as u64).unwrap();
            let stats = b
                .unweighted_each(&f, n, 1e-3, &mut |p, w| out.push(p, w))
                .unwrap();
            out.finish().unwrap();
            assert_eq!(stats.w_max, u.w_max);
            assert_eq!(std::fs::read(&path).unwrap(), expected, "{name}");
            b.set_seed(3);
        }
        // A writer given the wrong number of points installs nothing.
        let path = dir.join("short.csv");
        let mut out = SampleWriter::create(&path, SampleFormat::Csv, 2, 2).unwrap();
        out.push(&[0.5, 0.5], 1.0).unwrap();
        assert!(out.push(&[0.5], 1.0).is_err());
        assert!(out.finish().is_err());
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 2);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn event_files_carry_a_channel_column() {
        let dir = std::env::temp_dir().join(format!("nis-events-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (csv, bin) = (dir.join("e.csv"), dir.join("e.bin"));
        for path in [&csv, &bin] {
            let format = SampleFormat::for_path(path);
            let mut out = SampleWriter::create_with_channels(path, format, 2, 2).unwrap();
            out.push_event(&[0.25, 0.5], 1.0, 7).unwrap();
            // A point without its channel in a file with the column: an error.
            assert!(out.push(&[0.25, 0.5], 1.0).is_err());
            out.push_event(&[0.75, 0.5], -1.0, 0).unwrap();
            out.finish().unwrap();
        }
        let text = std::fs::read_to_string(&csv).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines[0], "x0,x1,weight,channel");
        assert!(
            lines[1].ends_with(",1,7") && lines[2].ends_with(",-1,0"),
            "{text}"
        );
        let b = std::fs::read(&bin).unwrap();
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        let f64_at = |i: usize| f64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        assert_eq!(&b[..8], b"NISSMPL2");
        assert_eq!(b.len(), 20 + 2 * 8 * (2 + 1 + 1));
        assert_eq!(
            (f64_at(20), f64_at(28), f64_at(36), u64_at(44)),
            (0.25, 0.5, 1.0, 7)
        );
        // A plain file refuses a channel.
        let mut plain = SampleWriter::create(&dir.join("p.csv"), SampleFormat::Csv, 2, 1).unwrap();
        assert!(plain.push_event(&[0.5, 0.5], 1.0, 1).is_err());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
