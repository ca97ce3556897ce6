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
