//! Finding a model's files: a local directory, or a Hugging Face repo id at a revision, through
//! the Hub cache shared with Python (`crate::hub`).
//!
//! Two layouts are read:
//!
//! - **transformers** (`CLIPModel.save_pretrained`): `config.json`, and weights looked for in
//!   transformers' order (`modeling_utils.PreTrainedModel.from_pretrained`):
//!   `model.safetensors`, `model.safetensors.index.json` (shards), `pytorch_model.bin`,
//!   `pytorch_model.bin.index.json`. The first that exists wins.
//! - **OpenCLIP** (`crate::openclip`): `open_clip_config.json` with
//!   `open_clip_model.safetensors`, `open_clip_pytorch_model.safetensors` or
//!   `open_clip_pytorch_model.bin`. Some LAION repositories ship only this layout
//!   (`laion/CLIP-ViT-g-14-laion2B-s34B-b88K`: `open_clip_config.json`, `tokenizer.json` and
//!   `open_clip_pytorch_model.bin`, no `config.json` seen), others both (the s12B-b42K ViT-g/14
//!   repository has `config.json`, `pytorch_model.bin` and `model.safetensors` next to
//!   `open_clip_config.json`, `open_clip_pytorch_model.bin` and
//!   `open_clip_pytorch_model.safetensors`).
//!
//! transformers' layout is tried first; where a source has no `config.json`, or a
//! `config.json` but none of transformers' weight files, OpenCLIP's is tried. Both need
//! `tokenizer.json`. Where neither is complete, the error lists every file looked for.

use std::path::{Path, PathBuf};

use serde::Deserialize;
#[cfg(feature = "hub")]
use t2tf_core::error::ErrorKind;
use t2tf_core::error::Hint;

use super::config::ClipConfig;
use super::openclip::{self, OpenClipConfig};
use super::preprocess::Preprocessing;
use super::ClipError;
#[cfg(feature = "hub")]
use crate::hub::{Hub, HubError, HubRepo, HubSettings};

/// The default model (`--model` left out): OpenAI's CLIP ViT-B/32, the paper's model.
///
/// Its `main` branch has no `model.safetensors` (the Hub answers 404; transformers then falls
/// back to `pytorch_model.bin`), but it has had `pytorch_model.bin` (~600 MB) since 2021:
/// public download scripts fetch `.../clip-vit-base-patch32/resolve/main/pytorch_model.bin`,
/// and its LFS sha256 a6308213…576f appears in users' cache paths. We stay on `main` and let
/// the weight order above find the `.bin` rather than pinning a pull-request revision
/// (`refs/pr/15`, which candle's example uses for its safetensors): a PR ref can be closed or
/// rewritten, while `main` is what the model's owners maintain, and a safetensors file merged
/// into `main` later is picked up first. `--revision refs/pr/15` works as well.
pub const DEFAULT_MODEL: &str = "openai/clip-vit-base-patch32";

/// The revision used when none is given.
pub const DEFAULT_REVISION: &str = "main";

const CONFIG: &str = "config.json";
const TOKENIZER: &str = "tokenizer.json";
/// Optional: the image processor's statistics and sizes (`Preprocessing`); CLIP's constants
/// where a model has none.
const PREPROCESSOR: &str = "preprocessor_config.json";

/// Weight files in the order transformers tries them; `true` for an index naming shards.
pub const WEIGHT_FILES: [(&str, WeightFormat, bool); 4] = [
    ("model.safetensors", WeightFormat::Safetensors, false),
    (
        "model.safetensors.index.json",
        WeightFormat::Safetensors,
        true,
    ),
    ("pytorch_model.bin", WeightFormat::PyTorch, false),
    ("pytorch_model.bin.index.json", WeightFormat::PyTorch, true),
];

