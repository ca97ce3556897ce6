//! Real CLIP checkpoints the way users get them: from a stand-in for the Hugging Face Hub
//! (tests/hub_server) serving the tiny test CLIP in the layouts real repositories use.
//!
//! - the default model name resolves as on huggingface.co, where `openai/clip-vit-base-patch32`
//!   has `pytorch_model.bin` on `main` and `model.safetensors` only on a pull-request revision;
//! - `.bin`, sharded safetensors, sharded `.bin` and safetensors give bit-identical embeddings;
//! - offline (`HF_HUB_OFFLINE`), a cached model loads with no request at all;
//! - a repository in OpenCLIP's own layout only (`open_clip_config.json` and
//!   `open_clip_pytorch_model.bin`, as `laion/CLIP-ViT-g-14-laion2B-s34B-b88K` ships) loads
//!   through the same fallbacks, and one with both layouts is read as transformers';
//! - a hostile pickle is refused and runs nothing; a cut or corrupted download is never trusted;
//! - the CLI (`clip-score`, `model fetch`, `model list`) does all of it through the `HF_*`
//!   environment variables alone.

use crate::hub_server;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use hub_server::{Fault, HubServer, HubSpec};
use sha2::Digest;
use t2tf::clip::load::{resolve_with, WeightFormat};
use t2tf::clip::{Clip, ModelRequest, DEFAULT_MODEL};
use t2tf::hub::{Hub, HubSettings};
use t2tf::image::Image;

const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const MODEL_DIR: &str = "tests/fixtures/clip/quick_gelu";
const CHECKPOINTS: &str = "tests/fixtures/clip/checkpoints";
const OPENCLIP_DIR: &str = "tests/fixtures/clip/openclip";

/// OpenCLIP's Hub layout: its config, the tokenizer and `open_clip_pytorch_model.bin`.
fn openclip_files() -> Vec<(String, Vec<u8>)> {
    ["open_clip_config.json", "open_clip_pytorch_model.bin"]
        .into_iter()
        .map(|n| (n.to_string(), read(Path::new(OPENCLIP_DIR).join(n))))
        .chain([("tokenizer.json".to_string(), read(TOKENIZER))])
        .collect()
}

fn read(p: impl AsRef<Path>) -> Vec<u8> {
    std::fs::read(p.as_ref()).unwrap_or_else(|e| panic!("{}: {e}", p.as_ref().display()))
}

/// config.json + tokenizer.json + every file of a checkpoint folder (or one named file).
fn files_of(layout: &str) -> Vec<(String, Vec<u8>)> {
    let mut files = vec![
        (
            "config.json".to_string(),
            read(Path::new(MODEL_DIR).join("config.json")),
        ),
        ("tokenizer.json".to_string(), read(TOKENIZER)),
    ];
    if layout == "safetensors" {
        files.push((
            "model.safetensors".into(),
            read(Path::new(MODEL_DIR).join("model.safetensors")),
        ));
    } else {
        let dir = Path::new(CHECKPOINTS).join(layout);
        let mut names: Vec<PathBuf> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        names.sort();
        for p in names {
            let name = p.file_name().unwrap().to_string_lossy().to_string();
            files.push((name, read(&p)));
        }
    }
    files
}

