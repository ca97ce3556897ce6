//! Named tensors from a `torch.save` checkpoint (`pytorch_model.bin`), memory-mapped.
//!
//! Since torch 1.6 `torch.save` writes a zip archive: `PREFIX/data.pkl` (a pickle of the state
//! dict whose tensors point at storages by key), `PREFIX/data/KEY` (each storage's raw
//! little-endian bytes, STORED and 64-byte aligned), `PREFIX/byteorder`, `PREFIX/version`.
//! `PREFIX` is whatever single top folder holds `data.pkl` (`archive`, or the file's stem).
//!
//! Opening parses the zip's central directory and runs the pickle through the restricted
//! unpickler (`super::pickle`); no storage is read. `get` then converts one tensor: a STORED
//! storage is read in place from the mapping, a DEFLATED one (re-zipped by some tool) is
//! inflated on its own. Views are honoured (storage offset, any strides, shared storages).
//!
//! The zip crate (stored + deflate features only) reads the central directory, zip64 included,
//! and gives each entry's data offset (`ZipFile::data_start`), which is what reading in place
//! needs; inflating is done here with flate2 straight from the mapping, so the archive handle
//! is not kept.

use std::borrow::Cow;
use std::collections::{BTreeMap, HashMap};
use std::io::{Cursor, Read};
use std::path::{Path, PathBuf};

use memmap2::Mmap;
use zip::{CompressionMethod, ZipArchive};

use super::pickle::{self, DType, PickleError, Tensor};
use super::{check_finite, check_shape};
use crate::source::{gather_rows, row_index};
use crate::ClipError;

/// The pickle of a state dict is tens of kilobytes for CLIP and a few megabytes for the
/// largest language models; anything bigger is not a state dict.
const MAX_PICKLE_BYTES: usize = 64 << 20;
/// Deflate cannot expand data by more than about 1032:1; an entry claiming more is corrupt.
const MAX_DEFLATE_RATIO: usize = 1032;
/// A legacy (pre-1.6) `torch.save` file starts with the pickled magic number
/// 0x1950a86a20f9469cfc6c (protocol 2, LONG1 of 10 bytes).
const LEGACY_MAGIC: [u8; 14] = [
    0x80, 0x02, 0x8a, 0x0a, 0x6c, 0xfc, 0x9c, 0x46, 0xf9, 0x20, 0x6a, 0xa8, 0x50, 0x19,
];

/// Where an archive entry's bytes are in the file.
#[derive(Debug, Clone, Copy)]
struct Entry {
    start: usize,
    /// Bytes in the file (compressed size).
    stored_len: usize,
    /// Bytes once inflated.
    size: usize,
    deflated: bool,
}

/// A tensor with its storage entry, checked to lie inside it.
#[derive(Debug, Clone)]
struct Located {
    tensor: Tensor,
    entry: Entry,
}

/// An open, memory-mapped `torch.save` archive.
pub(crate) struct TorchCheckpoint {
    path: PathBuf,
    mmap: Mmap,
    tensors: BTreeMap<String, Located>,
}

impl TorchCheckpoint {
    pub(crate) fn open(path: &Path) -> Result<TorchCheckpoint, ClipError> {
        let io_err = |e| ClipError::Io {
            path: path.to_path_buf(),
            source: e,
        };
        let file = t2tf_core::input::open(path).map_err(io_err)?;
        // SAFETY: the file is opened read-only; like every mmap reader we rely on nobody
        // truncating the checkpoint while the model loads (tensors are copied out right away).
        let mmap = unsafe { Mmap::map(&file) }.map_err(io_err)?;
        let tensors = index(&mmap).map_err(|msg| ClipError::Weights {
            path: path.to_path_buf(),
            msg,
        })?;
        Ok(TorchCheckpoint {
            path: path.to_path_buf(),
            mmap,
            tensors,
        })
    }

    fn err(&self, msg: String) -> ClipError {
        ClipError::Weights {
            path: self.path.clone(),
            msg,
        }
    }

    /// The file this checkpoint was read from.
    pub(crate) fn path(&self) -> &Path {
        &self.path
    }

    /// Every tensor, sorted by name (non-float buffers included).
    pub(crate) fn names(&self) -> Vec<&str> {
        self.tensors.keys().map(String::as_str).collect()
    }

    pub(crate) fn shape(&self, name: &str) -> Option<&[usize]> {
        self.tensors.get(name).map(|l| l.tensor.shape.as_slice())
    }

