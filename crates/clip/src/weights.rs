//! A model's weights: one file or several shards, each a safetensors file or a PyTorch
//! `torch.save` checkpoint, looked up by Hugging Face `CLIPModel` tensor name.
//!
//! The format of each file is told by its first bytes, not its name (a zip archive is a PyTorch
//! checkpoint; an 8-byte length followed by `{` is safetensors), so a misnamed file still loads
//! and a file that is neither (an HTML error page, a Git LFS pointer) is a clear error. Every
//! tensor is checked against the shape the config implies and widened to f32 one at a time from
//! the memory-mapped file, so loading needs the model's f32 size plus one tensor, never a
//! second copy of the checkpoint.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use safetensors::tensor::Metadata;
use safetensors::{Dtype, SafeTensors};

use super::checkpoint::torch::TorchCheckpoint;
use super::checkpoint::{check_finite, check_shape, release};
use super::ClipError;

/// All the files of one checkpoint, with an index from tensor name to the file holding it.
pub struct Checkpoint {
    parts: Vec<Part>,
    owner: HashMap<String, usize>,
}

enum Part {
    Safetensors(SafetensorsFile),
    Torch(TorchCheckpoint),
}

impl Checkpoint {
    /// Open every file of a checkpoint (one, or the shards an index names). Only headers are
    /// read here; tensor data is read when asked for.
    pub fn open(files: &[PathBuf]) -> Result<Checkpoint, ClipError> {
        let mut parts = Vec::with_capacity(files.len());
        let mut owner = HashMap::new();
        for path in files {
            let part = match sniff(path)? {
                Format::Safetensors => Part::Safetensors(SafetensorsFile::open(path)?),
                Format::Torch => Part::Torch(TorchCheckpoint::open(path)?),
            };
            for name in part.names() {
                // A name in two shards: the first wins, as in transformers' sharded loading.
                owner.entry(name).or_insert(parts.len());
            }
            parts.push(part);
        }
        Ok(Checkpoint { parts, owner })
    }

    /// Tensor `name` as f32 (row-major), which must have exactly `shape`. A scalar may be
    /// stored with shape `[]` or `[1]`; ask for `&[]`.
    pub fn get(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        match self.owner.get(name).map(|&i| &self.parts[i]) {
            Some(Part::Safetensors(f)) => f.get(name, shape),
            Some(Part::Torch(f)) => f.get(name, shape),
            None => Err(ClipError::Weights {
                path: self.describe_files(),
                msg: format!("tensor \"{name}\" is missing"),
            }),
        }
    }

    /// Rows `rows` of tensor `name` (of `shape`, rows along the first dimension) as f32,
    /// `[rows.len(), shape[1..]]`: read alone from the map (a token table's few used rows,
    /// without copying the table) where the file stores them plainly, else from the whole
    /// tensor.
    pub fn rows(&self, name: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        match self.owner.get(name).map(|&i| &self.parts[i]) {
            Some(Part::Safetensors(f)) => f.rows(name, shape, rows),
            Some(Part::Torch(f)) => f.rows(name, shape, rows),
            None => Err(ClipError::Weights {
                path: self.describe_files(),
                msg: format!("tensor \"{name}\" is missing"),
            }),
        }
    }

    /// The stored shape of tensor `name`.
    pub fn shape(&self, name: &str) -> Option<Vec<usize>> {
        match self.owner.get(name).map(|&i| &self.parts[i])? {
            Part::Safetensors(f) => f.metadata.info(name).map(|i| i.shape.clone()),
            Part::Torch(f) => f.shape(name).map(<[usize]>::to_vec),
        }
    }

    /// Every tensor name, sorted.
    pub fn names(&self) -> Vec<&str> {
        let mut v: Vec<&str> = self.owner.keys().map(String::as_str).collect();
        v.sort_unstable();
        v
    }

    /// The file, or "first (and N more shards)", for messages about a missing tensor.
    fn describe_files(&self) -> PathBuf {
        let first = self.parts.first().map_or_else(PathBuf::new, Part::path);
        match self.parts.len() {
            0 | 1 => first,
            n => PathBuf::from(format!("{} (and {} more shards)", first.display(), n - 1)),
        }
    }
}

