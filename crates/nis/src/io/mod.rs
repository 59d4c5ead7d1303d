//! Saving and loading flows, and atomic file writes.
//!
//! A model is one safetensors file: every conditioner layer's weights and biases as f32 tensors
//! (`coupling{l}.layer{j}.weight` of shape `[in, out]`, `coupling{l}.layer{j}.bias` of `[out]`),
//! and in the header's metadata the [`FlowConfig`] as JSON, a format tag and an FNV-1a checksum of
//! the weights, so a truncated, corrupted or mismatched file is an error, never a wrong flow.
//! Callers may store their own metadata beside it (the integrator keeps its settings there).
//!
//! Every file the project writes goes through [`atomic`]: a temporary file beside the target,
//! renamed over it once complete.

use std::collections::HashMap;
use std::fs;
use std::path::{Path, PathBuf};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

use crate::error::{Error, Result};
use crate::flow::{Density, Flow, FlowConfig};

pub mod atomic;
pub use atomic::{remove_stale_temps, write_atomic, AtomicFile};

const FORMAT: &str = "nis-flow/1";

/// FNV-1a, 64 bit: detects corrupted weights (not an adversary).
pub fn fnv1a(h: u64, bytes: &[u8]) -> u64 {
    bytes
        .iter()
        .fold(h, |h, &b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3))
}
/// The FNV-1a offset basis: the checksum of no bytes.
pub const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// The tensors of a flow: (name, shape, parameter range), in a fixed order.
fn layout(flow: &Flow) -> Vec<(String, Vec<usize>, std::ops::Range<usize>)> {
    let mut out = Vec::new();
    for (l, c) in flow.layers().iter().enumerate() {
        let mut off = c.param_range().start;
        for j in 0..c.mlp().layers() {
            let (i, o) = (c.mlp().dims[j], c.mlp().dims[j + 1]);
            out.push((
                format!("coupling{l}.layer{j}.weight"),
                vec![i, o],
                off..off + i * o,
            ));
            off += i * o;
            out.push((format!("coupling{l}.layer{j}.bias"), vec![o], off..off + o));
            off += o;
        }
    }
    out
}

/// Serialises a flow with extra metadata entries.
pub fn to_bytes(flow: &Flow, extra: &HashMap<String, String>) -> Result<Vec<u8>> {
    let bytes: Vec<u8> = flow.params().iter().flat_map(|p| p.to_le_bytes()).collect();
    let mut views = Vec::new();
    let mut checksum = FNV_OFFSET;
    for (name, shape, range) in layout(flow) {
        let data = &bytes[range.start * 4..range.end * 4];
        checksum = fnv1a(checksum, data);
        let view = TensorView::new(Dtype::F32, shape, data)
            .map_err(|e| Error::Config(format!("cannot describe tensor {name}: {e}")))?;
        views.push((name, view));
    }
    let mut meta = extra.clone();
    meta.insert("format".into(), FORMAT.into());
    meta.insert(
        "config".into(),
        serde_json::to_string(flow.config()).expect("a config serialises"),
    );
    meta.insert("checksum".into(), format!("{checksum:016x}"));
    safetensors::serialize(views, Some(meta))
        .map_err(|e| Error::Config(format!("cannot serialise the flow: {e}")))
}

/// Saves a flow to `path` (atomically).
pub fn save(flow: &Flow, path: &Path) -> Result<()> {
    save_with(flow, path, &HashMap::new())
}

/// Saves a flow with extra metadata entries (atomically).
pub fn save_with(flow: &Flow, path: &Path, extra: &HashMap<String, String>) -> Result<()> {
    write_atomic(path, &to_bytes(flow, extra)?)
}

/// Loads a flow saved by [`save`].
pub fn load(path: &Path) -> Result<Flow> {
    Ok(load_with(path)?.0)
}

