//! Mitsuba 3's sun-and-sky tables, read from its tensor files: `sunsky_datasets.bin` (the
//! Hosek–Wilkie sky coefficients and mean radiances, the sun's limb-darkened radiance
//! polynomials) and `sampling_data.bin` (the sun's spectral irradiance), both from the
//! mitsuba-data repository (BSD-3-Clause), which `scripts/scenes/fetch-public-scenes.sh` clones.
//!
//! A tensor file is the 12 bytes `tensor_file\0`, a two-byte version, a u32 count of fields,
//! then per field its name (u16 length and bytes), its rank (u16), its element type (u8: 10 is
//! f32, 11 is f64), the offset of its data from the start of the file (u64) and its shape (a u64
//! per axis); all little-endian (Mitsuba 3, `src/core/tensor.cpp`). Only the RGB tables are kept.

use std::path::{Path, PathBuf};

use crate::Error;

/// The environment variable that names the tables' folder (or `sunsky_datasets.bin` itself).
pub const ENV_VAR: &str = "NIS_SUNSKY_DATA";
/// The file of the sky and sun models.
pub const DATASETS_FILE: &str = "sunsky_datasets.bin";
/// The file of the irradiance tables, beside [`DATASETS_FILE`].
pub const SAMPLING_FILE: &str = "sampling_data.bin";
/// Where `scripts/scenes/fetch-public-scenes.sh` puts the tables, from the repository root.
pub const FETCHED_DIR: &str = "data/scenes/mitsuba-data/sunsky/output";

/// Turbidity levels of the tables (1 to 10).
pub const TURBIDITIES: usize = 10;
/// Albedo levels of the sky tables (0 and 1).
pub const ALBEDOS: usize = 2;
/// Bézier control points of the sky tables over the sun's elevation.
pub const SKY_CONTROL_POINTS: usize = 6;
/// Coefficients of the Hosek–Wilkie sky formula per channel.
pub const SKY_PARAMS: usize = 9;
/// Segments of the sun's piecewise polynomial over the elevation.
pub const SUN_SEGMENTS: usize = 45;
/// Powers of the elevation offset in each segment's polynomial.
pub const SUN_CONTROL_POINTS: usize = 4;
/// Powers of the limb's cosine in each segment's polynomial.
pub const SUN_LIMB_PARAMS: usize = 6;
/// Sun elevations of the irradiance tables (2° to 89°, every 3°).
pub const IRRADIANCE_ELEVATIONS: usize = 30;
/// Wavelengths of the spectral tables: 320, 360, …, 720 nm.
pub const WAVELENGTHS: usize = 11;

/// The tables the RGB sun and sky need, as read (f64), with their shapes checked.
#[derive(Clone, Debug)]
pub struct Dataset {
    /// Sky coefficients, shape (turbidity, albedo, control point, channel, parameter).
    pub sky_params: Vec<f64>,
    /// Sky mean radiances, shape (turbidity, albedo, control point, channel).
    pub sky_radiance: Vec<f64>,
    /// Sun radiance with its limb darkening, shape (turbidity, segment, channel, elevation
    /// power, limb power).
    pub sun_radiance: Vec<f64>,
    /// The sun's spectral irradiance, shape (turbidity, elevation, wavelength).
    pub sun_irradiance: Vec<f64>,
    /// The folder the tables were read from.
    pub dir: PathBuf,
}

