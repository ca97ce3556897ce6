//! `report.json`: everything needed to understand and repeat a run (settings, seed, model,
//! versions, the loss curve, CLIP scores at the end, time per phase). Strict JSON.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::settings::Settings;

/// Why `report.json` could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The report did not serialize.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// The file could not be written (`crate::fs`'s error, which names the file).
    #[error(transparent)]
    Write(#[from] crate::fs::FsError),
}

/// Loss terms of one step (each already weighted, so `total` is their sum), averaged over views.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepLog {
    /// 0-based step index.
    pub step: usize,
    /// Learning rate of the step.
    pub lr: f64,
    /// Sum of the terms below.
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
    /// The density initialization.
    pub init: f64,
    /// Text (and reference-image) embeddings, the caption pool included.
    pub text: f64,
    /// Forward renders.
    pub render: f64,
    /// CLIP's image tower, forward.
    pub clip_forward: f64,
    /// CLIP's image tower, backward.
    pub clip_backward: f64,
    /// The renderer's backward.
    pub render_backward: f64,
    /// Everything else (losses, parameterization, SGD, final scores, preview).
    pub other: f64,
    /// Writing the output files.
    pub output: f64,
}

/// CLIP agreement of the final TF with one caption.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Score {
    /// The caption ("reference image" for an image positive).
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
    /// The local model folder, absolute (`None` for a Hub model).
    #[serde(default)]
    pub folder: Option<String>,
    /// The tokenizer.json used, absolute (the model's own, or the one given apart from it).
    #[serde(default)]
    pub tokenizer: Option<String>,
    /// SHA-256 of the weight files, shard after shard (hex): the key of the caption-embedding
    /// cache.
    pub weights_sha256: Option<String>,
    /// SHA-256 of the tokenizer.json used (hex): a `tokenizer` given apart from the model
    /// changes the text embeddings.
    #[serde(default)]
    pub tokenizer_sha256: Option<String>,
    /// CLIP's logit scale (exp of the stored parameter).
    pub logit_scale: f64,
}

/// The volume used.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct VolumeInfo {
    /// The file, absolute ("(in memory)" for an array).
    pub path: String,
    /// Points along x, y, z.
    pub dims: [usize; 3],
    /// Point spacing along x, y, z.
    pub spacing: [f64; 3],
    /// A raw file's scalar type as read (`uint8`, `float32`, …).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dtype: Option<String>,
    /// A raw file's byte order as read (`little` or `big`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub byte_order: Option<String>,
    /// The point-data array read from a `.vti` or legacy `.vtk` file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub array: Option<String>,
    /// Finite data range.
    pub range: [f64; 2],
    /// Voxels that are NaN or infinite (left out of the range and histogram).
    pub non_finite_voxels: usize,
}

/// The time series a run optimized one TF for.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeSeriesInfo {
    /// The `.pvd` or `.series` file, absolute; absent for a list of files.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub collection: Option<String>,
    /// Steps in the whole series (before `--time-range` / `--time-steps`).
    pub total_steps: usize,
    /// Data range over the steps used (the TF's range).
    pub range: [f64; 2],
    /// Times a step was read from its file during the run.
    pub loads: usize,
    /// The steps used, in time order.
    pub steps: Vec<TimeStepInfo>,
}

/// One step of a time series in report.json.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TimeStepInfo {
    /// Its time value.
    pub time: f64,
    /// Its file, absolute.
    pub path: String,
    /// Its own finite data range.
    pub range: [f64; 2],
    /// Views of the run that rendered it.
    pub views: usize,
    /// The final TF's scores on this step alone (prompt first, then the user's negatives).
    pub final_scores: Vec<Score>,
}

/// The machine a run ran on: what decides which CLIP kernel runs and so the last bits of
/// the result.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MachineInfo {
    /// The CPU's model name (`/proc/cpuinfo` on Linux, the system's name for it elsewhere),
    /// where the system says.
    pub cpu_model: Option<String>,
    /// The CPU's feature flags (all of `/proc/cpuinfo`'s on Linux; elsewhere those the
    /// kernels dispatch on, spelled as Linux does).
    pub cpu_flags: Vec<String>,
    /// Logical CPUs the process may use.
    pub logical_cpus: usize,
    /// Operating system and architecture (`linux x86_64`).
    pub os: String,
}

impl MachineInfo {
    /// This machine.
    pub fn detect() -> MachineInfo {
        let cpu = t2tf_core::platform::cpu();
        MachineInfo {
            cpu_model: cpu.model,
            cpu_flags: cpu.flags,
            logical_cpus: std::thread::available_parallelism().map_or(1, |n| n.get()),
            os: format!("{} {}", std::env::consts::OS, std::env::consts::ARCH),
        }
    }
}

/// Result of the density initialization.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InitInfo {
    /// The common density scale found.
    pub scale: f64,
    /// Mean T_N of view V0 at that scale.
    pub mean_transmittance: f64,
    /// Renders the search took.
    pub evaluations: usize,
    /// Whether ρ was reached (false: even the densest TF leaves more light through).
    pub reached: bool,
}

/// A file a run read, to find it again and to tell whether it changed since.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct InputFile {
    /// The file, absolute.
    pub path: String,
    /// SHA-256 of its bytes (hex).
    pub sha256: String,
}