/// What the user asked for: `--model`, `--revision`, `--tokenizer`.
#[derive(Clone, Debug)]
pub struct ModelRequest {
    /// A directory, or a Hugging Face repo id such as `openai/clip-vit-base-patch32`.
    pub model: String,
    /// Branch, tag, `refs/pr/N` or commit; only for repo ids.
    pub revision: String,
    /// `tokenizer.json` to use instead of the model's own.
    pub tokenizer: Option<PathBuf>,
    /// How to reach the Hub and where its cache is, for a repo id. [`ModelRequest::new`] gives
    /// the public Hub and Python's default cache folder; a front end that honours the
    /// `HF_*` variables passes [`HubSettings::from_env`].
    #[cfg(feature = "hub")]
    pub hub: HubSettings,
}

impl ModelRequest {
    /// `model` at the default revision, with its own tokenizer, the public Hub and the
    /// default cache (no environment variable read).
    pub fn new(model: &str) -> ModelRequest {
        ModelRequest {
            model: model.to_string(),
            revision: DEFAULT_REVISION.to_string(),
            tokenizer: None,
            #[cfg(feature = "hub")]
            hub: HubSettings::defaults(),
        }
    }
}

/// How the weights are stored.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WeightFormat {
    /// `*.safetensors`.
    Safetensors,
    /// PyTorch's `torch.save` zip (`pytorch_model.bin`).
    PyTorch,
}

/// Which program's files a model comes as: they name the config and the tensors differently.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// transformers' `CLIPModel`: `config.json`, `model.safetensors` / `pytorch_model.bin`.
    Transformers,
    /// OpenCLIP's: `open_clip_config.json`, `open_clip_model.safetensors` /
    /// `open_clip_pytorch_model.bin`, OpenCLIP's tensor names.
    OpenClip,
}

/// Paths of the files a model needs.
#[derive(Clone, Debug)]
pub struct ModelFiles {
    /// Whose layout the config and weights are in.
    pub layout: Layout,
    /// `config.json`, or `open_clip_config.json` for OpenCLIP's layout.
    pub config: PathBuf,
    /// One file, or every shard an index names, in the index's order.
    pub weights: Vec<PathBuf>,
    /// How the weights are stored.
    pub format: WeightFormat,
    /// `tokenizer.json` (the model's own or `--tokenizer`).
    pub tokenizer: PathBuf,
    /// `preprocessor_config.json`, where the model has one (transformers' layout; OpenCLIP's
    /// config holds its own `preprocess_cfg`).
    pub preprocessor: Option<PathBuf>,
}

impl ModelFiles {
    /// The architecture the config file describes, whichever the layout.
    pub fn read_config(&self) -> Result<ClipConfig, ClipError> {
        Ok(self.read_config_and_preprocessing()?.0)
    }

    /// The architecture, and the image processing where the files say one (else CLIP's).
    pub(crate) fn read_config_and_preprocessing(
        &self,
    ) -> Result<(ClipConfig, Option<Preprocessing>), ClipError> {
        match self.layout {
            Layout::Transformers => {
                let config = ClipConfig::from_file(&self.config)?;
                let prep = self
                    .preprocessor
                    .as_deref()
                    .map(|p| Preprocessing::from_file(p, config.vision.image_size))
                    .transpose()?;
                Ok((config, prep))
            }
            Layout::OpenClip => {
                let c = OpenClipConfig::from_file(&self.config)?;
                Ok((c.clip, Some(c.preprocessing)))
            }
        }
    }
}

/// Resolve a request with its Hub settings.
#[cfg(feature = "hub")]
pub fn resolve(req: &ModelRequest) -> Result<ModelFiles, ClipError> {
    resolve_with(req, &Hub::new(req.hub.clone()))
}

/// Resolve a request: a local folder only (this build has no Hub client, feature `hub`).
#[cfg(not(feature = "hub"))]
pub fn resolve(req: &ModelRequest) -> Result<ModelFiles, ClipError> {
    if let Some(files) = resolve_local(req)? {
        return Ok(files);
    }
    Err(ClipError::Request {
        message: format!(
            "{}: not a local model folder, and this build has no Hugging Face Hub client \
             (feature `hub` of t2tf-clip)",
            req.model
        ),
        hint: Hint::invalid("model"),
    })
}