impl Part {
    fn names(&self) -> Vec<String> {
        match self {
            Part::Safetensors(f) => f.metadata.tensors().into_keys().collect(),
            Part::Torch(f) => f.names().into_iter().map(str::to_string).collect(),
        }
    }

    fn path(&self) -> PathBuf {
        match self {
            Part::Safetensors(f) => f.path.clone(),
            Part::Torch(f) => f.path().to_path_buf(),
        }
    }
}

enum Format {
    Safetensors,
    Torch,
}

/// What a file is, from its first bytes.
fn sniff(path: &Path) -> Result<Format, ClipError> {
    use std::io::Read;
    let io = |source| ClipError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut head = Vec::with_capacity(64);
    t2tf_core::input::open(path)
        .map_err(io)?
        .take(64)
        .read_to_end(&mut head)
        .map_err(io)?;
    if head.starts_with(b"PK\x03\x04") {
        return Ok(Format::Torch);
    }
    if head.len() > 8 && head[8] == b'{' {
        return Ok(Format::Safetensors);
    }
    let what = if head.starts_with(b"version https://git-lfs") {
        "a Git LFS pointer, not the weights themselves (run `git lfs pull` in that clone, or \
         let t2tf download the model)"
            .to_string()
    } else if head.first() == Some(&0x80) {
        "a PyTorch checkpoint in the legacy pre-1.6 format; re-save it with torch >= 1.6 \
         (torch.save) or convert it to safetensors"
            .to_string()
    } else if head.is_empty() {
        "empty".to_string()
    } else {
        let shown: String = head
            .iter()
            .take(16)
            .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
            .collect();
        format!("neither a safetensors file nor a PyTorch checkpoint (it starts with \"{shown}\")")
    };
    Err(ClipError::Weights {
        path: path.to_path_buf(),
        msg: what,
    })
}

/// One memory-mapped safetensors file with its parsed header.
struct SafetensorsFile {
    path: PathBuf,
    mmap: Mmap,
    /// Where tensor data starts: 8 bytes of header length plus the header.
    data_start: usize,
    metadata: Metadata,
}

impl SafetensorsFile {
    fn open(path: &Path) -> Result<SafetensorsFile, ClipError> {
        let io = |source| ClipError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = t2tf_core::input::open(path).map_err(io)?;
        // SAFETY: the file is opened read-only; like every mmap reader we rely on nobody
        // truncating the weights while the model loads (they are copied out right away).
        let mmap = unsafe { Mmap::map(&file) }.map_err(io)?;
        // `read_metadata` validates every tensor's offsets against the file's length.
        let (header_len, metadata) =
            SafeTensors::read_metadata(&mmap).map_err(|e| ClipError::Weights {
                path: path.to_path_buf(),
                msg: format!("not a valid safetensors file: {e}"),
            })?;
        Ok(SafetensorsFile {
            path: path.to_path_buf(),
            mmap,
            data_start: 8 + header_len,
            metadata,
        })
    }

    fn err(&self, msg: String) -> ClipError {
        ClipError::Weights {
            path: self.path.clone(),
            msg,
        }
    }

    fn get(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let info = self
            .metadata
            .info(name)
            .ok_or_else(|| self.err(format!("tensor \"{name}\" is missing")))?;
        check_shape(name, &info.shape, shape).map_err(|m| self.err(m))?;
        let (s, e) = info.data_offsets;
        let range = self.data_start + s..self.data_start + e;
        let out = widen(&self.mmap[range.clone()], info.dtype);
        // The tensor is now a copy: its pages stop counting as this process's memory, so a
        // load holds one tensor of the file at a time on top of the model it builds, not the
        // whole file's page-cache pages until the map is dropped.
        release(&self.mmap, range);
        let out = out.ok_or_else(|| {
            self.err(format!(
                "tensor \"{name}\" has dtype {:?}; only F32, F16 and BF16 are supported",
                info.dtype
            ))
        })?;
        check_finite(name, &out).map_err(|m| self.err(m))?;
        Ok(out)
    }

