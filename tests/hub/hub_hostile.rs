//! A hostile or broken Hub cannot make a download unbounded: a `config.json` without end stops
//! at the cap for files that are not weights, a gzip bomb is refused before a byte is inflated,
//! a body longer than the Hub declared is an error, and a body that drips a byte at a time is
//! retried once and then reported as stalled. Nothing unchecked is kept in the cache.

use crate::hub_server;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use hub_server::{Fault, HubServer, HubSpec};
use t2tf::hub::{Hub, HubError, HubSettings};

const REPO: &str = "acme/tiny";
const CONFIG: &str = "config.json";
const WEIGHTS: &str = "model.safetensors";
const TOKENIZER: &str = "../shared/data/clip/tokenizer.json";
const MODEL_DIR: &str = "tests/fixtures/clip/quick_gelu";

fn read(p: impl AsRef<Path>) -> Vec<u8> {
    std::fs::read(p.as_ref()).unwrap_or_else(|e| panic!("{}: {e}", p.as_ref().display()))
}

/// A small CLIP model as a Hub repo: config.json is a plain git file, the tokenizer and the
/// weights are LFS files.
fn spec() -> HubSpec {
    let mut spec = HubSpec::new().lfs_threshold(100_000);
    spec.repo(REPO).revision(
        "main",
        [
            (CONFIG, read(Path::new(MODEL_DIR).join(CONFIG))),
            ("tokenizer.json", read(TOKENIZER)),
            (WEIGHTS, read(Path::new(MODEL_DIR).join(WEIGHTS))),
        ],
    );
    spec
}

fn hub(server: &HubServer, cache: &Path) -> Hub {
    Hub::new(HubSettings {
        endpoint: server.endpoint(),
        cache_dir: cache.to_path_buf(),
        token: None,
        offline: false,
        progress: false,
        stall_timeout: t2tf::hub::env::DEFAULT_STALL,
        on_event: None,
    })
}

/// Every file under `dir` with its size.
fn files(dir: &Path) -> Vec<(PathBuf, u64)> {
    let mut out = Vec::new();
    let Ok(entries) = std::fs::read_dir(dir) else {
        return out;
    };
    for e in entries {
        let p = e.unwrap().path();
        let meta = std::fs::symlink_metadata(&p).unwrap();
        if meta.is_dir() {
            out.extend(files(&p));
        } else {
            out.push((p, meta.len()));
        }
    }
    out
}

/// The cache holds no snapshot and no blob of more than `max` bytes.
fn nothing_kept(cache: &Path, max: u64) {
    for (p, len) in files(cache) {
        let name = p.to_string_lossy();
        assert!(!name.contains("/snapshots/"), "{name} linked");
        if name.contains("/blobs/") {
            assert!(len <= max, "{name} holds {len} bytes");
        }
    }
}

fn one_line(e: &HubError, needles: &[&str]) -> String {
    let m = e.to_string();
    assert!(!m.contains('\n'), "not one line: {m}");
    for n in needles {
        assert!(m.contains(n), "{n:?} not in: {m}");
    }
    m
}

#[test]
fn an_endless_config_json_stops_at_the_cap() {
    let server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    // No size declared anywhere (the HEAD and the GET both without Content-Length): the cap
    // for files that are not weights.
    server.inject(CONFIG, Fault::Endless, 2);
    let e = hub(&server, cache.path())
        .repo(REPO, "main")
        .get(CONFIG)
        .unwrap_err();
    assert!(matches!(e, HubError::TooLarge { .. }), "{e}");
    one_line(&e, &[CONFIG, REPO, "32.0 MiB", "not weights"]);
    nothing_kept(cache.path(), 0);
    // The next try, the server behaving, gets the file.
    let path = hub(&server, cache.path())
        .repo(REPO, "main")
        .get(CONFIG)
        .unwrap()
        .unwrap();
    assert_eq!(read(path), read(Path::new(MODEL_DIR).join(CONFIG)));
}

#[test]
fn a_gzip_bomb_is_refused_before_it_is_inflated() {
    let server = HubServer::start(spec());
    // 64 MiB of zeros in about 64 kB: beyond the cap once inflated.
    server.inject(CONFIG, Fault::GzipBomb(64 << 20), 1);
    let cache = tempfile::tempdir().unwrap();
    let e = hub(&server, cache.path())
        .repo(REPO, "main")
        .get(CONFIG)
        .unwrap_err();
    one_line(&e, &["Content-Encoding: gzip", "does not inflate"]);
    nothing_kept(cache.path(), 0);
    let asked = server.requests();
    assert!(
        asked
            .iter()
            .filter(|r| r.method == "GET")
            .all(|r| r.header("accept-encoding") == Some("identity")),
        "{asked:?}"
    );
}

#[test]
fn a_body_longer_than_the_hub_declared_is_an_error() {
    let server = HubServer::start(spec());
    let size = read(Path::new(MODEL_DIR).join(WEIGHTS)).len();
    server.inject(WEIGHTS, Fault::ExtraBytes(1000), 1);
    let cache = tempfile::tempdir().unwrap();
    let e = hub(&server, cache.path())
        .repo(REPO, "main")
        .get(WEIGHTS)
        .unwrap_err();
    assert!(matches!(e, HubError::TooLarge { .. }), "{e}");
    one_line(
        &e,
        &[
            WEIGHTS,
            &format!("declared {size} bytes"),
            &format!("announces {}", size + 1000),
        ],
    );
    nothing_kept(cache.path(), 0);
    // A body longer than declared that announces no length is cut at the declared size.
    server.inject(WEIGHTS, Fault::Endless, 1);
    let e = hub(&server, cache.path())
        .repo(REPO, "main")
        .get(WEIGHTS)
        .unwrap_err();
    one_line(&e, &[&format!("longer than the {size} bytes declared")]);
    nothing_kept(cache.path(), 0);
}