/// Resolve a request; repo ids go through `hub`.
#[cfg(feature = "hub")]
pub fn resolve_with(req: &ModelRequest, hub: &Hub) -> Result<ModelFiles, ClipError> {
    if let Some(files) = resolve_local(req)? {
        return Ok(files);
    }
    let repo = hub.repo(&req.model, &req.revision);
    resolve_files(
        &RepoFiles {
            repo,
            offline: hub.settings().offline,
        },
        req.tokenizer.as_deref(),
    )
}

/// A request for a local folder resolved; `None` for a Hub repo id; an error for anything
/// else.
fn resolve_local(req: &ModelRequest) -> Result<Option<ModelFiles>, ClipError> {
    let path = Path::new(&req.model);
    if path.is_dir() {
        check_dir(path, req.tokenizer.is_some())?;
        return resolve_files(&LocalDir(path), req.tokenizer.as_deref()).map(Some);
    }
    if path.exists() {
        return Err(ClipError::Request {
            message: format!(
                "{}: is a file; a `model` is a directory holding {CONFIG}, {TOKENIZER} and the \
                 weights, or a Hugging Face repo id such as {DEFAULT_MODEL}",
                req.model
            ),
            hint: Hint::invalid("model"),
        });
    }
    if !looks_like_repo_id(&req.model) {
        return Err(ClipError::Request {
            message: format!(
                "{}: no such directory, and not a Hugging Face repo id (owner/name)",
                req.model
            ),
            hint: Hint::invalid("model"),
        });
    }
    Ok(None)
}

/// Everything a model directory lacks, said at once.
fn check_dir(dir: &Path, own_tokenizer: bool) -> Result<(), ClipError> {
    // A name that is there but not a regular file (a pipe would block the read): said as such.
    let names = [CONFIG, TOKENIZER, openclip::CONFIG]
        .into_iter()
        .chain(WEIGHT_FILES.iter().map(|w| w.0))
        .chain(openclip::WEIGHT_FILES.iter().map(|w| w.0));
    for name in names {
        let path = dir.join(name);
        if let Ok(meta) = std::fs::metadata(&path) {
            t2tf_core::input::regular(&meta).map_err(|e| ClipError::Io { path, source: e })?;
        }
    }
    let has = |name: &str| dir.join(name).is_file();
    let transformers = has(CONFIG) && WEIGHT_FILES.iter().any(|w| has(w.0));
    let open_clip = has(openclip::CONFIG) && openclip::WEIGHT_FILES.iter().any(|w| has(w.0));
    let mut missing = Vec::new();
    // The option that fixes it: a `tokenizer` where that alone is missing, else the `model`.
    let mut option = "model";
    if !transformers && !open_clip {
        let (config, weights): (&str, Vec<&str>) = if has(openclip::CONFIG) && !has(CONFIG) {
            (
                openclip::CONFIG,
                openclip::WEIGHT_FILES.iter().map(|w| w.0).collect(),
            )
        } else {
            (CONFIG, WEIGHT_FILES.iter().map(|w| w.0).collect())
        };
        if !has(config) {
            missing.push(format!("{CONFIG} (or OpenCLIP's {})", openclip::CONFIG));
        }
        missing.push(format!("weights (one of {})", weights.join(", ")));
    }
    if !own_tokenizer && !has(TOKENIZER) {
        if missing.is_empty() {
            option = "tokenizer";
        }
        missing.push(format!("{TOKENIZER} (or give a `tokenizer`)"));
    }
    if missing.is_empty() {
        Ok(())
    } else {
        Err(ClipError::Request {
            message: format!(
                "model directory {} is incomplete: missing {} (a CLIP model folder holds what \
                 transformers' CLIPModel.save_pretrained or OpenCLIP's save_for_hf writes)",
                dir.display(),
                missing.join(", ")
            ),
            hint: Hint::invalid(option),
        })
    }
}

