//! `report.json`: everything needed to understand and repeat a run (settings, seed, model,
//! versions, the loss curve, CLIP scores at the end, time per phase). Strict JSON.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::settings::Settings;

/// Loss terms of one step (each already weighted, so `total` is their sum), averaged over views.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepLog {
    /// 0-based step index.
    pub step: usize,
    pub lr: f64,
    pub total: f64,
    /// Contrastive cross-entropy.
    pub clip: f64,
    /// prior_weight · Beta prior (0 before `prior_start`).
    pub prior: f64,
    /// λ1 ‖σ‖₁.
    pub l1: f64,
    /// λ2 ‖c − 0.5‖².
    pub l2: f64,
    /// Softmax probability of the prompt among prompt + negatives.
    pub prompt_probability: f64,
    /// Mean T_N over the pixels of the step's views.
    pub mean_transmittance: f64,
    /// Euclidean norm of the parameter gradient.
    pub grad_norm: f64,
    /// Wall time of the step in seconds.
    pub seconds: f64,
}

/// Wall time per phase in seconds, summed over the run.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PhaseTimes {
    pub init: f64,
    pub text: f64,
    pub render: f64,
    pub clip_forward: f64,
    pub clip_backward: f64,
    pub render_backward: f64,
    pub other: f64,
    pub output: f64,
}

/// CLIP agreement of the final TF with one caption.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Score {
    pub caption: String,
    /// Mean cosine similarity over the evaluation views.
    pub cosine: f64,
    /// logit_scale · cosine.
    pub logit: f64,
}

/// The model used.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ModelInfo {
    /// Hugging Face repo id or local directory as given.
    pub id: String,
    /// The Hub revision asked for (`None` for a local directory).
    #[serde(default)]
    pub revision: Option<String>,
    /// SHA-256 of the weight files, shard after shard (hex): the key of the caption-embedding
    /// cache.
    pub weights_sha256: Option<String>,
    pub logit_scale: f64,
}

/// The volume used.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VolumeInfo {
    pub path: String,
    pub dims: [usize; 3],
    pub spacing: [f64; 3],
    /// Finite data range.
    pub range: [f64; 2],
    pub non_finite_voxels: usize,
}

/// Result of the density initialization.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InitInfo {
    pub scale: f64,
    pub mean_transmittance: f64,
    pub evaluations: usize,
    pub reached: bool,
}

/// The whole report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Report {
    pub tool: String,
    pub version: String,
    /// The text prompt (absent in reference-image mode).
    pub prompt: Option<String>,
    /// The reference image (reference-image mode).
    pub reference_image: Option<String>,
    /// The user's negatives (default "a blank image").
    pub negatives: Vec<String>,
    /// "builtin" or the `--negatives-file` path.
    pub caption_pool: String,
    pub caption_pool_size: usize,
    pub model: ModelInfo,
    pub volume: VolumeInfo,
    pub settings: Settings,
    /// Renderer settings as the CLI passed them (step size, level, threads, image size).
    pub render: serde_json::Value,
    pub initialization: InitInfo,
    pub steps: Vec<StepLog>,
    /// Steps actually run (< settings.steps after Ctrl-C).
    pub steps_run: usize,
    pub interrupted: bool,
    /// Prompt first, then the user's negatives, on the evaluation views.
    pub final_scores: Vec<Score>,
    pub timings: PhaseTimes,
    /// Files written (names inside the output folder).
    pub outputs: Vec<String>,
}

impl Report {
    /// A report with the tool name and version filled in.
    pub fn new(settings: Settings) -> Report {
        Report {
            tool: "t2tf".into(),
            version: env!("CARGO_PKG_VERSION").into(),
            caption_pool: "builtin".into(),
            settings,
            render: serde_json::Value::Null,
            ..Report::default()
        }
    }

    /// Write pretty strict JSON atomically (serde_json writes non-finite floats as null).
    pub fn write(&self, path: &Path) -> anyhow::Result<()> {
        let mut bytes = serde_json::to_vec_pretty(self)?;
        bytes.push(b'\n');
        crate::formats::atomic_write_bytes(path, &bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_round_trips_as_strict_json() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = Report::new(Settings::default());
        r.prompt = Some("a potted tree".into());
        r.steps.push(StepLog {
            step: 0,
            lr: 10.0,
            total: 4.9,
            clip: f64::NAN,
            ..StepLog::default()
        });
        let p = dir.path().join("report.json");
        r.write(&p).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(!text.contains("NaN"));
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["settings"]["steps"], 300);
        assert_eq!(v["settings"]["lr"], 10.0);
        assert_eq!(v["prompt"], "a potted tree");
        assert_eq!(v["steps"][0]["clip"], serde_json::Value::Null);
        assert_eq!(v["tool"], "t2tf");
        assert_eq!(v["version"], env!("CARGO_PKG_VERSION"));
    }
}