    /// As `Weights::get`: tensor `name` as f32 (row-major), which must have exactly `shape`.
    /// A scalar may be stored with shape `[]` or `[1]`; ask for `&[]`. Float tensors (f32,
    /// f16, bf16, f64) are widened or rounded to f32; other dtypes and non-finite values are
    /// errors.
    pub(crate) fn get(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, ClipError> {
        let loc = self
            .tensors
            .get(name)
            .ok_or_else(|| self.err(format!("tensor \"{name}\" is missing")))?;
        check_shape(name, &loc.tensor.shape, shape).map_err(|m| self.err(m))?;
        let out =
            read_f32(&self.mmap, loc).map_err(|m| self.err(format!("tensor \"{name}\" {m}")))?;
        // As for safetensors: the copy is made, its storage's pages stop counting (a storage
        // other tensors view is read back from the file for them).
        let e = &loc.entry;
        super::release(&self.mmap, e.start..e.start.saturating_add(e.stored_len));
        check_finite(name, &out).map_err(|m| self.err(m))?;
        Ok(out)
    }
}

impl TorchCheckpoint {
    /// As `Checkpoint::rows`: rows `rows` of tensor `name` (of `shape`, rows along the first
    /// dimension). A contiguous tensor in a stored (not deflated) entry has each row read
    /// alone from the map and its pages released; any other is read whole.
    pub(crate) fn rows(
        &self,
        name: &str,
        shape: &[usize],
        rows: &[u32],
    ) -> Result<Vec<f32>, ClipError> {
        let loc = self
            .tensors
            .get(name)
            .ok_or_else(|| self.err(format!("tensor \"{name}\" is missing")))?;
        check_shape(name, &loc.tensor.shape, shape).map_err(|m| self.err(m))?;
        let (t, e) = (&loc.tensor, &loc.entry);
        let decode = match decoder(t.dtype) {
            Some(d) if !e.deflated && e.stored_len == e.size && is_contiguous(t) => d,
            _ => return gather_rows(name, &self.get(name, shape)?, shape, rows),
        };
        let size = t.dtype.size();
        let row_len: usize = shape.iter().skip(1).product();
        let mut out = Vec::with_capacity(rows.len() * row_len);
        for &r in rows {
            let r = row_index(name, shape, r)?;
            // Inside the entry: `locate` checked the view's extent against it at open.
            let from = e.start + (t.offset + r * row_len) * size;
            let range = from..from + row_len * size;
            let row: Vec<f32> = self.mmap[range.clone()]
                .chunks_exact(size)
                .map(decode)
                .collect();
            super::release(&self.mmap, range);
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

/// Parse the archive and its pickle: every tensor, located and bounds-checked.
fn index(bytes: &[u8]) -> Result<BTreeMap<String, Located>, String> {
    if bytes.starts_with(&LEGACY_MAGIC) {
        return Err(
            "this is a legacy (pre-1.6, non-zip) torch.save file, which t2tf does not \
                    read; re-save it with torch >= 1.6 (torch.save(torch.load(f), f)) or \
                    convert it to safetensors"
                .into(),
        );
    }
    if !bytes.starts_with(b"PK") {
        return Err(
            "not a PyTorch checkpoint (neither a torch.save zip archive nor a legacy \
                    torch file)"
                .into(),
        );
    }
    let entries = read_zip(bytes)?;
    let prefix = archive_prefix(&entries)?;
    refuse_torchscript(&entries, prefix)?;
    check_byteorder(bytes, &entries, prefix)?;

    let pkl_name = format!("{prefix}/data.pkl");
    let pkl = entry_bytes(bytes, &entries[&pkl_name], MAX_PICKLE_BYTES)
        .map_err(|m| format!("{pkl_name}: {m}"))?;
    let tensors = pickle::load_tensors(&pkl).map_err(|e| match e {
        PickleError::Refused(_) => e.to_string(),
        PickleError::Malformed(m) => format!("{pkl_name}: {m}"),
    })?;
    let mut out = BTreeMap::new();
    for (name, tensor) in tensors {
        let located = locate(&name, tensor, &entries, prefix)?;
        out.insert(name, located);
    }
    Ok(out)
}

/// Every entry of the zip by name, with where its bytes are.
fn read_zip(bytes: &[u8]) -> Result<HashMap<String, Entry>, String> {
    let zip_err = |e: zip::result::ZipError| format!("not a readable zip archive: {e}");
    let mut archive = ZipArchive::new(Cursor::new(bytes)).map_err(zip_err)?;
    let mut entries = HashMap::new();
    for i in 0..archive.len() {
        let f = archive.by_index_raw(i).map_err(zip_err)?;
        let name = f.name().to_owned();
        if f.encrypted() {
            return Err(format!("zip entry {name} is encrypted"));
        }
        let deflated = match f.compression() {
            CompressionMethod::Stored => false,
            CompressionMethod::Deflated => true,
            other => return Err(format!("zip entry {name} uses {other} compression")),
        };
        let (Some(start), Ok(stored_len), Ok(size)) = (
            f.data_start().and_then(|s| usize::try_from(s).ok()),
            usize::try_from(f.compressed_size()),
            usize::try_from(f.size()),
        ) else {
            return Err(format!("zip entry {name} has no usable offset or size"));
        };
        if start
            .checked_add(stored_len)
            .is_none_or(|end| end > bytes.len())
        {
            return Err(format!("zip entry {name} runs past the end of the file"));
        }
        let entry = Entry {
            start,
            stored_len,
            size,
            deflated,
        };
        entries.insert(name, entry);
    }
    Ok(entries)
}

/// The single top folder holding `data.pkl` (torch names it after the file or `archive`).
fn archive_prefix(entries: &HashMap<String, Entry>) -> Result<&str, String> {
    let mut prefixes: Vec<&str> = entries
        .keys()
        .filter_map(|n| n.strip_suffix("/data.pkl"))
        .filter(|p| !p.is_empty() && !p.contains('/'))
        .collect();
    prefixes.sort_unstable();
    match prefixes.as_slice() {
        [one] => Ok(one),
        [] => Err("a zip archive without FOLDER/data.pkl, so not a torch.save checkpoint".into()),
        many => Err(format!(
            "a zip archive with several data.pkl ({}), so not one torch.save checkpoint",
            many.join(", ")
        )),
    }
}

/// A TorchScript archive also has `data.pkl`, but it pickles the model's classes; saying so
/// beats refusing its `__torch__` globals one by one. (OpenAI's original CLIP `.pt` files are
/// TorchScript.)
fn refuse_torchscript(entries: &HashMap<String, Entry>, prefix: &str) -> Result<(), String> {
    let code = format!("{prefix}/code/");
    let torchscript = entries.contains_key(&format!("{prefix}/constants.pkl"))
        || entries.keys().any(|n| n.starts_with(&code));
    if torchscript {
        return Err(
            "this is a TorchScript archive (torch.jit.save), not a state dict; \
                    save model.state_dict() with torch.save, or convert it to safetensors"
                .into(),
        );
    }
    Ok(())
}

/// Storages are raw bytes in the saving machine's order; torch records it since 1.9.
fn check_byteorder(
    bytes: &[u8],
    entries: &HashMap<String, Entry>,
    prefix: &str,
) -> Result<(), String> {
    let name = format!("{prefix}/byteorder");
    let Some(entry) = entries.get(&name) else {
        return Ok(()); // older archives: little-endian, as every machine torch ran on
    };
    let order = entry_bytes(bytes, entry, 16).map_err(|m| format!("{name}: {m}"))?;
    match order.trim_ascii() {
        b"little" => Ok(()),
        b"big" => Err(
            "this checkpoint was saved on a big-endian machine (byteorder \"big\"); \
                       t2tf reads little-endian checkpoints only: re-save it on a \
                       little-endian machine or convert it to safetensors"
                .into(),
        ),
        other => Err(format!(
            "{name} says {:?}, expected \"little\"",
            String::from_utf8_lossy(other)
        )),
    }
}

/// The first `reach` bytes of an entry (`reach` ≤ its size, checked when the tensor was
/// located): in place if STORED, inflated only that far if DEFLATED.
fn entry_prefix<'a>(bytes: &'a [u8], e: &Entry, reach: usize) -> Result<Cow<'a, [u8]>, String> {
    if reach >= e.size {
        return entry_bytes(bytes, e, e.size);
    }
    let raw = &bytes[e.start..e.start + e.stored_len];
    if !e.deflated {
        if e.stored_len != e.size {
            return Err("stored entry whose sizes disagree".into());
        }
        return Ok(Cow::Borrowed(&raw[..reach]));
    }
    let mut out = Vec::new();
    out.try_reserve_exact(reach)
        .map_err(|_| format!("cannot allocate {reach} bytes to inflate it"))?;
    flate2::read::DeflateDecoder::new(raw)
        .take(reach as u64)
        .read_to_end(&mut out)
        .map_err(|err| format!("cannot inflate: {err}"))?;
    if out.len() != reach {
        return Err(format!(
            "inflates to {} bytes, fewer than the {reach} its tensor reads",
            out.len()
        ));
    }
    Ok(Cow::Owned(out))
}

/// An entry's bytes: in place if STORED, inflated (at most `limit` bytes) if DEFLATED.
fn entry_bytes<'a>(bytes: &'a [u8], e: &Entry, limit: usize) -> Result<Cow<'a, [u8]>, String> {
    if e.size > limit {
        return Err(format!("{} bytes, more than the {limit} expected", e.size));
    }
    let raw = &bytes[e.start..e.start + e.stored_len];
    if !e.deflated {
        if e.stored_len != e.size {
            return Err("stored entry whose sizes disagree".into());
        }
        return Ok(Cow::Borrowed(raw));
    }
    if e.size
        > e.stored_len
            .saturating_mul(MAX_DEFLATE_RATIO)
            .saturating_add(64)
    {
        return Err(format!(
            "deflated entry of {} bytes claims {} bytes inflated",
            e.stored_len, e.size
        ));
    }
    let mut out = Vec::new();
    out.try_reserve_exact(e.size)
        .map_err(|_| format!("cannot allocate {} bytes to inflate it", e.size))?;
    flate2::read::DeflateDecoder::new(raw)
        .take(e.size as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|err| format!("cannot inflate: {err}"))?;
    if out.len() != e.size {
        return Err(format!(
            "inflates to {} bytes, the zip says {}",
            out.len(),
            e.size
        ));
    }
    Ok(Cow::Owned(out))
}

