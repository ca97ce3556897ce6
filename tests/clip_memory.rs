//! Loading a checkpoint costs at most a quarter of its size in memory on top of what the model
//! keeps: tensors are widened one at a time from the memory-mapped file, never from a second
//! copy, and each tensor's pages of the map stop counting once it is copied (without that the
//! whole file's pages count until the map is dropped: about 1× the file). What the model keeps
//! with `Compute::one_copy` is one copy of the weights (the text tower only runs forward and
//! keeps no backward copy; the image tower's f32 backward reads the forward's packed panels).
//!
//! The text tower is built when texts are encoded and freed by `release_text`, reading only the
//! token table's rows it needs.
//!
//! Its own test binary (one test) so that the process's peak resident set (VmHWM in
//! /proc/self/status, reset through /proc/self/clear_refs) is this load's alone.

use std::cell::RefCell;
use std::path::Path;

use safetensors::tensor::TensorView;
use safetensors::Dtype;
use t2tf::clip::{ClipConfig, ModelFiles, RandomSource, TensorSource};

/// Records the names and shapes the model asks for; hands out zeros.
struct Recorder(RefCell<Vec<(String, Vec<usize>)>>);

impl TensorSource for Recorder {
    fn tensor(&self, name: &str, shape: &[usize]) -> Result<Vec<f32>, t2tf::clip::ClipError> {
        self.0.borrow_mut().push((name.to_string(), shape.to_vec()));
        Ok(vec![0.0; shape.iter().product::<usize>().max(1)])
    }
}

fn status_kb(field: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// A mid-sized CLIP (about 36 M parameters, 145 MB in f32): big enough that a second copy of
/// the file would stand out against the allocator's noise, small enough for a test.
fn config() -> ClipConfig {
    let mut c = ClipConfig::vit_b32();
    c.text.tower.hidden_size = 256;
    c.text.tower.intermediate_size = 1024;
    c.text.tower.num_layers = 4;
    c.text.tower.num_heads = 4;
    c.vision.tower.num_layers = 5;
    c.projection_dim = 256;
    c
}

#[test]
fn loading_needs_at_most_a_quarter_of_the_file_beyond_the_model() {
    // Peak RSS resets need Linux's clear_refs; say so and stop elsewhere.
    if std::fs::write("/proc/self/clear_refs", "5").is_err() || status_kb("VmHWM:").is_none() {
        eprintln!("skipped: /proc/self/clear_refs or VmHWM unavailable on this system");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let cfg = config();
    let names = Recorder(RefCell::new(Vec::new()));
    let compute = t2tf::clip::Compute::default().with_one_copy(true);
    drop(t2tf::clip::Clip::from_source_with(cfg.clone(), &names, compute).unwrap());
    let weights = dir.path().join("model.safetensors");
    {
        let random = RandomSource::new(1);
        let data: Vec<(String, Vec<usize>, Vec<u8>)> = names
            .0
            .borrow()
            .iter()
            .map(|(n, s)| {
                let v = random.tensor(n, s).unwrap();
                (
                    n.clone(),
                    s.clone(),
                    v.iter().flat_map(|x| x.to_le_bytes()).collect(),
                )
            })
            .collect();
        let views: Vec<(String, TensorView)> = data
            .iter()
            .map(|(n, s, b)| {
                (
                    n.clone(),
                    TensorView::new(Dtype::F32, s.clone(), b).unwrap(),
                )
            })
            .collect();
        safetensors::serialize_to_file(views, None, &weights).unwrap();
    }
    let file_kb = std::fs::metadata(&weights).unwrap().len() / 1024;
    assert!(
        file_kb > 100_000,
        "the test model is too small to measure: {file_kb} KB"
    );
    std::fs::write(dir.path().join("config.json"), config_json(&cfg)).unwrap();
    let files = ModelFiles {
        layout: t2tf::clip::Layout::Transformers,
        config: dir.path().join("config.json"),
        weights: vec![weights],
        format: t2tf::clip::load::WeightFormat::Safetensors,
        tokenizer: Path::new("../shared/data/clip/tokenizer.json").to_path_buf(),
        preprocessor: None,
    };

    std::fs::write("/proc/self/clear_refs", "5").unwrap();
    let clip = t2tf::clip::Clip::load_files_with(&files, compute).unwrap();
    let peak = status_kb("VmHWM:").unwrap();
    // What the model keeps: resident now that the file is unmapped.
    let kept = status_kb("VmRSS:").unwrap();
    // One copy of each weight is the f32 file's size; the rest of the process (test harness,
    // tokenizer, heap slack) measures about 0.35× the file here; with a backward copy of every
    // linear layer it is 2.2×.
    assert!(
        kept as f64 <= 1.6 * file_kb as f64,
        "{kept} KB resident after the load, more than 1.6× the {file_kb} KB file: a second copy of weights"
    );
    let transient = peak.saturating_sub(kept);
    eprintln!(
        "file {file_kb} KB; resident after load {kept} KB; peak {peak} KB; transient {transient} KB = {:.2}× the file",
        transient as f64 / file_kb as f64
    );
    assert!(
        transient as f64 <= 0.25 * file_kb as f64,
        "loading needed {transient} KB beyond what the model keeps, more than 0.25× the {file_kb} KB file"
    );
    assert_eq!(clip.config(), &cfg);

    // The text tower is built when texts are encoded, reads only its tokens' rows of the
    // token table (49,408 × 256 here: 48 MiB), and is freed by `release_text`.
    let t = &cfg.text.tower;
    let text_kb =
        (t.num_layers * (4 * t.hidden_size.pow(2) + 2 * t.hidden_size * t.intermediate_size) * 4
            / 1024) as u64;
    let table_kb = (cfg.text.vocab_size * t.hidden_size * 4 / 1024) as u64;
    let before = status_kb("VmRSS:").unwrap();
    let first = clip.encode_text(&["a photo of a skull"]).unwrap();
    let with_text = status_kb("VmRSS:").unwrap();
    eprintln!(
        "text tower {text_kb} KB, token table {table_kb} KB; resident {before} KB before \
         encoding, {with_text} KB with the text tower"
    );
    assert!(
        with_text <= before + text_kb + table_kb / 4,
        "encoding one caption took {} KB: the token table ({table_kb} KB) was read whole",
        with_text.saturating_sub(before)
    );
    clip.release_text();
    let after = status_kb("VmRSS:").unwrap();
    eprintln!("resident after release_text: {after} KB");
    assert!(
        after <= before + text_kb / 2,
        "release_text left {} KB of the {text_kb} KB text tower resident",
        after.saturating_sub(before)
    );
    assert_eq!(clip.encode_text(&["a photo of a skull"]).unwrap(), first);
}

/// The config as transformers writes it (only the fields that differ from the defaults matter).
fn config_json(c: &ClipConfig) -> String {
    serde_json::json!({
        "model_type": "clip",
        "projection_dim": c.projection_dim,
        "text_config": {
            "hidden_size": c.text.tower.hidden_size,
            "intermediate_size": c.text.tower.intermediate_size,
            "num_hidden_layers": c.text.tower.num_layers,
            "num_attention_heads": c.text.tower.num_heads,
            "eos_token_id": c.text.eos_token_id,
        },
        "vision_config": {
            "num_hidden_layers": c.vision.tower.num_layers,
        },
    })
    .to_string()
}