impl Dataset {
    /// Find the tables and read them: in the folder (or beside the file) that
    /// [`ENV_VAR`] names when it is set, else beside the scene (`scene_dirs`, each also with
    /// `data/sunsky/` as Mitsuba looks), else in [`FETCHED_DIR`] from the current directory
    /// and from this repository's root.
    pub fn find(scene_dirs: &[PathBuf]) -> Result<Dataset, Error> {
        let candidates = candidate_dirs(scene_dirs);
        for dir in &candidates {
            if dir.join(DATASETS_FILE).is_file() {
                return Dataset::load(dir);
            }
        }
        Err(Error::MissingSunskyData {
            searched: candidates
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", "),
        })
    }

    /// Read the two table files from `dir`.
    pub fn load(dir: &Path) -> Result<Dataset, Error> {
        let datasets = TensorFile::read(&dir.join(DATASETS_FILE))?;
        let sampling = TensorFile::read(&dir.join(SAMPLING_FILE))?;
        Ok(Dataset {
            sky_params: datasets.field(
                "sky_params_rgb",
                &[TURBIDITIES, ALBEDOS, SKY_CONTROL_POINTS, 3, SKY_PARAMS],
            )?,
            sky_radiance: datasets.field(
                "sky_rad_rgb",
                &[TURBIDITIES, ALBEDOS, SKY_CONTROL_POINTS, 3],
            )?,
            sun_radiance: datasets.field(
                "sun_rad_rgb",
                &[
                    TURBIDITIES,
                    SUN_SEGMENTS,
                    3,
                    SUN_CONTROL_POINTS,
                    SUN_LIMB_PARAMS,
                ],
            )?,
            sun_irradiance: sampling.field(
                "sun_irradiance",
                &[TURBIDITIES, IRRADIANCE_ELEVATIONS, WAVELENGTHS],
            )?,
            dir: dir.to_path_buf(),
        })
    }
}

/// The folders [`Dataset::find`] looks in, in order.
fn candidate_dirs(scene_dirs: &[PathBuf]) -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(v) = std::env::var_os(ENV_VAR).filter(|v| !v.is_empty()) {
        let p = PathBuf::from(v);
        // The file itself, or its folder.
        if p.file_name().is_some_and(|n| n == DATASETS_FILE) {
            dirs.push(p.parent().map(Path::to_path_buf).unwrap_or_default());
        } else {
            dirs.push(p);
        }
        return dirs;
    }
    for d in scene_dirs {
        dirs.push(d.clone());
        dirs.push(d.join("data/sunsky"));
    }
    dirs.push(PathBuf::from(FETCHED_DIR));
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    dirs.push(root.join(FETCHED_DIR));
    dirs
}

/// One field of a tensor file: its type, shape and where its data lies.
struct FieldInfo {
    name: String,
    float64: bool,
    shape: Vec<u64>,
    offset: u64,
}

/// A tensor file read whole, with its table of fields.
struct TensorFile {
    path: PathBuf,
    bytes: Vec<u8>,
    fields: Vec<FieldInfo>,
}

/// A little-endian reader over a byte slice that fails past its end.
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let end = self.pos.checked_add(n)?;
        let s = self.bytes.get(self.pos..end)?;
        self.pos = end;
        Some(s)
    }
    fn u8(&mut self) -> Option<u8> {
        self.take(1).map(|b| b[0])
    }
    fn u16(&mut self) -> Option<u16> {
        self.take(2).map(|b| u16::from_le_bytes([b[0], b[1]]))
    }
    fn u32(&mut self) -> Option<u32> {
        self.take(4)
            .map(|b| u32::from_le_bytes(b.try_into().expect("4 bytes")))
    }
    fn u64(&mut self) -> Option<u64> {
        self.take(8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
    }
}

impl TensorFile {
    fn read(path: &Path) -> Result<TensorFile, Error> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.display().to_string(),
            source,
        })?;
        let fields =
            parse_header(&bytes).ok_or_else(|| bad(path, "not a tensor file, or truncated"))?;
        Ok(TensorFile {
            path: path.to_path_buf(),
            bytes,
            fields,
        })
    }

    /// The values of field `name`, which must have `shape`, as f64.
    fn field(&self, name: &str, shape: &[usize]) -> Result<Vec<f64>, Error> {
        let f = self
            .fields
            .iter()
            .find(|f| f.name == name)
            .ok_or_else(|| bad(&self.path, &format!("no field '{name}'")))?;
        let want: Vec<u64> = shape.iter().map(|&s| s as u64).collect();
        if f.shape != want {
            return Err(bad(
                &self.path,
                &format!("field '{name}' has shape {:?}, expected {want:?}", f.shape),
            ));
        }
        let count: usize = shape.iter().product();
        let size = if f.float64 { 8 } else { 4 };
        let start = usize::try_from(f.offset).unwrap_or(usize::MAX);
        let data = start
            .checked_add(count * size)
            .and_then(|end| self.bytes.get(start..end))
            .ok_or_else(|| {
                bad(
                    &self.path,
                    &format!("field '{name}' runs past the file's end"),
                )
            })?;
        let values: Vec<f64> = if f.float64 {
            data.chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
                .collect()
        } else {
            data.chunks_exact(4)
                .map(|c| f64::from(f32::from_le_bytes(c.try_into().expect("4 bytes"))))
                .collect()
        };
        if values.iter().any(|v| !v.is_finite()) {
            return Err(bad(
                &self.path,
                &format!("field '{name}' holds a non-finite value"),
            ));
        }
        Ok(values)
    }
}