/// Find a tensor's storage entry and check that the view stays inside it, so reading it
/// later cannot go out of bounds.
fn locate(
    name: &str,
    tensor: Tensor,
    entries: &HashMap<String, Entry>,
    prefix: &str,
) -> Result<Located, String> {
    let key = format!("{prefix}/data/{}", tensor.storage.key);
    let Some(&entry) = entries.get(&key) else {
        return Err(format!(
            "tensor \"{name}\": its storage {key} is not in the archive"
        ));
    };
    let storage_bytes = (tensor.storage.numel)
        .checked_mul(tensor.storage.dtype.size() as u64)
        .filter(|&b| b <= entry.size as u64)
        .ok_or_else(|| {
            format!(
                "tensor \"{name}\": storage {key} should hold {} {} elements but has {} bytes",
                tensor.storage.numel,
                tensor.storage.dtype.name(),
                entry.size
            )
        })?;
    let fits = view_end(&tensor)
        .and_then(|end| end.checked_mul(tensor.dtype.size() as u64))
        .is_some_and(|end| end <= storage_bytes);
    if !fits {
        return Err(format!(
            "tensor \"{name}\" (shape {:?}, stride {:?}, offset {}) reaches past its storage \
             {key} of {storage_bytes} bytes",
            tensor.shape, tensor.stride, tensor.offset
        ));
    }
    Ok(Located { tensor, entry })
}