/// Where files come from: a directory or a Hub repo at a revision.
trait FileSource {
    /// `Ok(None)`: the source does not have this file.
    fn get(&self, name: &str) -> Result<Option<PathBuf>, ClipError>;
    /// `Ok(None)` also where the source cannot tell without a network (offline, not cached):
    /// used to probe the weight files in order, keeping the error for when none is found.
    fn probe(&self, name: &str) -> Result<Option<PathBuf>, ClipError> {
        self.get(name)
    }
    /// "directory X" or "repo R at revision V", for messages.
    fn describe(&self) -> String;
    /// What to say when none of the weight files was found.
    fn no_weights(&self, tried: &str) -> ClipError {
        ClipError::Missing(format!(
            "{} has no weights: none of {tried}",
            self.describe()
        ))
    }
}

struct LocalDir<'a>(&'a Path);

impl FileSource for LocalDir<'_> {
    fn get(&self, name: &str) -> Result<Option<PathBuf>, ClipError> {
        let p = self.0.join(name);
        Ok(p.is_file().then_some(p))
    }
    fn describe(&self) -> String {
        format!("model directory {}", self.0.display())
    }
}

#[cfg(feature = "hub")]
struct RepoFiles<'a> {
    repo: HubRepo<'a>,
    offline: bool,
}

#[cfg(feature = "hub")]
impl FileSource for RepoFiles<'_> {
    fn get(&self, name: &str) -> Result<Option<PathBuf>, ClipError> {
        Ok(self.repo.get(name)?)
    }
    fn probe(&self, name: &str) -> Result<Option<PathBuf>, ClipError> {
        match self.repo.get(name) {
            Err(HubError::NotCached { .. }) if self.offline => Ok(None),
            r => Ok(r?),
        }
    }
    fn describe(&self) -> String {
        self.repo.describe()
    }
    fn no_weights(&self, tried: &str) -> ClipError {
        if !self.offline {
            return ClipError::Missing(format!(
                "{} has no weights: none of {tried}",
                self.describe()
            ));
        }
        ClipError::Request {
            message: format!(
                "{} has no weights: none of {tried} in the Hugging Face cache {}, and offline \
                 mode is on (HF_HUB_OFFLINE)",
                self.describe(),
                self.repo.cache_folder().display()
            ),
            hint: Hint::new(ErrorKind::ModelUnavailable {
                repo: self.repo.id().to_string(),
                offline: true,
            })
            .about("model"),
        }
    }
}

fn resolve_files(src: &dyn FileSource, tokenizer: Option<&Path>) -> Result<ModelFiles, ClipError> {
    let (layout, config, weights, format) = find_layout(src)?;
    // Optional: absent (a 404 from the Hub, remembered in the cache like any missing file, or
    // offline and never fetched) means CLIP's constants. OpenCLIP's config has its own.
    let preprocessor = match layout {
        Layout::Transformers => src.probe(PREPROCESSOR)?,
        Layout::OpenClip => None,
    };
    let tokenizer = match tokenizer {
        Some(t) => t.to_path_buf(),
        None => src.get(TOKENIZER)?.ok_or_else(|| ClipError::Request {
            message: format!(
                "{} has no {TOKENIZER} (a CLIP model has a config, {TOKENIZER} and its \
                 weights); a `tokenizer` can point to a tokenizer.json",
                src.describe()
            ),
            hint: Hint::invalid("tokenizer"),
        })?,
    };
    Ok(ModelFiles {
        layout,
        config,
        weights,
        format,
        tokenizer,
        preprocessor,
    })
}

/// The first complete layout of the source: transformers' (`config.json` and one of its weight
/// files), else OpenCLIP's (`open_clip_config.json` and one of its weight files).
fn find_layout(
    src: &dyn FileSource,
) -> Result<(Layout, PathBuf, Vec<PathBuf>, WeightFormat), ClipError> {
    let transformers_config = src.probe(CONFIG)?;
    if let Some(config) = &transformers_config {
        if let Some((weights, format)) = find_weights(src)? {
            return Ok((Layout::Transformers, config.clone(), weights, format));
        }
    }
    let open_clip_config = src.probe(openclip::CONFIG)?;
    if let Some(config) = &open_clip_config {
        for (name, format) in openclip::WEIGHT_FILES {
            if let Some(path) = src.probe(name)? {
                return Ok((Layout::OpenClip, config.clone(), vec![path], format));
            }
        }
    }
    let transformers_weights: Vec<&str> = WEIGHT_FILES.iter().map(|w| w.0).collect();
    let open_clip_weights: Vec<&str> = openclip::WEIGHT_FILES.iter().map(|w| w.0).collect();
    if transformers_config.is_none() && open_clip_config.is_none() {
        // Neither config: ask for config.json as a required file, so that offline the cache's
        // own message (what is missing, where it looked) is what the user sees.
        src.get(CONFIG)?;
        return Err(ClipError::Missing(format!(
            "{} has neither {CONFIG} (transformers' CLIPModel) nor {} (OpenCLIP)",
            src.describe(),
            openclip::CONFIG
        )));
    }
    Err(src.no_weights(&format!(
        "{} (with {CONFIG}), nor {} (with {})",
        transformers_weights.join(", "),
        open_clip_weights.join(", "),
        openclip::CONFIG
    )))
}