/// `t2tf model fetch REPO` against `server` with a stall timeout of one second.
fn fetch(server: &HubServer, cache: &Path) -> (std::process::Output, Duration) {
    let start = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_t2tf"))
        .args(["model", "fetch", REPO])
        .env("HF_ENDPOINT", server.endpoint())
        .env("HF_HUB_CACHE", cache)
        .env("HF_HOME", cache.join("home"))
        .env_remove("HF_TOKEN")
        .env_remove("HF_HUB_OFFLINE")
        .env("T2TF_HUB_STALL_TIMEOUT", "1")
        .output()
        .unwrap();
    (out, start.elapsed())
}

fn config_gets(server: &HubServer) -> usize {
    server
        .requests()
        .iter()
        .filter(|r| {
            r.method == "GET"
                && r.path.starts_with("/api/resolve-cache/")
                && r.path.ends_with("/config.json")
        })
        .count()
}

#[test]
fn a_dripping_download_is_retried_once_then_reported_as_stalled() {
    let server = HubServer::start(spec());
    // One byte every 200 ms: never silent as long as a read's timeout, yet far below 1 KiB/s.
    server.inject(CONFIG, Fault::Drip(200), 2);
    let cache = tempfile::tempdir().unwrap();
    let (out, took) = fetch(&server, cache.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert_eq!(err.trim_end().lines().count(), 1, "not one line: {err}");
    for n in [
        "config.json",
        "stalled",
        "1 s",
        "twice",
        "T2TF_HUB_STALL_TIMEOUT",
    ] {
        assert!(err.contains(n), "{n:?} not in: {err}");
    }
    assert_eq!(config_gets(&server), 2, "one try and one retry");
    assert!(took < Duration::from_secs(10), "took {took:?}");

    // A stall on one connection only: the retry resumes and the model arrives.
    server.clear_requests();
    server.inject(CONFIG, Fault::Drip(200), 1);
    let cache = tempfile::tempdir().unwrap();
    let (out, took) = fetch(&server, cache.path());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert_eq!(config_gets(&server), 2, "one try and one retry");
    let resumed = server
        .requests()
        .iter()
        .any(|r| r.path.ends_with("/config.json") && r.header("range").is_some());
    assert!(resumed, "the retry did not resume");
    assert!(took < Duration::from_secs(10), "took {took:?}");
}

#[cfg(unix)]
#[test]
fn cache_entries_leading_out_of_the_cache_are_never_read_or_written() {
    let server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let elsewhere = tempfile::tempdir().unwrap();
    let victim = elsewhere.path().join("secret.txt");
    let text = "SECRET first line\nsecond line\n";
    std::fs::write(&victim, text).unwrap();
    let hub = hub(&server, cache.path());
    let repo = hub.repo(REPO, "main");
    let snapshot = repo.get(CONFIG).unwrap().unwrap();
    let folder = repo.cache_folder();
    let commit = server.commit(REPO, "main");

    // A snapshot entry and a ref replaced by symlinks to the victim.
    let planted = folder.join("snapshots").join(&commit).join(WEIGHTS);
    std::os::unix::fs::symlink(&victim, &planted).unwrap();
    std::fs::remove_file(folder.join("refs/main")).unwrap();
    std::os::unix::fs::symlink(&victim, folder.join("refs/main")).unwrap();
    let offline = Hub::new(HubSettings {
        offline: true,
        ..hub.settings().clone()
    });
    for file in [WEIGHTS, CONFIG] {
        let e = offline.repo(REPO, "main").get(file).unwrap_err();
        let m = one_line(&e, &[file]);
        assert!(!m.contains("SECRET"), "{m}");
    }
    let e = offline.repo(REPO, &commit).get(WEIGHTS).unwrap_err();
    assert!(matches!(e, HubError::NotCached { .. }), "{e}");

    // A download in progress planted as a symlink: replaced, the victim untouched; the
    // snapshot entry is linked anew to the real blob, the ref rewritten.
    let weights = read(Path::new(MODEL_DIR).join(WEIGHTS));
    let etag = hub_server::hex(&<sha2::Sha256 as sha2::Digest>::digest(&weights));
    let incomplete = folder.join("blobs").join(format!("{etag}.incomplete"));
    std::os::unix::fs::symlink(&victim, &incomplete).unwrap();
    let got = repo.get(WEIGHTS).unwrap().unwrap();
    assert_eq!(got, planted);
    assert_eq!(read(&got), weights);
    assert_eq!(std::fs::read_to_string(&victim).unwrap(), text);
    assert!(std::fs::symlink_metadata(folder.join("refs/main"))
        .unwrap()
        .is_file());
    assert_eq!(read(snapshot), read(Path::new(MODEL_DIR).join(CONFIG)));

    // A blob that is itself a link out of the cache is refused, its contents never quoted.
    let other = tempfile::tempdir().unwrap();
    let hub = Hub::new(HubSettings {
        cache_dir: other.path().to_path_buf(),
        ..hub.settings().clone()
    });
    let blobs = hub.repo(REPO, "main").cache_folder().join("blobs");
    std::fs::create_dir_all(&blobs).unwrap();
    std::os::unix::fs::symlink(&victim, blobs.join(&etag)).unwrap();
    let e = hub.repo(REPO, "main").get(WEIGHTS).unwrap_err();
    assert!(matches!(e, HubError::OutsideCache { .. }), "{e}");
    assert!(!e.to_string().contains("SECRET"), "{e}");
}