/// One past the last storage element the view touches (0 for an empty tensor); `None` on
/// overflow, including an element count that does not fit.
fn view_end(t: &Tensor) -> Option<u64> {
    let numel = t.shape.iter().try_fold(1usize, |n, &d| n.checked_mul(d))?;
    if numel == 0 {
        return Some(0);
    }
    let mut last = t.offset as u64;
    for (&d, &s) in t.shape.iter().zip(&t.stride) {
        last = last.checked_add((d as u64 - 1).checked_mul(s as u64)?)?;
    }
    last.checked_add(1)
}

/// Decode one stored element as f32.
type Decode = fn(&[u8]) -> f32;

fn decoder(dtype: DType) -> Option<Decode> {
    Some(match dtype {
        DType::F32 => |b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
        DType::F16 => |b| half::f16::from_le_bytes([b[0], b[1]]).to_f32(),
        DType::BF16 => |b| half::bf16::from_le_bytes([b[0], b[1]]).to_f32(),
        // Rounded to nearest; a value beyond f32's range becomes infinite and is reported.
        DType::F64 => {
            |b| f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32
        }
        _ => return None,
    })
}

/// The tensor's elements in row-major order as f32; `bytes` is the whole file.
fn read_f32(bytes: &[u8], loc: &Located) -> Result<Vec<f32>, String> {
    let t = &loc.tensor;
    let decode = decoder(t.dtype).ok_or_else(|| {
        format!(
            "has dtype {}; only float32, float16, bfloat16 and float64 tensors are converted",
            t.dtype.name()
        )
    })?;
    let numel: usize = t.shape.iter().product(); // checked by `view_end` at open
    if numel == 0 {
        return Ok(Vec::new()); // the offset of an empty view need not lie in its storage
    }
    // Only the part of the storage the view reaches is inflated: a storage entry far larger
    // than the tensor the config asks for costs nothing beyond the tensor.
    let reach = view_end(t)
        .and_then(|end| usize::try_from(end).ok()?.checked_mul(t.dtype.size()))
        .ok_or_else(|| "has a view too large to address".to_string())?;
    let storage = entry_prefix(bytes, &loc.entry, reach)
        .map_err(|m| format!("(storage {}): {m}", t.storage.key))?;
    let mut out = Vec::new();
    out.try_reserve_exact(numel)
        .map_err(|_| format!("has {numel} elements, too many to allocate"))?;
    let size = t.dtype.size();
    if is_contiguous(t) {
        let run = &storage[t.offset * size..(t.offset + numel) * size];
        out.extend(run.chunks_exact(size).map(decode));
    } else {
        for_each_offset(&t.shape, &t.stride, t.offset, |o| {
            out.push(decode(&storage[o * size..(o + 1) * size]));
        });
    }
    Ok(out)
}