    /// As `get` for the rows `rows` only (rows along the first dimension), each read from
    /// the map by itself and its pages released after.
    fn rows(&self, name: &str, shape: &[usize], rows: &[u32]) -> Result<Vec<f32>, ClipError> {
        let info = self
            .metadata
            .info(name)
            .ok_or_else(|| self.err(format!("tensor \"{name}\" is missing")))?;
        check_shape(name, &info.shape, shape).map_err(|m| self.err(m))?;
        if !matches!(info.dtype, Dtype::F32 | Dtype::F16 | Dtype::BF16) {
            return Err(self.err(format!(
                "tensor \"{name}\" has dtype {:?}; only F32, F16 and BF16 are supported",
                info.dtype
            )));
        }
        let elem = if info.dtype == Dtype::F32 { 4 } else { 2 };
        let row_len = shape.iter().skip(1).product::<usize>();
        let row_bytes = row_len * elem;
        let start = self.data_start + info.data_offsets.0;
        let mut out = Vec::with_capacity(rows.len() * row_len);
        for &r in rows {
            let r = crate::source::row_index(name, shape, r)?;
            let range = start + r * row_bytes..start + (r + 1) * row_bytes;
            let row = widen(&self.mmap[range.clone()], info.dtype).unwrap_or_default();
            release(&self.mmap, range);
            if row.iter().any(|v| !v.is_finite()) {
                return Err(self.err(format!(
                    "tensor \"{name}\" has a non-finite value in row {r}"
                )));
            }
            out.extend(row);
        }
        Ok(out)
    }
}