/// The Hub as the tests see it: the default repo as on huggingface.co, and one repo per layout.
fn hub_spec() -> HubSpec {
    // Files of 100 kB and more are LFS (302 to the CDN host, sha256 etag), like weights and the
    // tokenizer; config.json is a plain git file (307 to /api/resolve-cache).
    let mut spec = HubSpec::new().lfs_threshold(100_000);
    spec.repo(DEFAULT_MODEL).revision("main", files_of("bin"));
    spec.repo(DEFAULT_MODEL)
        .revision("refs/pr/15", files_of("safetensors"));
    for layout in ["bin", "sharded_bin", "sharded_safetensors", "safetensors"] {
        spec.repo(&format!("t2tf-test/{layout}"))
            .revision("main", files_of(layout));
    }
    let mut hostile = files_of("safetensors");
    hostile.retain(|(n, _)| n != "model.safetensors");
    hostile.push((
        "pytorch_model.bin".into(),
        read("tests/fixtures/clip/torch/hostile_os_system.bin"),
    ));
    spec.repo("t2tf-test/hostile").revision("main", hostile);
    spec.repo("t2tf-test/openclip")
        .revision("main", openclip_files());
    let mut both = files_of("safetensors");
    both.extend(
        openclip_files()
            .into_iter()
            .filter(|(n, _)| n != "tokenizer.json"),
    );
    spec.repo("t2tf-test/both-layouts").revision("main", both);
    let mut with_processor = files_of("safetensors");
    with_processor.push((
        "preprocessor_config.json".into(),
        br#"{"image_mean": [0.5, 0.5, 0.5], "image_std": [0.25, 0.25, 0.25]}"#.to_vec(),
    ));
    spec.repo("t2tf-test/preprocessor")
        .revision("main", with_processor);
    spec
}

fn settings(server: &HubServer, cache: &Path, offline: bool) -> HubSettings {
    HubSettings {
        endpoint: server.endpoint(),
        cache_dir: cache.to_path_buf(),
        token: None,
        offline,
        progress: false,
        stall_timeout: t2tf::hub::env::DEFAULT_STALL,
        on_event: None,
    }
}

/// Text and image embeddings of a fixed caption set and image: what "scores" means here.
fn embeddings(clip: &Clip) -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    let text = clip
        .encode_text(&["a white skull", "blood vessels", ""])
        .unwrap();
    let s = clip.image_size();
    let mut im = Image::new(s, s);
    for (i, v) in im.data.iter_mut().enumerate() {
        *v = ((i * 37) % 251) as f32 / 250.0;
    }
    let (img, _) = clip.encode_images(&[im]).unwrap();
    (text, img)
}

fn reference() -> (Vec<Vec<f32>>, Vec<Vec<f32>>) {
    embeddings(&Clip::load_with_tokenizer(MODEL_DIR, Some(Path::new(TOKENIZER))).unwrap())
}

fn load(hub: &Hub, repo: &str, revision: &str) -> (WeightFormat, Clip) {
    let mut req = ModelRequest::new(repo);
    req.revision = revision.to_string();
    let files = resolve_with(&req, hub).unwrap_or_else(|e| panic!("{repo}@{revision}: {e}"));
    (files.format, Clip::load_files(&files).unwrap())
}

#[test]
fn default_model_resolves_and_scores_like_the_fixture_online_then_offline() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let want = reference();

    let online = Hub::new(settings(&server, cache.path(), false));
    let (format, clip) = load(&online, DEFAULT_MODEL, "main");
    assert_eq!(format, WeightFormat::PyTorch, "main has only the .bin");
    assert_eq!(embeddings(&clip), want);
    // model.safetensors was asked for first and answered 404, as on huggingface.co.
    let asked: Vec<String> = server.requests().iter().map(|r| r.path.clone()).collect();
    assert!(
        asked.iter().any(|p| p.ends_with("/main/model.safetensors")),
        "{asked:?}"
    );
    assert!(!server.cdn_saw_authorization());

    let (format, clip) = load(&online, DEFAULT_MODEL, "refs/pr/15");
    assert_eq!(format, WeightFormat::Safetensors);
    assert_eq!(embeddings(&clip), want);

    server.clear_requests();
    let offline = Hub::new(settings(&server, cache.path(), true));
    for rev in ["main", "refs/pr/15"] {
        let (_, clip) = load(&offline, DEFAULT_MODEL, rev);
        assert_eq!(embeddings(&clip), want, "offline {rev}");
    }
    assert!(server.requests().is_empty(), "{:?}", server.requests());
}