/// Row-major with no gaps (strides of size-1 dimensions do not matter).
fn is_contiguous(t: &Tensor) -> bool {
    let mut expected = 1usize;
    for (&d, &s) in t.shape.iter().zip(&t.stride).rev() {
        if d != 1 && s != expected {
            return false;
        }
        expected = expected.saturating_mul(d);
    }
    true
}

/// Call `f` with the storage index of every element, in row-major order. The indices are
/// in bounds because `locate` checked the view's extent; intermediate sums wrap harmlessly
/// (a size-1 dimension may carry any stride) and are undone before use.
fn for_each_offset(shape: &[usize], stride: &[usize], offset: usize, mut f: impl FnMut(usize)) {
    let numel: usize = shape.iter().product();
    let mut index = vec![0usize; shape.len()];
    let mut at = offset;
    for _ in 0..numel {
        f(at);
        for d in (0..shape.len()).rev() {
            index[d] += 1;
            at = at.wrapping_add(stride[d]);
            if index[d] < shape[d] {
                break;
            }
            at = at.wrapping_sub(stride[d].wrapping_mul(shape[d]));
            index[d] = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::Value;

    const DIR: &str = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../tests/fixtures/clip/torch"
    );
    /// What the hostile fixtures' command would create in the working directory.
    const MARKER: &str = "t2tf-pickle-marker";

    fn fixture(name: &str) -> PathBuf {
        Path::new(DIR).join(name)
    }

    fn expected(file: &str) -> serde_json::Map<String, Value> {
        let text = std::fs::read_to_string(fixture("expected.json")).unwrap();
        let json: Value = serde_json::from_str(&text).unwrap();
        json["files"][file].as_object().unwrap().clone()
    }

    fn shape_of(v: &Value) -> Vec<usize> {
        let dims = v["shape"].as_array().unwrap();
        dims.iter().map(|d| d.as_u64().unwrap() as usize).collect()
    }

    fn open_err(name: &str) -> String {
        TorchCheckpoint::open(&fixture(name))
            .err()
            .unwrap_or_else(|| panic!("{name} opened"))
            .to_string()
    }

    /// Every tensor of `file` against torch's values for `golden` (the same tensors).
    fn check_against_torch(file: &str, golden: &str) {
        let ck = TorchCheckpoint::open(&fixture(file)).unwrap();
        let want = expected(golden);
        let mut names: Vec<&str> = want.keys().map(String::as_str).collect();
        names.sort_unstable();
        assert_eq!(ck.names(), names, "{file}");
        for (name, w) in &want {
            let shape = shape_of(w);
            assert_eq!(ck.shape(name), Some(shape.as_slice()), "{file} {name}");
            let got = ck.get(name, &shape);
            let Some(bits) = w.get("f32_bits") else {
                // Integer and bool tensors are listed but not converted.
                let e = got.unwrap_err().to_string();
                let dtype = w["dtype"].as_str().unwrap();
                assert!(e.contains(name) && e.contains(dtype), "{e}");
                assert!(e.contains(file), "{e}");
                continue;
            };
            let bits: Vec<u32> = bits
                .as_array()
                .unwrap()
                .iter()
                .map(|b| b.as_u64().unwrap() as u32)
                .collect();
            if bits.iter().any(|&b| !f32::from_bits(b).is_finite()) {
                let e = got.unwrap_err().to_string();
                assert!(e.contains("non-finite") && e.contains(name), "{e}");
                continue;
            }
            let got: Vec<u32> = got.unwrap().iter().map(|v| v.to_bits()).collect();
            assert_eq!(got, bits, "{file} {name}");
        }
    }

    #[test]
    fn reads_torch_saved_tensors_bit_for_bit() {
        // "archive" prefix, protocol 2, aligned STORED storages.
        check_against_torch("state_dict.bin", "state_dict.bin");
        // "pytorch_model" prefix, protocol 4, a module's state dict with its _metadata.
        check_against_torch("pytorch_model.bin", "pytorch_model.bin");
    }

    #[test]
    fn reads_rezipped_archives() {
        // Every entry DEFLATED (inflated on demand), and zip64 local headers.
        check_against_torch("deflated.bin", "state_dict.bin");
        check_against_torch("zip64.bin", "state_dict.bin");
    }

    #[test]
    fn views_share_one_storage() {
        let ck = TorchCheckpoint::open(&fixture("state_dict.bin")).unwrap();
        let views = ["full", "transposed", "slice", "row", "broadcast"];
        let keys: Vec<&str> = views
            .iter()
            .map(|v| {
                ck.tensors[&format!("shared.{v}")]
                    .tensor
                    .storage
                    .key
                    .as_str()
            })
            .collect();
        assert!(keys.iter().all(|k| *k == keys[0]), "{keys:?}");
        let slice = &ck.tensors["shared.slice"].tensor;
        assert_eq!((slice.offset, slice.stride.as_slice()), (6, &[4, 1][..]));
        let t = &ck.tensors["shared.transposed"].tensor;
        assert_eq!(t.stride, [1, 4]);
        assert_eq!(ck.tensors["shared.broadcast"].tensor.stride, [0, 1]);
        assert_eq!(ck.tensors["u16"].tensor.dtype, DType::U16);
    }

    /// Rows read alone (contiguous tensors in stored entries, offset views among them) or
    /// from the whole tensor (transposed and broadcast views, deflated entries) are the
    /// rows of `get`, in the order asked; where `get` refuses a tensor, so do its rows.
    #[test]
    fn rows_are_the_rows_of_the_whole_tensor() {
        for file in ["state_dict.bin", "deflated.bin", "pytorch_model.bin"] {
            let ck = TorchCheckpoint::open(&fixture(file)).unwrap();
            let mut checked = 0;
            for name in ck.names() {
                let shape = ck.tensors[name].tensor.shape.clone();
                let Some(&n) = shape.first() else { continue };
                let order: Vec<u32> = (0..n as u32).rev().chain([0]).collect();
                let rows = ck.rows(name, &shape, &order);
                let Ok(whole) = ck.get(name, &shape) else {
                    assert!(rows.is_err(), "{file} {name}: rows of a refused tensor");
                    continue;
                };
                let want = gather_rows(name, &whole, &shape, &order).unwrap();
                assert_eq!(rows.unwrap(), want, "{file} {name}");
                checked += 1;
            }
            assert!(checked >= 4, "{file}: {checked} tensors checked");
            let name = ck.names()[0].to_string();
            let shape = ck.tensors[&name].tensor.shape.clone();
            if let Some(&n) = shape.first() {
                let e = ck.rows(&name, &shape, &[n as u32]).unwrap_err().to_string();
                assert!(e.contains("row"), "{e}");
            }
        }
    }

    #[test]
    fn shape_and_name_errors_name_the_tensor_and_file() {
        let ck = TorchCheckpoint::open(&fixture("state_dict.bin")).unwrap();
        assert_eq!(ck.get("logit_scale", &[]).unwrap().len(), 1);
        let e = ck.get("f32", &[3, 2]).unwrap_err().to_string();
        assert!(
            e.contains("\"f32\"") && e.contains("[2, 3]") && e.contains("state_dict.bin"),
            "{e}"
        );
        let e = ck.get("text_model.missing", &[1]).unwrap_err().to_string();
        assert!(
            e.contains("text_model.missing") && e.contains("missing"),
            "{e}"
        );
        let e = ck.get("position_ids", &[1, 7]).unwrap_err().to_string();
        assert!(e.contains("int64") && e.contains("position_ids"), "{e}");
        assert_eq!(ck.shape("nope"), None);
    }

    #[test]
    fn hostile_pickles_are_refused_and_run_nothing() {
        for (file, global) in [
            ("hostile_os_system.bin", "os.system"),
            ("hostile_builtins_eval.bin", "builtins.eval"),
        ] {
            let e = open_err(file);
            assert!(
                e.contains("refusing to load") && e.contains(global) && e.contains(file),
                "{e}"
            );
        }
        // The command would run in the working directory (the package root under cargo test).
        assert!(!Path::new(MARKER).exists());
        assert!(!fixture(MARKER).exists());
    }

    #[test]
    fn other_formats_get_clear_errors() {
        let e = open_err("truncated.bin");
        assert!(
            e.contains("archive/data.pkl") && e.contains("truncated"),
            "{e}"
        );
        let e = open_err("legacy.bin");
        assert!(e.contains("legacy") && e.contains("torch >= 1.6"), "{e}");
        let e = open_err("torchscript.pt");
        assert!(e.contains("TorchScript"), "{e}");
        let e = open_err("big_endian.bin");
        assert!(
            e.contains("big-endian") && e.contains("big_endian.bin"),
            "{e}"
        );

        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in [
            ("text.bin", &b"not a checkpoint at all"[..]),
            ("empty.bin", &b""[..]),
            (
                "zip.bin",
                &b"PK\x05\x06\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0\0"[..],
            ),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            let e = TorchCheckpoint::open(&p).err().unwrap().to_string();
            assert!(e.contains(name) && e.contains("checkpoint"), "{e}");
        }
        let e = TorchCheckpoint::open(&dir.path().join("absent.bin"))
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("absent.bin"), "{e}");
    }

    /// Index `bytes` and, if that works, convert every small float tensor.
    fn index_and_read(bytes: &[u8]) {
        let Ok(tensors) = index(bytes) else {
            return;
        };
        for loc in tensors.values() {
            let numel = loc
                .tensor
                .shape
                .iter()
                .try_fold(1usize, |n, &d| n.checked_mul(d));
            if numel.is_some_and(|n| n <= 1 << 16) {
                let _ = read_f32(bytes, loc);
            }
        }
    }

    #[test]
    fn every_prefix_and_mutation_is_an_error_or_ok_never_a_panic() {
        for file in ["state_dict.bin", "deflated.bin"] {
            let bytes = std::fs::read(fixture(file)).unwrap();
            for n in 0..bytes.len() {
                index_and_read(&bytes[..n]);
            }
            // Single-byte changes anywhere, then inside data.pkl where they reach the
            // unpickler and the view checks (xorshift: deterministic, no rand needed).
            let entries = read_zip(&bytes).unwrap();
            let pkl = entries["archive/data.pkl"];
            let mut s = 0x9e37_79b9_7f4a_7c15u64;
            for i in 0..4000 {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                let at = if i % 2 == 0 {
                    (s % bytes.len() as u64) as usize
                } else {
                    pkl.start + (s % pkl.stored_len as u64) as usize
                };
                let mut m = bytes.clone();
                m[at] = (s >> 40) as u8;
                index_and_read(&m);
            }
        }
    }

    #[test]
    fn strided_walk_matches_a_direct_computation() {
        // A 2×3×2 view with a size-1-free odd stride set and an offset.
        let (shape, stride, offset) = ([2usize, 3, 2], [13usize, 1, 5], 4usize);
        let mut got = Vec::new();
        for_each_offset(&shape, &stride, offset, |o| got.push(o));
        let mut want = Vec::new();
        for i in 0..2 {
            for j in 0..3 {
                for k in 0..2 {
                    want.push(offset + i * 13 + j + k * 5);
                }
            }
        }
        assert_eq!(got, want);
        // A size-1 dimension may carry any stride, even one that overflows when added.
        let mut got = Vec::new();
        for_each_offset(&[1, 3], &[usize::MAX, 2], 1, |o| got.push(o));
        assert_eq!(got, [1, 3, 5]);
    }
}
