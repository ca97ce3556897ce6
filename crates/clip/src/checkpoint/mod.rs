//! PyTorch checkpoints (`pytorch_model.bin`, the `torch.save` zip format) read without executing
//! anything: `pickle` is a restricted unpickler (like torch's `weights_only=True`), `torch` the
//! archive and its tensors.
//!
//! Why not an existing crate (checked in candle-core 0.11.1 and serde-pickle 1.2.0 sources):
//! candle-core's `pickle` module comes only with the whole framework (18 non-optional
//! dependencies: gemm, rayon, rand_distr, safetensors, zip, float8, ...), and it does not refuse
//! unknown globals: `REDUCE` on any class other than `OrderedDict` just records an inert
//! `Object::Reduce`, so nothing reports that a file tried to call `os.system` (it also allocates
//! a string's claimed length before reading it). serde-pickle has `BINPERSID` commented out
//! (an unsupported-opcode error) and turns every global it does not know into one opaque
//! `Global::Other`, so it can represent neither torch's persistent storage ids nor which
//! rebuild function a tensor names.

pub(crate) mod pickle;
pub(crate) mod torch;

// The checks every weights format makes on a tensor it reads (safetensors in `clip::weights`,
// PyTorch zips in `torch`): here, below both, so that neither imports the other.

/// `got` must equal `want`, except that a scalar (`want == []`) may be stored as `[1]`.
pub(crate) fn check_shape(name: &str, got: &[usize], want: &[usize]) -> Result<(), String> {
    let scalar_ok = want.is_empty() && (got.is_empty() || got == [1]);
    if got == want || scalar_ok {
        Ok(())
    } else {
        Err(format!(
            "tensor \"{name}\" has shape {got:?}, but the config implies {want:?} (is the config \
             file the one that belongs to these weights?)"
        ))
    }
}

/// No NaN or infinity in a weight: they would only show up later as NaN scores.
pub(crate) fn check_finite(name: &str, values: &[f32]) -> Result<(), String> {
    match values.iter().position(|v| !v.is_finite()) {
        Some(i) => Err(format!("tensor \"{name}\" has a non-finite value at {i}")),
        None => Ok(()),
    }
}

/// Stop counting the pages of `map` that `range` touches as this process's memory
/// (`MADV_DONTNEED` where the system has it). Whole pages around the range: a page it shares
/// with a neighbouring tensor is read back from the file if that tensor is read later (also
/// under a slice another thread is reading: a text tower built from the map while another
/// call reads token rows).
pub(crate) fn release(map: &memmap2::Mmap, range: std::ops::Range<usize>) {
    let page = t2tf_core::platform::page_size();
    let first = range.start / page * page;
    let end = range.end.div_ceil(page).saturating_mul(page).min(map.len());
    t2tf_core::platform::release_pages(map, first..end);
}