#[test]
fn every_checkpoint_layout_gives_bit_identical_embeddings() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&server, cache.path(), false));
    let want = reference();
    for (layout, format) in [
        ("bin", WeightFormat::PyTorch),
        ("sharded_bin", WeightFormat::PyTorch),
        ("sharded_safetensors", WeightFormat::Safetensors),
        ("safetensors", WeightFormat::Safetensors),
    ] {
        let (got_format, clip) = load(&hub, &format!("t2tf-test/{layout}"), "main");
        assert_eq!(got_format, format, "{layout}");
        assert_eq!(embeddings(&clip), want, "{layout} from the Hub");
        // The same files in a local folder (--model DIR).
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in files_of(layout) {
            std::fs::write(dir.path().join(name), bytes).unwrap();
        }
        let clip = Clip::load(dir.path().to_str().unwrap()).unwrap();
        assert_eq!(embeddings(&clip), want, "{layout} from a folder");
    }
}

#[test]
fn hostile_pickle_is_refused_and_runs_nothing() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&server, cache.path(), false));
    // The pickle would run `touch t2tf-pickle-marker` in the working directory.
    let marker = Path::new("t2tf-pickle-marker");
    assert!(!marker.exists());
    let files = resolve_with(&ModelRequest::new("t2tf-test/hostile"), &hub).unwrap();
    let e = Clip::load_files(&files).err().expect("refused").to_string();
    assert!(
        e.contains("os.system") && e.contains("pytorch_model.bin"),
        "{e}"
    );
    assert!(!marker.exists(), "the pickle ran");
}

/// Blobs in the cache that a later run would trust (not `.incomplete`).
fn trusted_blobs(cache: &Path, repo: &str) -> Vec<String> {
    let dir = cache
        .join(format!("models--{}", repo.replace('/', "--")))
        .join("blobs");
    std::fs::read_dir(dir)
        .map(|d| {
            d.map(|e| e.unwrap().file_name().to_string_lossy().to_string())
                .filter(|n| !n.ends_with(".incomplete"))
                .collect()
        })
        .unwrap_or_default()
}

/// Transfers the client retries after the first (crates/clip/src/hub/download.rs).
const RETRIES: usize = 2;

#[test]
fn cut_or_corrupted_weights_are_never_trusted() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&server, cache.path(), false));
    let repo = "t2tf-test/bin";
    let want = reference();
    // The LFS blob of the weights is named by its sha256.
    let weights_sha = hub_server::hex(&sha2::Sha256::digest(read(
        Path::new(CHECKPOINTS).join("bin/pytorch_model.bin"),
    )));
    let weights_trusted = || trusted_blobs(cache.path(), repo).contains(&weights_sha);

    // The connection drops a third of the way into the weights, on the first try and on
    // every retry the client makes.
    server.inject("pytorch_model.bin", Fault::CutAfter(500_000), 1 + RETRIES);
    let e = resolve_with(&ModelRequest::new(repo), &hub)
        .expect_err("a cut download fails")
        .to_string();
    assert!(e.contains("pytorch_model.bin"), "{e}");
    assert!(!weights_trusted());

    // Wrong bytes of the right length: the sha256 check catches them.
    server.inject("pytorch_model.bin", Fault::WrongBytes, 1);
    let e = resolve_with(&ModelRequest::new(repo), &hub)
        .expect_err("a corrupted download fails")
        .to_string();
    assert!(e.to_lowercase().contains("sha256"), "{e}");
    assert!(!weights_trusted());

    // Next run: downloads again and loads the right model.
    let (_, clip) = load(&hub, repo, "main");
    assert_eq!(embeddings(&clip), want);
    assert!(weights_trusted());
}

// ---- the CLI, configured through the environment only ----

