//! Named tensors from a memory-mapped `model.safetensors` with Hugging Face `CLIPModel` names.
//!
//! Every tensor is checked against the shape the config implies and converted to f32
//! (stored f32, f16 and bf16 are accepted), so a missing or misshaped tensor is a clear error
//! naming the file and the tensor rather than a wrong answer later.

use std::path::{Path, PathBuf};

use memmap2::Mmap;
use safetensors::{Dtype, SafeTensors};

use super::ClipError;

/// An open, memory-mapped safetensors file.
pub struct WeightFile {
    path: PathBuf,
    mmap: Mmap,
}

impl WeightFile {
    pub fn open(path: &Path) -> Result<WeightFile, ClipError> {
        let file = std::fs::File::open(path).map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        // SAFETY: the file is opened read-only; like every mmap reader we rely on nobody
        // truncating the weights while the model loads (they are copied out right away).
        let mmap = unsafe { Mmap::map(&file) }.map_err(|e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        Ok(WeightFile {
            path: path.to_path_buf(),
            mmap,
        })
    }

    /// Parse the header; the returned view borrows the mapping.
    pub fn tensors(&self) -> Result<Weights<'_>, ClipError> {
        let st = SafeTensors::deserialize(&self.mmap).map_err(|e| ClipError::Weights {
            path: self.path.clone(),
            msg: format!("not a safetensors file: {e}"),
        })?;
        Ok(Weights {
            path: &self.path,
            st,
        })
    }
}

/// The tensors of one file.
pub struct Weights<'a> {
    path: &'a Path,
    st: SafeTensors<'a>,
}

impl Weights<'_> {
    fn err(&self, msg: String) -> ClipError {
        ClipError::Weights {
            path: self.path.to_path_buf(),
            msg,
        }
    }

    /// Tensor `name` as f32 (row-major), which must have exactly `shape`. A scalar may be
    /// stored with shape `[]` or `[1]`; ask for `&[]`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let t = self
            .st
            .tensor(name)
            .map_err(|_| self.err(format!("tensor \"{name}\" is missing")))?;
        let got = t.shape();
        let scalar_ok = shape.is_empty() && (got.is_empty() || got == [1]);
        if got != shape && !scalar_ok {
            return Err(self.err(format!(
                "tensor \"{name}\" has shape {got:?}, expected {shape:?}"
            )));
        }
        let bytes = t.data();
        // `data()` may be unaligned, so decode element by element.
        let out: Vec<f32> = match t.dtype() {
            Dtype::F32 => bytes
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            Dtype::F16 => bytes
                .chunks_exact(2)
                .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect(),
            Dtype::BF16 => bytes
                .chunks_exact(2)
                .map(|b| half::bf16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect(),
            other => {
                return Err(self.err(format!(
                    "tensor \"{name}\" has dtype {other:?}; only F32, F16 and BF16 are supported"
                )))
            }
        };
        if let Some(i) = out.iter().position(|v| !v.is_finite()) {
            return Err(self.err(format!("tensor \"{name}\" has a non-finite value at {i}")));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use safetensors::tensor::TensorView;

    fn write(dir: &Path, tensors: &[(&str, Dtype, Vec<usize>, Vec<u8>)]) -> PathBuf {
        let views: Vec<(String, TensorView)> = tensors
            .iter()
            .map(|(n, d, s, b)| (n.to_string(), TensorView::new(*d, s.clone(), b).unwrap()))
            .collect();
        let p = dir.join("model.safetensors");
        safetensors::serialize_to_file(views, None, &p).unwrap();
        p
    }

    #[test]
    fn reads_f32_f16_bf16_and_checks_shapes() {
        let dir = tempfile::tempdir().unwrap();
        let f32s: Vec<u8> = [1.5f32, -2.0, 3.25, 0.0]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let f16s: Vec<u8> = [0.5f32, -1.0]
            .iter()
            .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
            .collect();
        let bf16s: Vec<u8> = [2.0f32]
            .iter()
            .flat_map(|v| half::bf16::from_f32(*v).to_le_bytes())
            .collect();
        let p = write(
            dir.path(),
            &[
                ("a", Dtype::F32, vec![2, 2], f32s),
                ("b", Dtype::F16, vec![2], f16s),
                ("s", Dtype::BF16, vec![], bf16s),
            ],
        );
        let wf = WeightFile::open(&p).unwrap();
        let w = wf.tensors().unwrap();
        assert_eq!(w.get("a", &[2, 2]).unwrap(), vec![1.5, -2.0, 3.25, 0.0]);
        assert_eq!(w.get("b", &[2]).unwrap(), vec![0.5, -1.0]);
        assert_eq!(w.get("s", &[]).unwrap(), vec![2.0]);
        let e = w.get("a", &[4]).unwrap_err().to_string();
        assert!(
            e.contains("\"a\"") && e.contains("[2, 2]") && e.contains("model.safetensors"),
            "{e}"
        );
        let e = w.get("missing.weight", &[1]).unwrap_err().to_string();
        assert!(e.contains("missing.weight") && e.contains("missing"), "{e}");
    }

    #[test]
    fn garbage_file_is_a_clear_error() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("model.safetensors");
        std::fs::write(&p, b"definitely not safetensors").unwrap();
        let wf = WeightFile::open(&p).unwrap();
        let e = wf.tensors().err().unwrap().to_string();
        assert!(
            e.contains("model.safetensors") && e.contains("safetensors"),
            "{e}"
        );
    }
}
