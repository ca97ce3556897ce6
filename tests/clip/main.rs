//! Integration tests: CLIP: transformers and OpenCLIP parity, backward, kernels, families, preprocessing, tokenizer.
//!
//! One test binary per area (`cargo test --release --test clip`); each
//! module covers one subject, so a test's name is `MODULE::TEST`.

mod clip_backward;
mod clip_cli;
mod clip_families;
mod clip_golden;
mod clip_kernels;
mod clip_openclip;
mod clip_preprocess;
mod clip_tokenizer;