fn t2tf(args: &[&str], server: &HubServer, cache: &Path, offline: bool) -> Output {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_t2tf"));
    cmd.args(args)
        .env("HF_ENDPOINT", server.endpoint())
        .env("HF_HUB_CACHE", cache)
        .env_remove("HF_TOKEN")
        .env("HF_HOME", cache.join("home"));
    if offline {
        cmd.env("HF_HUB_OFFLINE", "1");
    } else {
        cmd.env_remove("HF_HUB_OFFLINE");
    }
    cmd.output().expect("run t2tf")
}

fn ok(o: &Output) -> String {
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    String::from_utf8_lossy(&o.stdout).to_string()
}

fn one_line_error(o: &Output, needles: &[&str]) {
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "succeeded: {err}");
    assert_ne!(o.status.code(), Some(101), "panicked: {err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in needles {
        assert!(err.contains(n), "lacks '{n}': {err}");
    }
}

#[test]
fn cli_uses_the_default_model_from_the_hub_then_offline() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let png = cache.path().join("view.png");
    let mut im = Image::new(40, 36);
    for (i, v) in im.data.iter_mut().enumerate() {
        *v = ((i * 13) % 255) as f32 / 255.0;
    }
    im.save_png(&png).unwrap();
    let score = ["clip-score", png.to_str().unwrap(), "--caption", "a skull"];
    let score = [&score[..], &["--caption", "an engine"]].concat();

    let want = ok(&t2tf(
        &[
            &score[..],
            &["--model", MODEL_DIR, "--tokenizer", TOKENIZER],
        ]
        .concat(),
        &server,
        cache.path(),
        false,
    ));
    // Offline before anything is cached: one line naming the file and what to do.
    one_line_error(
        &t2tf(&score, &server, cache.path(), true),
        &[DEFAULT_MODEL, "HF_HUB_OFFLINE", "t2tf model fetch"],
    );
    assert_eq!(ok(&t2tf(&score, &server, cache.path(), false)), want);

    // `model fetch` prints the snapshot folder last; `model list` shows the repo.
    let fetched = ok(&t2tf(
        &["model", "fetch", "t2tf-test/sharded_safetensors"],
        &server,
        cache.path(),
        false,
    ));
    let snapshot = PathBuf::from(fetched.lines().last().unwrap());
    assert!(
        snapshot.join("model.safetensors.index.json").is_file(),
        "{fetched}"
    );
    let listed = ok(&t2tf(&["model", "list"], &server, cache.path(), true));
    for repo in [DEFAULT_MODEL, "t2tf-test/sharded_safetensors"] {
        assert!(listed.contains(repo), "{listed}");
    }

    server.clear_requests();
    assert_eq!(ok(&t2tf(&score, &server, cache.path(), true)), want);
    let with_snapshot = [&score[..], &["--model", snapshot.to_str().unwrap()]].concat();
    assert_eq!(ok(&t2tf(&with_snapshot, &server, cache.path(), true)), want);
    assert!(server.requests().is_empty());

    // Errors a user can act on.
    one_line_error(
        &t2tf(
            &[&score[..], &["--model", "nobody/no-such-model"]].concat(),
            &server,
            cache.path(),
            false,
        ),
        &["nobody/no-such-model"],
    );
    one_line_error(
        &t2tf(
            &[&score[..], &["--revision", "no-such-branch"]].concat(),
            &server,
            cache.path(),
            false,
        ),
        &["no-such-branch"],
    );
}