impl InputFile {
    /// `path` made absolute (against the current folder, links kept) and its bytes hashed.
    pub fn read(path: &Path) -> std::io::Result<InputFile> {
        use sha2::Digest;
        let mut file = std::fs::File::open(path)?;
        let mut hash = sha2::Sha256::new();
        std::io::copy(&mut file, &mut hash)?;
        Ok(InputFile {
            path: absolute(path),
            sha256: hash.finalize().iter().map(|b| format!("{b:02x}")).collect(),
        })
    }
}

/// `path` absolute against the current folder (not resolving links), as text; the path as
/// given where the current folder cannot be read.
pub fn absolute(path: &Path) -> String {
    std::path::absolute(path)
        .unwrap_or_else(|_| path.to_path_buf())
        .display()
        .to_string()
}

// A struct of documented output fields, shaped like formats::WrittenFiles: alike in form only.
/// The whole report.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Report {
    /// "t2tf".
    pub tool: String,
    /// The crate version that wrote the report.
    pub version: String,
    /// The git commit it was built from ("unknown" outside a git checkout).
    #[serde(default)]
    pub commit: String,
    /// The machine it ran on.
    #[serde(default)]
    pub machine: MachineInfo,
    /// The command line as given, program name first (a run of `t2tf optimize`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub argv: Option<Vec<String>>,
    /// The folder the run started in: relative paths of `argv` are relative to it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cwd: Option<String>,
    /// The arguments of the Python call that ran it (`t2tf.optimize`), by keyword.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub python_call: Option<serde_json::Value>,
    /// The text prompt (absent in reference-image mode).
    pub prompt: Option<String>,
    /// The reference image as given (reference-image mode).
    pub reference_image: Option<String>,
    /// The reference image, absolute, and its hash (reference-image mode).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_image_file: Option<InputFile>,
    /// The user's negatives (default "a blank image").
    pub negatives: Vec<String>,
    /// "builtin" or the `--negatives-file` path, absolute.
    pub caption_pool: String,
    /// The `--negatives-file`, absolute, and its hash.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub negatives_file: Option<InputFile>,
    /// Captions in the pool.
    pub caption_pool_size: usize,
    /// The CLIP model; `None` (null) when the run needed none (0 steps from a TF with
    /// opacity: no step, no CLIP score).
    pub model: Option<ModelInfo>,
    /// The volume.
    pub volume: VolumeInfo,
    /// The optimizer's settings.
    pub settings: Settings,
    /// Renderer settings: as given (`up`, `step_size`, `level`, `render_size`, `max_memory`)
    /// and as used (`step_voxels`, image size, LUT size, threads, CLIP's engine and precision).
    pub render: serde_json::Value,
    /// What the density initialization found.
    pub initialization: InitInfo,
    /// The TF the run started from instead of the paper's initialization (file, absolute,
    /// and the preset's name in it); absent for a fresh run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init: Option<String>,
    /// The start's file, absolute, and its hash (absent for a fresh run and for a start
    /// given as a Python `TransferFunction`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_file: Option<InputFile>,
    /// The name of the preset of `init_file` the run started from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_preset: Option<String>,
    /// Data ranges [min, max] whose TF the run kept as it started.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub locks: Vec<[f64; 2]>,
    /// One log per step run.
    pub steps: Vec<StepLog>,
    /// Steps actually run (< settings.steps after Ctrl-C).
    pub steps_run: usize,
    /// True when a stop signal ended the run early.
    pub interrupted: bool,
    /// Prompt first, then the user's negatives, on the evaluation views (for a time series,
    /// averaged over its steps).
    pub final_scores: Vec<Score>,
    /// For a time series: the steps used, each with its time, file and final scores.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub time_series: Option<TimeSeriesInfo>,
    /// Wall time per phase.
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
            // Set by build.rs.
            commit: env!("T2TF_GIT_COMMIT").into(),
            machine: MachineInfo::detect(),
            caption_pool: "builtin".into(),
            settings,
            render: serde_json::Value::Null,
            ..Report::default()
        }
    }

    /// Write pretty strict JSON atomically (serde_json writes non-finite floats as null).
    pub fn write(&self, path: &Path) -> Result<(), ReportError> {
        let mut bytes = serde_json::to_vec_pretty(self)?;
        bytes.push(b'\n');
        Ok(crate::fs::atomic_write_bytes(path, &bytes)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_report_says_what_built_it_and_where_it_ran() {
        let r = Report::new(Settings::default());
        assert_eq!(r.version, env!("CARGO_PKG_VERSION"));
        // A 40-hex commit in a git checkout, "unknown" in a source tarball.
        assert!(
            r.commit == "unknown"
                || (r.commit.len() == 40 && r.commit.bytes().all(|b| b.is_ascii_hexdigit())),
            "{}",
            r.commit
        );
        assert!(r.machine.logical_cpus >= 1);
        if cfg!(target_arch = "x86_64") {
            assert!(
                r.machine.cpu_flags.iter().any(|f| f == "sse2"),
                "{:?}",
                r.machine
            );
        }
    }

    #[test]
    fn an_input_file_is_recorded_absolute_with_its_hash() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("abc.txt");
        std::fs::write(&path, b"abc").unwrap();
        let f = InputFile::read(&path).unwrap();
        // FIPS 180-2's example digest of "abc".
        assert_eq!(
            f.sha256,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(Path::new(&f.path), path);
        assert!(Path::new(&absolute(Path::new("x.json"))).is_absolute());
        assert!(InputFile::read(&dir.path().join("missing")).is_err());
    }

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