/// The first weight file of `WEIGHT_FILES` the source has, with its shards if it is an index;
/// `None` where it has none of them.
fn find_weights(src: &dyn FileSource) -> Result<Option<(Vec<PathBuf>, WeightFormat)>, ClipError> {
    for (name, format, sharded) in WEIGHT_FILES {
        let Some(path) = src.probe(name)? else {
            continue;
        };
        if !sharded {
            return Ok(Some((vec![path], format)));
        }
        let mut files = Vec::new();
        for shard in shard_names(&path)? {
            let p = src.get(&shard)?.ok_or_else(|| {
                ClipError::Missing(format!(
                    "{} names shard {shard} in {name}, but {} has no such file",
                    path.display(),
                    src.describe()
                ))
            })?;
            files.push(p);
        }
        return Ok(Some((files, format)));
    }
    Ok(None)
}

#[derive(Deserialize)]
struct ShardIndex {
    weight_map: std::collections::BTreeMap<String, String>,
}

/// The distinct shard files an index names, in first-appearance order of sorted tensor names.
/// Shard names must be plain file names in the same folder (an index is data from the Hub).
fn shard_names(index: &Path) -> Result<Vec<String>, ClipError> {
    let err = |msg: String| ClipError::Weights {
        path: index.to_path_buf(),
        msg,
    };
    let text = t2tf_core::input::read_to_string(index).map_err(|e| ClipError::Io {
        path: index.to_path_buf(),
        source: e,
    })?;
    let parsed: ShardIndex = serde_json::from_str(&text).map_err(|e| {
        err(format!(
            "not a shard index (weight_map of tensor → file): {e}"
        ))
    })?;
    let mut names: Vec<String> = Vec::new();
    for shard in parsed.weight_map.values() {
        let plain =
            !shard.is_empty() && !shard.contains(['/', '\\']) && shard != "." && shard != "..";
        if !plain {
            return Err(err(format!(
                "shard name \"{shard}\" is not a plain file name"
            )));
        }
        if !names.contains(shard) {
            names.push(shard.clone());
        }
    }
    if names.is_empty() {
        return Err(err("the weight_map names no shards".into()));
    }
    Ok(names)
}