fn bad(path: &Path, message: &str) -> Error {
    Error::SunskyData {
        path: path.display().to_string(),
        message: message.to_string(),
    }
}

/// The fields of a tensor file's header; `None` when it is not one or is truncated.
fn parse_header(bytes: &[u8]) -> Option<Vec<FieldInfo>> {
    let mut c = Cursor { bytes, pos: 0 };
    if c.take(12)? != b"tensor_file\0" {
        return None;
    }
    let _version = c.take(2)?;
    let n = c.u32()?;
    let mut fields = Vec::new();
    for _ in 0..n {
        let len = c.u16()? as usize;
        let name = String::from_utf8(c.take(len)?.to_vec()).ok()?;
        let ndim = c.u16()?;
        let dtype = c.u8()?;
        let offset = c.u64()?;
        let shape = (0..ndim).map(|_| c.u64()).collect::<Option<Vec<u64>>>()?;
        let float64 = match dtype {
            10 => false,
            11 => true,
            // Other element types are not among the tables read here.
            _ => continue,
        };
        fields.push(FieldInfo {
            name,
            float64,
            shape,
            offset,
        });
    }
    Some(fields)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A tensor file of one f32 field, written as Mitsuba's `tensor_io.write` does.
    fn file(name: &str, shape: &[u64], values: &[f32], dtype: u8) -> Vec<u8> {
        let mut b = b"tensor_file\0".to_vec();
        b.extend([1, 0]);
        b.extend(1u32.to_le_bytes());
        b.extend((name.len() as u16).to_le_bytes());
        b.extend(name.as_bytes());
        b.extend((shape.len() as u16).to_le_bytes());
        b.push(dtype);
        let offset = b.len() as u64 + 8 + 8 * shape.len() as u64;
        b.extend(offset.to_le_bytes());
        for s in shape {
            b.extend(s.to_le_bytes());
        }
        for v in values {
            b.extend(v.to_le_bytes());
        }
        b
    }

    #[test]
    fn a_tensor_file_is_read_and_a_bad_one_is_an_error() {
        let dir = std::env::temp_dir().join(format!("nis-tensor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("t.bin");
        std::fs::write(
            &path,
            file("w", &[2, 3], &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], 10),
        )
        .unwrap();
        let t = TensorFile::read(&path).unwrap();
        assert_eq!(
            t.field("w", &[2, 3]).unwrap(),
            vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
        );
        assert!(t.field("w", &[3, 2]).is_err());
        assert!(t.field("v", &[2, 3]).is_err());
        // Truncated data, a truncated header, and another file.
        let mut short = file("w", &[2, 3], &[1.0; 6], 10);
        short.truncate(short.len() - 4);
        std::fs::write(&path, &short).unwrap();
        let e = TensorFile::read(&path)
            .unwrap()
            .field("w", &[2, 3])
            .unwrap_err();
        assert!(e.to_string().contains("past the file's end"), "{e}");
        for bytes in [&short[..20], b"not a tensor file at all".as_slice()] {
            std::fs::write(&path, bytes).unwrap();
            assert!(matches!(
                TensorFile::read(&path),
                Err(Error::SunskyData { .. })
            ));
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn missing_tables_name_the_fetch_script() {
        let dir = std::env::temp_dir().join(format!("nis-no-sunsky-{}", std::process::id()));
        let e = Dataset::load(&dir).unwrap_err();
        assert!(matches!(e, Error::Io { .. }), "{e}");
        let e = Error::MissingSunskyData {
            searched: dir.display().to_string(),
        };
        assert!(e
            .to_string()
            .contains("scripts/scenes/fetch-public-scenes.sh"));
    }
}