/// `preprocessor_config.json` is optional: fetched where the repo has it (and used), absent
/// (404) where it has not, and offline neither case asks the server anything.
#[test]
fn preprocessor_config_is_optional_on_the_hub() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let online = Hub::new(settings(&server, cache.path(), false));
    for (repo, has) in [
        ("t2tf-test/preprocessor", true),
        ("t2tf-test/safetensors", false),
    ] {
        let files = resolve_with(&ModelRequest::new(repo), &online).unwrap();
        assert_eq!(files.preprocessor.is_some(), has, "{repo}");
        let clip = Clip::load_files(&files).unwrap();
        let want = if has { [0.5; 3] } else { t2tf::clip::MEAN };
        assert_eq!(clip.preprocessing().mean, want, "{repo}");
    }
    server.clear_requests();
    let offline = Hub::new(settings(&server, cache.path(), true));
    for (repo, has) in [
        ("t2tf-test/preprocessor", true),
        ("t2tf-test/safetensors", false),
    ] {
        let files = resolve_with(&ModelRequest::new(repo), &offline).unwrap();
        assert_eq!(files.preprocessor.is_some(), has, "offline {repo}");
    }
    assert!(server.requests().is_empty(), "{:?}", server.requests());
}

/// A repository with only OpenCLIP's files: `config.json` and OpenCLIP's safetensors names are
/// asked for and answered 404, `open_clip_pytorch_model.bin` is fetched, and the model scores as
/// the fixture folder does; offline it loads from the cache with no request. A repository with
/// both layouts is read as transformers'.
#[test]
fn openclip_layout_loads_from_the_hub_then_offline() {
    let server = HubServer::start(hub_spec());
    let cache = tempfile::tempdir().unwrap();
    let want =
        embeddings(&Clip::load_with_tokenizer(OPENCLIP_DIR, Some(Path::new(TOKENIZER))).unwrap());
    let online = Hub::new(settings(&server, cache.path(), false));
    let files = resolve_with(&ModelRequest::new("t2tf-test/openclip"), &online).unwrap();
    assert_eq!(files.layout, t2tf::clip::Layout::OpenClip);
    assert_eq!(files.format, WeightFormat::PyTorch);
    assert!(files.config.ends_with("open_clip_config.json"));
    assert!(files.preprocessor.is_none());
    assert_eq!(embeddings(&Clip::load_files(&files).unwrap()), want);
    let asked: Vec<String> = server.requests().iter().map(|r| r.path.clone()).collect();
    for name in [
        "config.json",
        "open_clip_config.json",
        "open_clip_model.safetensors",
        "open_clip_pytorch_model.safetensors",
        "open_clip_pytorch_model.bin",
    ] {
        assert!(
            asked.iter().any(|p| p.ends_with(&format!("/main/{name}"))),
            "{name}: {asked:?}"
        );
    }
    assert!(
        !asked
            .iter()
            .any(|p| p.ends_with("/preprocessor_config.json")),
        "{asked:?}"
    );

    server.clear_requests();
    let offline = Hub::new(settings(&server, cache.path(), true));
    let files = resolve_with(&ModelRequest::new("t2tf-test/openclip"), &offline).unwrap();
    assert_eq!(files.layout, t2tf::clip::Layout::OpenClip);
    assert_eq!(embeddings(&Clip::load_files(&files).unwrap()), want);
    assert!(server.requests().is_empty(), "{:?}", server.requests());

    let files = resolve_with(&ModelRequest::new("t2tf-test/both-layouts"), &online).unwrap();
    assert_eq!(files.layout, t2tf::clip::Layout::Transformers);
    assert_eq!(embeddings(&Clip::load_files(&files).unwrap()), reference());

    // `model fetch` and `model list` know the OpenCLIP repository as a CLIP model.
    let fetched = ok(&t2tf(
        &["model", "fetch", "t2tf-test/openclip"],
        &server,
        cache.path(),
        false,
    ));
    assert!(
        fetched.contains("open_clip_pytorch_model.bin") && fetched.contains("OpenClip"),
        "{fetched}"
    );
    let listed = ok(&t2tf(&["model", "list"], &server, cache.path(), true));
    let line = listed
        .lines()
        .find(|l| l.starts_with("t2tf-test/openclip "))
        .unwrap_or_else(|| panic!("{listed}"));
    assert!(line.contains("open_clip_pytorch_model.bin"), "{listed}");
}