/// Loads a flow and the metadata saved beside it.
pub fn load_with(path: &Path) -> Result<(Flow, HashMap<String, String>)> {
    let bytes = fs::read(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    from_bytes(&bytes).map_err(|reason| Error::Model {
        path: PathBuf::from(path),
        reason,
    })
}

/// The metadata of a safetensors file that nis wrote as `what`, checked for the format tag.
pub fn read_metadata(
    bytes: &[u8],
    format: &str,
    what: &str,
) -> std::result::Result<HashMap<String, String>, String> {
    let (_, header) = SafeTensors::read_metadata(bytes)
        .map_err(|e| format!("not a readable safetensors file ({e})"))?;
    let meta = header
        .metadata()
        .clone()
        .ok_or_else(|| format!("no metadata: not {what}"))?;
    if meta.get("format").map(String::as_str) != Some(format) {
        return Err(format!(
            "format is {:?}, expected {format:?}",
            meta.get("format")
        ));
    }
    Ok(meta)
}

/// Parses a model file's bytes; the error says what is wrong with them.
pub fn from_bytes(bytes: &[u8]) -> std::result::Result<(Flow, HashMap<String, String>), String> {
    let meta = read_metadata(bytes, FORMAT, "a nis model")?;
    let config: FlowConfig = serde_json::from_str(meta.get("config").ok_or("no config")?)
        .map_err(|e| format!("config is not valid: {e}"))?;
    config.validate().map_err(|e| e.to_string())?;
    // The weights must be in the file: check the claim before allocating the flow.
    let needed = config.param_count().and_then(|n| n.checked_mul(4));
    if needed.is_none_or(|n| n > bytes.len()) {
        return Err(format!(
            "the config needs {} bytes of weights, the file has {} bytes in all",
            needed.map_or("more than 2^64".into(), |n| n.to_string()),
            bytes.len()
        ));
    }
    let mut flow = Flow::new(config).map_err(|e| e.to_string())?;
    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| format!("truncated or corrupt ({e})"))?;
    let layout = layout(&flow);
    if tensors.len() != layout.len() {
        return Err(format!(
            "{} tensors, the config needs {}",
            tensors.len(),
            layout.len()
        ));
    }
    let mut checksum = FNV_OFFSET;
    let params = flow.params_mut();
    for (name, shape, range) in layout {
        let t = tensors
            .tensor(&name)
            .map_err(|_| format!("tensor {name} is missing"))?;
        if t.dtype() != Dtype::F32 || t.shape() != shape.as_slice() {
            return Err(format!(
                "tensor {name} is {:?} {:?}, the config needs F32 {shape:?}",
                t.dtype(),
                t.shape()
            ));
        }
        checksum = fnv1a(checksum, t.data());
        for (p, b) in params[range].iter_mut().zip(t.data().chunks_exact(4)) {
            *p = f32::from_le_bytes([b[0], b[1], b[2], b[3]]);
        }
    }
    if meta.get("checksum") != Some(&format!("{checksum:016x}")) {
        return Err("checksum mismatch: the weights are corrupted".into());
    }
    if flow.params().iter().any(|p| !p.is_finite()) {
        return Err("non-finite weights".into());
    }
    Ok((flow, meta))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transform::TransformKind;

    fn trained_like_flow() -> Flow {
        let mut flow = Flow::new(FlowConfig {
            dim: 3,
            transform: TransformKind::RationalQuadratic { bins: 5 },
            hidden_width: 8,
            context_dim: 1,
            ..FlowConfig::new(3)
        })
        .unwrap();
        for (i, p) in flow.params_mut().iter_mut().enumerate() {
            *p += (i % 7) as f32 * 0.01;
        }
        flow
    }

    #[test]
    fn save_and_load_round_trip_exactly() {
        let dir = std::env::temp_dir().join(format!("nis-io-{}", std::process::id()));
        fs::create_dir_all(&dir).unwrap();
        let path = dir.join("flow.safetensors");
        let flow = trained_like_flow();
        let mut extra = HashMap::new();
        extra.insert("note".to_string(), "hello".to_string());
        save_with(&flow, &path, &extra).unwrap();
        let (back, meta) = load_with(&path).unwrap();
        assert_eq!(back.config(), flow.config());
        assert_eq!(back.params(), flow.params());
        assert_eq!(meta.get("note").unwrap(), "hello");
        // No temporary file is left behind.
        assert_eq!(fs::read_dir(&dir).unwrap().count(), 1);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn damaged_or_mismatched_files_are_errors() {
        let flow = trained_like_flow();
        let bytes = to_bytes(&flow, &HashMap::new()).unwrap();
        // Truncated anywhere.
        for cut in [0, 4, 8, 100, bytes.len() / 2, bytes.len() - 1] {
            assert!(from_bytes(&bytes[..cut]).is_err(), "cut at {cut}");
        }
        // One flipped bit in the weights (the end of the file is tensor data).
        let mut bad = bytes.clone();
        let last = bad.len() - 3;
        bad[last] ^= 0x10;
        assert!(from_bytes(&bad).unwrap_err().contains("checksum"));
        // Garbage.
        assert!(from_bytes(b"this is not a model").is_err());
        // A valid file for another config: same tensors, config edited to another width.
        let other = Flow::new(FlowConfig {
            hidden_width: 9,
            ..flow.config().clone()
        })
        .unwrap();
        let other_bytes = to_bytes(&other, &HashMap::new()).unwrap();
        let (_, header) = SafeTensors::read_metadata(&other_bytes).unwrap();
        let mut meta = header.metadata().clone().unwrap();
        meta.insert(
            "config".into(),
            serde_json::to_string(flow.config()).unwrap(),
        );
        let tensors = SafeTensors::deserialize(&other_bytes).unwrap();
        let forged = safetensors::serialize(tensors.tensors(), Some(meta)).unwrap();
        assert!(from_bytes(&forged).unwrap_err().contains("config needs"));
        // A missing file is an I/O error naming the path.
        let err = load(Path::new("/nonexistent/flow.safetensors")).unwrap_err();
        assert!(err.to_string().contains("/nonexistent/flow.safetensors"));
    }
}