/// Little-endian F32/F16/BF16 bytes to f32; `None` for other dtypes. The bytes may be
/// unaligned, so decode element by element.
fn widen(bytes: &[u8], dtype: Dtype) -> Option<Vec<f32>> {
    Some(match dtype {
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
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use safetensors::tensor::TensorView;

    fn write(path: &Path, tensors: &[(&str, Dtype, Vec<usize>, Vec<u8>)]) -> PathBuf {
        let views: Vec<(String, TensorView)> = tensors
            .iter()
            .map(|(n, d, s, b)| (n.to_string(), TensorView::new(*d, s.clone(), b).unwrap()))
            .collect();
        safetensors::serialize_to_file(views, None, path).unwrap();
        path.to_path_buf()
    }

    fn f32_bytes(v: &[f32]) -> Vec<u8> {
        v.iter().flat_map(|v| v.to_le_bytes()).collect()
    }

    #[test]
    fn reads_f32_f16_bf16_and_checks_shapes() {
        let dir = tempfile::tempdir().unwrap();
        let f16s: Vec<u8> = [0.5f32, -1.0]
            .iter()
            .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
            .collect();
        let bf16s: Vec<u8> = half::bf16::from_f32(2.0).to_le_bytes().to_vec();
        let p = write(
            &dir.path().join("model.safetensors"),
            &[
                (
                    "a",
                    Dtype::F32,
                    vec![2, 2],
                    f32_bytes(&[1.5, -2.0, 3.25, 0.0]),
                ),
                ("b", Dtype::F16, vec![2], f16s),
                ("s", Dtype::BF16, vec![], bf16s),
                ("ids", Dtype::I64, vec![1], vec![0; 8]),
            ],
        );
        let w = Checkpoint::open(&[p]).unwrap();
        assert_eq!(w.get("a", &[2, 2]).unwrap(), vec![1.5, -2.0, 3.25, 0.0]);
        assert_eq!(w.get("b", &[2]).unwrap(), vec![0.5, -1.0]);
        assert_eq!(w.get("s", &[]).unwrap(), vec![2.0]);
        let e = w.get("a", &[4]).unwrap_err().to_string();
        assert!(
            e.contains("\"a\"")
                && e.contains("[2, 2]")
                && e.contains("[4]")
                && e.contains("model.safetensors"),
            "{e}"
        );
        let e = w.get("missing.weight", &[1]).unwrap_err().to_string();
        assert!(e.contains("missing.weight") && e.contains("missing"), "{e}");
        let e = w.get("ids", &[1]).unwrap_err().to_string();
        assert!(e.contains("I64"), "{e}");
    }

    /// Rows read alone from the map are the rows of the whole tensor, in the order asked,
    /// for each float dtype; a row past the end, a wrong shape, another dtype and a
    /// non-finite value in a row read are errors.
    #[test]
    fn rows_are_read_alone() {
        let dir = tempfile::tempdir().unwrap();
        let table: Vec<f32> = (0..12).map(|v| v as f32 * 0.5).collect();
        let f16s: Vec<u8> = table
            .iter()
            .flat_map(|v| half::f16::from_f32(*v).to_le_bytes())
            .collect();
        let bf16s: Vec<u8> = table
            .iter()
            .flat_map(|v| half::bf16::from_f32(*v).to_le_bytes())
            .collect();
        let mut nan = table.clone();
        nan[7] = f32::NAN;
        let p = write(
            &dir.path().join("model.safetensors"),
            &[
                ("f32", Dtype::F32, vec![4, 3], f32_bytes(&table)),
                ("f16", Dtype::F16, vec![4, 3], f16s),
                ("bf16", Dtype::BF16, vec![4, 3], bf16s),
                ("nan", Dtype::F32, vec![4, 3], f32_bytes(&nan)),
                ("ids", Dtype::I64, vec![4, 3], vec![0; 96]),
            ],
        );
        let w = Checkpoint::open(&[p]).unwrap();
        for name in ["f32", "f16", "bf16"] {
            let whole = w.get(name, &[4, 3]).unwrap();
            let rows = w.rows(name, &[4, 3], &[3, 0, 3]).unwrap();
            let want: Vec<f32> = [3, 0, 3]
                .iter()
                .flat_map(|&r| whole[r * 3..r * 3 + 3].to_vec())
                .collect();
            assert_eq!(rows, want, "{name}");
            assert!(w.rows(name, &[4, 3], &[]).unwrap().is_empty());
        }
        let e = w.rows("f32", &[4, 3], &[4]).unwrap_err().to_string();
        assert!(e.contains("row 4") && e.contains("has 4"), "{e}");
        let e = w.rows("f32", &[3, 4], &[0]).unwrap_err().to_string();
        assert!(e.contains("[3, 4]"), "{e}");
        let e = w.rows("ids", &[4, 3], &[0]).unwrap_err().to_string();
        assert!(e.contains("I64"), "{e}");
        assert_eq!(w.rows("nan", &[4, 3], &[0, 3]).unwrap().len(), 6);
        let e = w.rows("nan", &[4, 3], &[2]).unwrap_err().to_string();
        assert!(e.contains("\"nan\"") && e.contains("row 2"), "{e}");
        let e = w.rows("missing", &[4, 3], &[0]).unwrap_err().to_string();
        assert!(e.contains("missing"), "{e}");
    }

    #[test]
    fn shards_are_one_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let a = write(
            &dir.path().join("model-00001-of-00002.safetensors"),
            &[("x", Dtype::F32, vec![1], f32_bytes(&[1.0]))],
        );
        let b = write(
            &dir.path().join("model-00002-of-00002.safetensors"),
            &[("y", Dtype::F32, vec![2], f32_bytes(&[2.0, 3.0]))],
        );
        let w = Checkpoint::open(&[a, b]).unwrap();
        assert_eq!(w.names(), vec!["x", "y"]);
        assert_eq!(w.get("y", &[2]).unwrap(), vec![2.0, 3.0]);
        let e = w.get("z", &[1]).unwrap_err().to_string();
        assert!(e.contains("1 more shards"), "{e}");
    }

    #[test]
    fn files_that_are_not_weights_say_what_they_are() {
        let dir = tempfile::tempdir().unwrap();
        let cases: [(&[u8], &str); 4] = [
            (b"definitely not safetensors", "neither a safetensors file"),
            (
                b"version https://git-lfs.github.com/spec/v1\noid sha256:abc\n",
                "Git LFS pointer",
            ),
            (b"\x80\x02\x8a\x0al\xfc\x9cF\xf9 j\xa8P\x19.", "legacy"),
            (b"", "empty"),
        ];
        for (bytes, needle) in cases {
            let p = dir.path().join("model.bin");
            std::fs::write(&p, bytes).unwrap();
            let e = Checkpoint::open(std::slice::from_ref(&p))
                .err()
                .unwrap()
                .to_string();
            assert!(e.contains(needle) && e.contains("model.bin"), "{e}");
        }
        // Looks like safetensors but the header lies about the length.
        let p = dir.path().join("model.safetensors");
        let mut bytes = 100u64.to_le_bytes().to_vec();
        bytes.extend_from_slice(b"{\"a\":1}");
        std::fs::write(&p, bytes).unwrap();
        let e = Checkpoint::open(&[p]).err().unwrap().to_string();
        assert!(e.contains("not a valid safetensors file"), "{e}");
    }
}