/// `owner/name`, each part of letters, digits, `-`, `_` and `.`.
pub fn looks_like_repo_id(s: &str) -> bool {
    let mut parts = s.split('/');
    let ok = |p: Option<&str>| {
        p.is_some_and(|p| {
            !p.is_empty()
                && p != "."
                && p != ".."
                && p.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        })
    };
    ok(parts.next()) && ok(parts.next()) && parts.next().is_none()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(dir: &Path, names: &[&str]) {
        for n in names {
            std::fs::write(dir.join(n), "x").unwrap();
        }
    }

    #[test]
    fn weights_are_found_in_transformers_order() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        touch(d, &[CONFIG, TOKENIZER, "pytorch_model.bin"]);
        let req = ModelRequest::new(d.to_str().unwrap());
        let f = resolve(&req).unwrap();
        assert_eq!(f.format, WeightFormat::PyTorch);
        assert_eq!(f.weights, vec![d.join("pytorch_model.bin")]);
        std::fs::write(
            d.join("model.safetensors.index.json"),
            r#"{"metadata":{},"weight_map":{"b":"model-00002-of-00002.safetensors",
                "a":"model-00001-of-00002.safetensors","c":"model-00001-of-00002.safetensors"}}"#,
        )
        .unwrap();
        let e = resolve(&req).unwrap_err().to_string();
        assert!(e.contains("model-00001-of-00002.safetensors"), "{e}");
        touch(
            d,
            &[
                "model-00001-of-00002.safetensors",
                "model-00002-of-00002.safetensors",
            ],
        );
        let f = resolve(&req).unwrap();
        assert_eq!(f.format, WeightFormat::Safetensors);
        assert_eq!(
            f.weights,
            vec![
                d.join("model-00001-of-00002.safetensors"),
                d.join("model-00002-of-00002.safetensors")
            ]
        );
        touch(d, &["model.safetensors"]);
        assert_eq!(
            resolve(&req).unwrap().weights,
            vec![d.join("model.safetensors")]
        );
    }

    #[test]
    fn transformers_layout_first_then_openclips() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let req = ModelRequest::new(d.to_str().unwrap());
        touch(
            d,
            &[TOKENIZER, openclip::CONFIG, "open_clip_pytorch_model.bin"],
        );
        let f = resolve(&req).unwrap();
        assert_eq!(
            (f.layout, f.format, f.preprocessor.is_none()),
            (Layout::OpenClip, WeightFormat::PyTorch, true)
        );
        assert_eq!(f.config, d.join(openclip::CONFIG));
        touch(d, &["open_clip_model.safetensors", PREPROCESSOR]);
        let f = resolve(&req).unwrap();
        assert_eq!(f.weights, vec![d.join("open_clip_model.safetensors")]);
        assert!(f.preprocessor.is_none(), "OpenCLIP's config has its own");
        // A config.json without transformers' weights: still OpenCLIP's layout.
        touch(d, &[CONFIG]);
        assert_eq!(resolve(&req).unwrap().layout, Layout::OpenClip);
        // Both complete (as the s12B-b42K ViT-g/14 repository is): transformers' layout.
        touch(d, &["pytorch_model.bin"]);
        let f = resolve(&req).unwrap();
        assert_eq!((f.layout, f.config), (Layout::Transformers, d.join(CONFIG)));
        assert_eq!(f.preprocessor, Some(d.join(PREPROCESSOR)));
    }

    #[test]
    fn hostile_shard_names_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        touch(d, &[CONFIG, TOKENIZER]);
        for bad in ["../../etc/passwd", "/etc/passwd", "..", ""] {
            std::fs::write(
                d.join("pytorch_model.bin.index.json"),
                format!(r#"{{"weight_map":{{"a":"{bad}"}}}}"#),
            )
            .unwrap();
            let e = resolve(&ModelRequest::new(d.to_str().unwrap()))
                .unwrap_err()
                .to_string();
            assert!(e.contains("not a plain file name"), "{bad}: {e}");
        }
    }

    #[test]
    fn incomplete_directory_says_what_is_missing() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let req = ModelRequest::new(d.to_str().unwrap());
        let e = resolve(&req).unwrap_err().to_string();
        assert!(
            e.contains(CONFIG) && e.contains(&d.display().to_string()),
            "{e}"
        );
        for w in WEIGHT_FILES {
            assert!(e.contains(w.0), "{e}");
        }
        assert!(e.contains(openclip::CONFIG), "{e}");
        assert!(e.contains(TOKENIZER) && e.contains("`tokenizer`"), "{e}");
        touch(d, &[CONFIG, "model.safetensors"]);
        let e = resolve(&req).unwrap_err().to_string();
        assert!(!e.contains(CONFIG) && e.contains(TOKENIZER), "{e}");
        let e = resolve(&ModelRequest::new("not a repo id at all"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("not a Hugging Face repo id"), "{e}");
        assert!(!looks_like_repo_id("../x") && !looks_like_repo_id("a/b/c"));
        assert!(looks_like_repo_id(
            "laion/CLIP-ViT-bigG-14-laion2B-39B-b160k"
        ));
    }
}
