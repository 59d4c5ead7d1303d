//! Fuzzing the experiments' readers of outside data (issue 16): the digits CSV (plain and
//! gzipped), MNIST IDX (with forged dimensions), MNIST JSON, PNG/JPEG image targets (with
//! decompression bombs) and density checkpoints (truncated, flipped, forged). Each must give a
//! typed error or a valid value within the limits of `nis-fuzz-support`. `NIS_FUZZ_CASES=N` sets
//! the cases per target.

use nis_fuzz_support as fuzz;

use std::io::Write;
use std::path::Path;

use fuzz::{check, mutated, Counting};
use nis::transform::TransformKind;
use nis_paper::data::{read_digits_csv, read_idx_images, read_mnist_json, Dataset, Images};
use nis_paper::density::{Arch, DensityConfig, Session};
use nis_paper::image::Target;
use proptest::prelude::*;

#[global_allocator]
static ALLOC: Counting = Counting;

fn gzip(bytes: &[u8]) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
    gz.write_all(bytes).expect("in memory");
    gz.finish().expect("in memory")
}

fn images_len(images: &Images) -> usize {
    images.pixels.len()
}

/// An accepted image set is consistent: whole images, values below the level count.
fn assert_valid(images: &Images) -> Result<(), TestCaseError> {
    prop_assert!(images.width * images.height > 0);
    prop_assert!(!images.pixels.is_empty());
    prop_assert_eq!(images.pixels.len() % (images.width * images.height), 0);
    prop_assert!(images.pixels.iter().all(|&p| (p as usize) < images.levels));
    Ok(())
}

/// Three lines of a valid digits CSV.
fn digits_csv() -> Vec<u8> {
    let mut s = String::new();
    for label in 0..3 {
        let pixels: Vec<String> = (0..64)
            .map(|i| ((i * 7 + label) % 17).to_string())
            .collect();
        s += &format!("{},{label}\n", pixels.join(","));
    }
    s.into_bytes()
}

#[test]
fn digits_csv_plain_and_gzipped() {
    let dir = fuzz::scratch("digits");
    let path = dir.join("digits.csv.gz");
    let csv = digits_csv();
    let cell = prop_oneof![
        Just("16.0".to_string()),
        Just("17".to_string()),
        Just("-0".to_string()),
        Just("NaN".to_string()),
        Just("inf".to_string()),
        Just("1e300".to_string()),
        Just("3.5".to_string()),
        Just("".to_string()),
        "[0-9]{1,25}",
    ];
    let strategy = prop_oneof![
        // Byte edits of the text, stored plain or gzipped.
        (mutated(csv.clone(), 6), any::<bool>()).prop_map(|(b, gz)| if gz { gzip(&b) } else { b }),
        // Byte edits of the gzip stream itself.
        mutated(gzip(&csv), 4),
        // One cell replaced by an absurd value.
        (0usize..195, cell).prop_map({
            let csv = csv.clone();
            move |(k, v)| {
                let text = String::from_utf8(csv.clone()).expect("text");
                let mut cells: Vec<String> = text
                    .lines()
                    .flat_map(|l| l.split(',').map(String::from).collect::<Vec<_>>())
                    .collect();
                cells[k] = v;
                cells
                    .chunks(65)
                    .map(|c| c.join(","))
                    .collect::<Vec<_>>()
                    .join("\n")
                    .into_bytes()
            }
        }),
    ];
    fuzz::fuzz("digits-csv", 300, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let r = check(tally, bytes.len(), || read_digits_csv(&path), images_len)?;
        if let Ok(images) = r {
            assert_valid(&images)?;
            prop_assert_eq!(images.levels, 17);
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

fn idx(n: u32, rows: u32, cols: u32, body: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    for x in [0x0803u32, n, rows, cols] {
        v.extend_from_slice(&x.to_be_bytes());
    }
    v.extend_from_slice(body);
    v
}

#[test]
fn mnist_idx_mutated_and_forged() {
    let dir = fuzz::scratch("idx");
    let path = dir.join("train-images-idx3-ubyte");
    let valid = idx(
        3,
        4,
        5,
        &(0..60).map(|i| (i * 13) as u8).collect::<Vec<_>>(),
    );
    let dimension = prop_oneof![
        Just(0u32),
        Just(1),
        Just(4096),
        Just(4097),
        Just(60000),
        Just(1 << 31),
        Just(u32::MAX),
        0u32..8
    ];
    let strategy = prop_oneof![
        (mutated(valid.clone(), 4), any::<bool>()).prop_map(|(b, gz)| if gz {
            gzip(&b)
        } else {
            b
        }),
        // Forged dimensions claiming huge images over a small body.
        (
            dimension.clone(),
            dimension.clone(),
            dimension,
            prop::collection::vec(any::<u8>(), 0..256),
            any::<bool>()
        )
            .prop_map(|(n, r, c, body, gz)| {
                let v = idx(n, r, c, &body);
                if gz {
                    gzip(&v)
                } else {
                    v
                }
            }),
    ];
    fuzz::fuzz("mnist-idx", 300, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let r = check(tally, bytes.len(), || read_idx_images(&path), images_len)?;
        if let Ok(images) = r {
            assert_valid(&images)?;
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn mnist_json_mutated() {
    let dir = fuzz::scratch("mnist-json");
    let image: Vec<String> = (0..784)
        .map(|i| format!("{:.3}", (i % 256) as f64 / 255.0))
        .collect();
    let valid = format!("{{\"data\": [{}]}}", image.join(",")).into_bytes();
    for class in 1..10 {
        std::fs::write(dir.join(format!("{class}.json")), &valid).expect("a scratch file");
    }
    let value = prop_oneof![
        Just("-0.0".to_string()),
        Just("1.0000001".to_string()),
        Just("1e400".to_string()),
        Just("null".to_string()),
        Just("\"0.5\"".to_string()),
        Just("[]".to_string()),
    ];
    let strategy = prop_oneof![
        mutated(valid.clone(), 6),
        (0usize..784, value).prop_map(|(k, v)| {
            let mut cells = image.clone();
            cells[k] = v;
            format!("{{\"data\": [{}]}}", cells.join(",")).into_bytes()
        }),
        prop::collection::vec(any::<u8>(), 0..128),
    ];
    fuzz::fuzz("mnist-json", 200, strategy, |tally, bytes| {
        std::fs::write(dir.join("0.json"), &bytes).expect("a scratch file");
        let r = check(
            tally,
            bytes.len() + 9 * valid.len(),
            || read_mnist_json(&dir),
            images_len,
        )?;
        if let Ok(images) = r {
            assert_valid(&images)?;
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

fn encoded(format: image::ImageFormat, w: u32, h: u32) -> Vec<u8> {
    let img = image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 9) as u8, (y * 7) as u8, 90]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, format).expect("encodes");
    out.into_inner()
}

/// A PNG that declares `w`×`h` grey pixels (with a correct header checksum) over `idat`.
fn png_claiming(w: u32, h: u32, idat: &[u8]) -> Vec<u8> {
    let chunk = |kind: &[u8], data: &[u8]| {
        let mut c = (data.len() as u32).to_be_bytes().to_vec();
        c.extend_from_slice(kind);
        c.extend_from_slice(data);
        let mut crc = flate2::Crc::new();
        crc.update(kind);
        crc.update(data);
        c.extend_from_slice(&crc.sum().to_be_bytes());
        c
    };
    let mut ihdr = w.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&h.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit grey, deflate, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    png.extend(chunk(b"IDAT", idat));
    png.extend(chunk(b"IEND", &[]));
    png
}

/// A zlib stream of `n` zero bytes (scanlines of a black image with filter 0).
fn zlib_zeros(n: usize) -> Vec<u8> {
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::best());
    let block = vec![0u8; 1 << 16];
    let mut left = n;
    while left > 0 {
        let k = left.min(block.len());
        z.write_all(&block[..k]).expect("in memory");
        left -= k;
    }
    z.finish().expect("in memory")
}

#[test]
fn image_targets_mutated_and_bombs() {
    let dir = fuzz::scratch("targets");
    let path = dir.join("target.img");
    let png = encoded(image::ImageFormat::Png, 12, 9);
    let jpeg = encoded(image::ImageFormat::Jpeg, 16, 8);
    // A real bomb: 3000×3000 black pixels (9 MB) in a few kB, beside forged headers.
    let bomb = png_claiming(3000, 3000, &zlib_zeros(3001 * 3000));
    let side = prop_oneof![
        Just(0u32),
        Just(1),
        Just(2048),
        Just(2049),
        Just(100_000),
        Just(1 << 31),
        Just(u32::MAX)
    ];
    let strategy = prop_oneof![
        3 => mutated(png, 4),
        3 => mutated(jpeg, 4),
        1 => (side.clone(), side, prop::collection::vec(any::<u8>(), 0..64))
            .prop_map(|(w, h, idat)| png_claiming(w, h, &idat)),
        1 => Just(bomb),
    ];
    fuzz::fuzz("image-target", 300, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let r = check(
            tally,
            bytes.len(),
            || Target::from_path(&path),
            // What the image decodes to: 8-bit RGB pixels.
            |t| 3 * t.width() * t.height(),
        )?;
        if let Ok(t) = r {
            prop_assert!(t.width() * t.height() <= nis_paper::image::target::MAX_PIXELS as usize);
            prop_assert!(t.value(0.5, 0.5).is_finite());
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

fn small_checkpoint(path: &Path) -> Vec<u8> {
    let mut config = DensityConfig::defaults(
        Dataset::Digits,
        Arch::Mlp,
        TransformKind::Quadratic { bins: 4 },
    );
    config.model.hidden_width = 4;
    config.model.couplings = 2;
    let session = Session::new(config).expect("a session");
    session.save(path).expect("saved");
    std::fs::read(path).expect("the checkpoint")
}

#[test]
fn density_checkpoints_truncated_flipped_and_forged() {
    let dir = fuzz::scratch("checkpoint");
    let path = dir.join("case.safetensors");
    let original = small_checkpoint(&dir.join("seed.safetensors"));
    let meta_end = 8 + u64::from_le_bytes(original[..8].try_into().expect("8 bytes")) as usize;
    let header = String::from_utf8(original[8..meta_end].to_vec()).expect("a JSON header");
    let numbers = prop::sample::select(vec![
        "0",
        "1",
        "65536",
        "1000000",
        "4294967296",
        "18446744073709551615",
    ]);
    let strategy = prop_oneof![
        3 => mutated(original.clone(), 4),
        1 => (0..original.len()).prop_map({
            let o = original.clone();
            move |n| o[..n].to_vec()
        }),
        // The model config in the header claims other (huge) sizes: the header is edited as
        // text, and its length prefix fixed up.
        2 => (prop::sample::select(vec!["hidden_width", "width", "height", "couplings", "features", "blocks", "hidden_layers", "batch"]), numbers)
            .prop_map({
                let header = header.clone();
                let body = original[meta_end..].to_vec();
                move |(key, n)| {
                    let pattern = format!("\\\"{key}\\\":");
                    let edited = match header.find(&pattern) {
                        Some(at) => {
                            let start = at + pattern.len();
                            let end = start + header[start..].find([',', '}']).unwrap_or(0);
                            format!("{}{n}{}", &header[..start], &header[end..])
                        }
                        None => header.clone(),
                    };
                    let mut v = (edited.len() as u64).to_le_bytes().to_vec();
                    v.extend_from_slice(edited.as_bytes());
                    v.extend_from_slice(&body);
                    v
                }
            }),
    ];
    fuzz::fuzz("density-checkpoint", 300, strategy, |tally, bytes| {
        std::fs::write(&path, &bytes).expect("a scratch file");
        let r = check(tally, bytes.len(), || Session::load(&path), |_| 0)?;
        if let Ok(session) = r {
            prop_assert!(3 * 4 * session.model().param_count() <= bytes.len());
        }
        Ok(())
    });
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_png_bomb_is_refused_before_decoding() {
    // Regression: the target loader decoded whatever size the header claimed (the image
    // crate's default limit is 512 MiB).
    let dir = fuzz::scratch("bomb");
    let path = dir.join("bomb.png");
    std::fs::write(&path, png_claiming(100_000, 100_000, &zlib_zeros(1 << 16))).expect("written");
    let e = Target::from_path(&path).unwrap_err().to_string();
    assert!(e.contains("exceeds limit"), "{e}"); // the decoder's own limit on a side
    std::fs::write(&path, png_claiming(5000, 5000, &zlib_zeros(1 << 16))).expect("written");
    let e = Target::from_path(&path).unwrap_err().to_string();
    assert!(e.contains("5000×5000 pixels is more than"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}
