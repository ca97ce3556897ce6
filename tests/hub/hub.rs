//! The Hub client against the stand-in server (`hub_server`), and against Python's
//! `huggingface_hub` sharing its cache. Every test has its own temporary cache and passes
//! settings explicitly: nothing touches the real cache, the environment or the network.

use crate::hub_server;

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;

use hub_server::{files_in, hex, Fault, HubServer, HubSpec};
use sha2::{Digest, Sha256};
use t2tf::error::ErrorKind;
use t2tf::hub::{cached_repos, EventSink, Hub, HubError, HubEvent, HubSettings, RepoKind};

const REPO: &str = "acme/tiny";
const GATED: &str = "acme/gated";
const CONFIG: &str = "config.json";
const WEIGHTS: &str = "model.safetensors";
const NESTED: &str = "sub/dir/extra.bin";
const CONFIG_PR: &[u8] = b"{\"hidden_size\": 8, \"pr\": true}";

fn config() -> Vec<u8> {
    b"{\"hidden_size\": 8}".to_vec()
}

/// Deterministic bytes, different per seed.
fn blob(len: usize, seed: u8) -> Vec<u8> {
    (0..len)
        .map(|i| (i.wrapping_mul(31) as u8) ^ seed)
        .collect()
}

fn weights() -> Vec<u8> {
    blob(300_000, 7)
}

/// `acme/tiny` (main and refs/pr/1) and a gated `acme/gated`; LFS from 256 bytes.
fn spec() -> HubSpec {
    let mut spec = HubSpec::new().lfs_threshold(256);
    let tiny = spec.repo(REPO);
    tiny.revision(
        "main",
        [
            (CONFIG, config()),
            (WEIGHTS, weights()),
            (NESTED, blob(1000, 3)),
        ],
    );
    tiny.revision(
        "refs/pr/1",
        [(CONFIG, CONFIG_PR.to_vec()), (WEIGHTS, weights())],
    );
    spec.repo(GATED)
        .gated("hf_good")
        .revision("main", [(CONFIG, config())]);
    spec
}

fn settings(endpoint: &str, cache: &Path) -> HubSettings {
    HubSettings {
        endpoint: endpoint.to_string(),
        cache_dir: cache.to_path_buf(),
        token: None,
        offline: false,
        progress: false,
        stall_timeout: t2tf::hub::env::DEFAULT_STALL,
        on_event: None,
    }
}

fn offline(cache: &Path) -> Hub {
    Hub::new(HubSettings {
        offline: true,
        ..settings("http://127.0.0.1:9", cache)
    })
}

fn sha256(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

fn get(hub: &Hub, repo: &str, rev: &str, file: &str) -> Result<Option<PathBuf>, HubError> {
    hub.repo(repo, rev).get(file)
}

fn read(path: Option<PathBuf>) -> Vec<u8> {
    std::fs::read(path.expect("a file")).expect("readable")
}

/// An endpoint nobody listens on.
fn dead_endpoint() -> String {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    format!("http://{}", listener.local_addr().unwrap())
}

fn assert_mentions(message: &str, needles: &[&str]) {
    for n in needles {
        assert!(message.contains(n), "{n:?} not in: {message}");
    }
    assert!(!message.contains('\n'), "not one line: {message}");
}

#[test]
fn small_file_follows_the_relative_redirect_into_pythons_layout() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    let path = get(&hub, REPO, "main", CONFIG).unwrap();
    assert_eq!(read(path.clone()), config());

    let commit = hub_server.commit(REPO, "main");
    let folder = hub.repo(REPO, "main").cache_folder();
    assert_eq!(folder, cache.path().join("models--acme--tiny"));
    let pointer = folder.join("snapshots").join(&commit).join(CONFIG);
    assert_eq!(path.as_deref(), Some(pointer.as_path()));
    let target = std::fs::read_link(&pointer).unwrap();
    assert!(target.starts_with("../../blobs"), "{}", target.display());
    let etag = target.file_name().unwrap().to_str().unwrap();
    assert_eq!(etag.len(), 40, "small files are named by their git etag");
    assert_eq!(
        std::fs::read_to_string(folder.join("refs/main")).unwrap(),
        commit
    );

    let log = hub_server.requests();
    let seen: Vec<(&str, &str)> = log
        .iter()
        .map(|r| (r.method.as_str(), r.path.as_str()))
        .collect();
    let cached = format!("/api/resolve-cache/models/{REPO}/{commit}/{CONFIG}");
    assert_eq!(
        seen,
        [
            ("HEAD", format!("/{REPO}/resolve/main/{CONFIG}").as_str()),
            ("HEAD", cached.as_str()),
            ("GET", cached.as_str()),
        ]
    );
    assert_eq!(log[0].header("accept-encoding"), Some("identity"));
}

#[test]
fn lfs_file_comes_from_the_cdn_without_the_token_and_is_checked() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(HubSettings {
        token: Some("hf_secret".into()),
        ..settings(&hub_server.endpoint(), cache.path())
    });
    assert_eq!(read(get(&hub, REPO, "main", WEIGHTS).unwrap()), weights());
    let blob = hub
        .repo(REPO, "main")
        .cache_folder()
        .join("blobs")
        .join(sha256(&weights()));
    assert!(blob.is_file(), "LFS blobs are named by their sha256");

    let log = hub_server.requests();
    let head = &log[0];
    assert_eq!(head.method, "HEAD");
    assert_eq!(head.header("authorization"), Some("Bearer hf_secret"));
    let cdn: Vec<_> = log.iter().filter(|r| r.path.starts_with("/cdn/")).collect();
    assert_eq!(cdn.len(), 1, "{log:?}");
    assert_eq!(cdn[0].method, "GET");
    assert_eq!(cdn[0].host, hub_server.cdn_host());
    assert!(
        !hub_server.cdn_saw_authorization(),
        "token leaked to the CDN: {log:?}"
    );
}

#[test]
fn nested_file_name_links_back_to_blobs() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    let path = get(&hub, REPO, "main", NESTED).unwrap().unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), blob(1000, 3));
    let link = std::fs::read_link(&path).unwrap();
    let want = Path::new("../../../../blobs").join(sha256(&blob(1000, 3)));
    assert_eq!(link, want);
}

#[test]
fn a_large_download_reports_its_progress_to_the_front_end_only() {
    // Above the quiet size: the client tells its sink, in order, that the file started, how
    // far it got (never past its size) and that it finished whole; with progress off, or a
    // small file, it tells nothing. The library itself writes nothing to stderr.
    let big = blob(11 << 20, 9);
    let mut spec = HubSpec::new();
    spec.repo(REPO)
        .revision("main", [(WEIGHTS, big.clone()), (CONFIG, config())]);
    let hub_server = HubServer::start(spec);
    let run = |progress: bool, file: &str| {
        let cache = tempfile::tempdir().unwrap();
        let events = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let seen = events.clone();
        let hub = Hub::new(HubSettings {
            progress,
            on_event: Some(EventSink::new(move |e| {
                seen.lock().unwrap().push(e.clone())
            })),
            ..settings(&hub_server.endpoint(), cache.path())
        });
        let bytes = read(get(&hub, REPO, "main", file).unwrap());
        let events = events.lock().unwrap().clone();
        (bytes, events)
    };
    let (bytes, events) = run(true, WEIGHTS);
    assert!(bytes == big);
    let total = big.len() as u64;
    assert_eq!(
        events.first(),
        Some(&HubEvent::Started {
            file: WEIGHTS.into(),
            total: Some(total)
        }),
        "{events:?}"
    );
    assert_eq!(
        events.last(),
        Some(&HubEvent::Finished {
            file: WEIGHTS.into(),
            done: total,
            ok: true
        }),
        "{events:?}"
    );
    let mut last = 0;
    for e in &events[1..events.len() - 1] {
        let HubEvent::Progress {
            file,
            done,
            total: t,
        } = e
        else {
            panic!("{e:?} between start and finish");
        };
        assert!(
            file == WEIGHTS && *t == Some(total) && (last..=total).contains(done),
            "{e:?}"
        );
        last = *done;
    }
    let (bytes, events) = run(false, WEIGHTS);
    assert!(bytes == big && events.is_empty(), "{events:?}");
    let (bytes, events) = run(true, CONFIG);
    assert!(bytes == config() && events.is_empty(), "{events:?}");
}

#[test]
fn a_folder_can_be_served_as_a_revision() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("sub")).unwrap();
    std::fs::write(dir.path().join(CONFIG), config()).unwrap();
    std::fs::write(dir.path().join("sub/w.bin"), blob(500, 1)).unwrap();
    let mut spec = HubSpec::new().lfs_threshold(256);
    spec.repo(REPO).revision("main", files_in(dir.path()));
    let hub_server = HubServer::start(spec);
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    assert_eq!(read(get(&hub, REPO, "main", CONFIG).unwrap()), config());
    assert_eq!(
        read(get(&hub, REPO, "main", "sub/w.bin").unwrap()),
        blob(500, 1)
    );
}

#[test]
fn token_comes_from_hf_token_or_the_token_file() {
    let hub_server = HubServer::start(spec());
    let dir = tempfile::tempdir().unwrap();
    let endpoint = hub_server.endpoint();
    let cache = dir.path().join("cache");
    let home = dir.path().join("home");
    std::fs::create_dir_all(&home).unwrap();
    let vars = |extra: &[(&str, &str)]| {
        let mut map: HashMap<String, String> = [
            ("HF_ENDPOINT", endpoint.as_str()),
            ("HF_HUB_CACHE", cache.to_str().unwrap()),
            ("HF_HOME", home.to_str().unwrap()),
        ]
        .iter()
        .chain(extra)
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
        map.insert("HF_HUB_DISABLE_PROGRESS_BARS".into(), "1".into());
        HubSettings::from_lookup(move |k| map.get(k).cloned())
    };

    let e = get(&Hub::new(vars(&[])), GATED, "main", CONFIG).unwrap_err();
    assert!(
        matches!(e, HubError::AuthRequired { status: 401, .. }),
        "{e:?}"
    );
    assert_mentions(
        &e.to_string(),
        &[
            GATED,
            "HF_TOKEN",
            "huggingface-cli login",
            "/acme/gated/resolve/main/config.json",
        ],
    );

    let with_env = Hub::new(vars(&[("HF_TOKEN", "hf_good")]));
    assert_eq!(
        read(get(&with_env, GATED, "main", CONFIG).unwrap()),
        config()
    );
    std::fs::remove_dir_all(&cache).unwrap();

    std::fs::write(home.join("token"), "hf_good\n").unwrap();
    let with_file = Hub::new(vars(&[]));
    assert_eq!(with_file.settings().token.as_deref(), Some("hf_good"));
    assert_eq!(
        read(get(&with_file, GATED, "main", CONFIG).unwrap()),
        config()
    );
    let bearers: Vec<_> = hub_server
        .requests()
        .iter()
        .filter_map(|r| r.header("authorization").map(str::to_string))
        .collect();
    assert!(
        bearers.iter().all(|b| b == "Bearer hf_good") && bearers.len() >= 2,
        "{bearers:?}"
    );

    let wrong = Hub::new(vars(&[("HF_TOKEN", "hf_wrong")]));
    std::fs::remove_dir_all(&cache).unwrap();
    let e = get(&wrong, GATED, "main", CONFIG).unwrap_err();
    assert!(
        matches!(e, HubError::AccessDenied { status: 403, .. }),
        "{e:?}"
    );
    assert_mentions(
        &e.to_string(),
        &[GATED, "licence", &format!("{endpoint}/{GATED}")],
    );
}

#[test]
fn missing_file_is_none_and_its_no_exist_marker_is_honoured_offline() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    assert_eq!(get(&hub, REPO, "main", "pytorch_model.bin").unwrap(), None);
    let commit = hub_server.commit(REPO, "main");
    let folder = hub.repo(REPO, "main").cache_folder();
    assert!(folder
        .join(".no_exist")
        .join(&commit)
        .join("pytorch_model.bin")
        .is_file());
    assert_eq!(
        std::fs::read_to_string(folder.join("refs/main")).unwrap(),
        commit
    );

    hub_server.clear_requests();
    assert_eq!(
        get(&offline(cache.path()), REPO, "main", "pytorch_model.bin").unwrap(),
        None
    );
    // A commit's contents never change, so online the marker is enough too.
    assert_eq!(get(&hub, REPO, &commit, "pytorch_model.bin").unwrap(), None);
    assert!(hub_server.requests().is_empty());
}

#[test]
fn unknown_revision_and_repo_have_their_own_messages() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    let e = get(&hub, REPO, "v9", CONFIG).unwrap_err();
    assert!(
        matches!(e, HubError::RevisionNotFound { status: 404, .. }),
        "{e:?}"
    );
    assert_mentions(
        &e.to_string(),
        &["\"v9\"", REPO, "/acme/tiny/resolve/v9/config.json"],
    );

    let e = get(&hub, "acme/nope", "main", CONFIG).unwrap_err();
    assert!(
        matches!(e, HubError::RepoNotFound { status: 401, .. }),
        "{e:?}"
    );
    assert_mentions(&e.to_string(), &["acme/nope", "not found", "HF_TOKEN"]);

    let with_token = Hub::new(HubSettings {
        token: Some("hf_x".into()),
        ..settings(&hub_server.endpoint(), cache.path())
    });
    let e = get(&with_token, "acme/nope", "main", CONFIG).unwrap_err();
    assert!(
        matches!(e, HubError::RepoNotFound { status: 404, .. }),
        "{e:?}"
    );
    assert_mentions(&e.to_string(), &["acme/nope", "token"]);
}

#[test]
fn pr_revision_is_quoted_and_stored_at_refs_refs_pr() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    assert_eq!(
        read(get(&hub, REPO, "refs/pr/1", CONFIG).unwrap()),
        CONFIG_PR
    );
    assert_eq!(
        hub_server.requests()[0].path,
        format!("/{REPO}/resolve/refs%2Fpr%2F1/{CONFIG}")
    );
    let folder = hub.repo(REPO, "refs/pr/1").cache_folder();
    let commit = std::fs::read_to_string(folder.join("refs/refs/pr/1")).unwrap();
    assert_eq!(commit, hub_server.commit(REPO, "refs/pr/1"));
    assert_eq!(
        read(get(&offline(cache.path()), REPO, "refs/pr/1", CONFIG).unwrap()),
        CONFIG_PR
    );
    assert!(get(&offline(cache.path()), REPO, "main", CONFIG).is_err());
}

#[test]
fn offline_answers_from_the_cache_or_says_what_to_do() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    get(&hub, REPO, "main", CONFIG).unwrap();
    drop(hub_server);

    let off = offline(cache.path());
    assert_eq!(read(get(&off, REPO, "main", CONFIG).unwrap()), config());
    let e = get(&off, REPO, "main", WEIGHTS).unwrap_err();
    assert!(matches!(e, HubError::NotCached { .. }), "{e:?}");
    let folder = off.repo(REPO, "main").cache_folder().display().to_string();
    assert_mentions(&e.to_string(), &[WEIGHTS, REPO, &folder, "HF_HUB_OFFLINE"]);
    // What to do instead (fetch elsewhere, a local model folder) is the front end's to say.
    assert_eq!(
        e.hint().kind,
        ErrorKind::ModelUnavailable {
            repo: REPO.into(),
            offline: true
        }
    );
    assert_eq!(e.hint().option, Some("model"));
    let e = get(&off, "acme/never", "main", CONFIG).unwrap_err();
    assert!(matches!(e, HubError::NotCached { .. }), "{e:?}");
}

#[test]
fn endpoint_and_cache_come_from_hf_endpoint_and_hf_hub_cache() {
    let hub_server = HubServer::start(spec());
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("elsewhere");
    let endpoint = format!("{}/", hub_server.endpoint());
    let vars: HashMap<&str, String> = [
        ("HF_ENDPOINT", endpoint),
        ("HF_HUB_CACHE", cache.display().to_string()),
        ("HF_HOME", dir.path().join("home").display().to_string()),
    ]
    .into_iter()
    .collect();
    let s = HubSettings::from_lookup(|k| vars.get(k).cloned());
    assert_eq!(s.endpoint, hub_server.endpoint());
    let hub = Hub::new(HubSettings {
        progress: false,
        stall_timeout: t2tf::hub::env::DEFAULT_STALL,
        on_event: None,
        ..s
    });
    let path = get(&hub, REPO, "main", CONFIG).unwrap().unwrap();
    assert!(
        path.starts_with(cache.join("models--acme--tiny")),
        "{}",
        path.display()
    );
    assert_eq!(hub_server.requests().len(), 3);
}

#[test]
fn a_cut_download_leaves_nothing_trusted_and_resumes_with_range() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    // More cuts than the client's retries: this run fails.
    hub_server.inject(WEIGHTS, Fault::CutAfter(1000), 3);
    let e = get(&hub, REPO, "main", WEIGHTS).unwrap_err();
    assert!(matches!(e, HubError::Network { .. }), "{e:?}");
    assert_mentions(&e.to_string(), &[WEIGHTS, "/cdn/", "check the network"]);

    let folder = hub.repo(REPO, "main").cache_folder();
    let sha = sha256(&weights());
    let partial = folder.join("blobs").join(format!("{sha}.incomplete"));
    assert!(!folder.join("blobs").join(&sha).exists());
    assert!(!folder
        .join("snapshots")
        .join(hub_server.commit(REPO, "main"))
        .join(WEIGHTS)
        .exists());
    assert_eq!(
        std::fs::metadata(&partial).unwrap().len(),
        3000,
        "each try resumed where the last stopped"
    );
    let ranges: Vec<_> = hub_server
        .requests()
        .iter()
        .filter_map(|r| r.header("range").map(str::to_string))
        .collect();
    assert_eq!(ranges, ["bytes=1000-", "bytes=2000-"]);

    hub_server.clear_requests();
    assert_eq!(read(get(&hub, REPO, "main", WEIGHTS).unwrap()), weights());
    let log = hub_server.requests();
    let cdn = log.iter().find(|r| r.path.starts_with("/cdn/")).unwrap();
    assert_eq!(cdn.header("range"), Some("bytes=3000-"));
    assert!(!partial.exists());
}

#[test]
fn a_server_ignoring_range_restarts_the_download_from_zero() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    let blobs = hub.repo(REPO, "main").cache_folder().join("blobs");
    std::fs::create_dir_all(&blobs).unwrap();
    // A leftover partial file whose bytes are not the file's start.
    std::fs::write(
        blobs.join(format!("{}.incomplete", sha256(&weights()))),
        vec![0xEE; 5000],
    )
    .unwrap();
    hub_server.inject(WEIGHTS, Fault::IgnoreRange, 1);
    assert_eq!(read(get(&hub, REPO, "main", WEIGHTS).unwrap()), weights());
    let cdn: Vec<_> = hub_server
        .requests()
        .into_iter()
        .filter(|r| r.path.starts_with("/cdn/"))
        .collect();
    assert_eq!(cdn.len(), 1);
    assert_eq!(cdn[0].header("range"), Some("bytes=5000-"));
}

#[test]
fn a_wrong_sha_is_detected_and_nothing_is_kept() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    hub_server.inject(WEIGHTS, Fault::WrongBytes, 1);
    let e = get(&hub, REPO, "main", WEIGHTS).unwrap_err();
    let sha = sha256(&weights());
    let HubError::Integrity { expected, got, .. } = &e else {
        panic!("{e:?}")
    };
    assert_eq!(expected, &sha);
    assert_ne!(got, &sha);
    assert_mentions(&e.to_string(), &[WEIGHTS, &sha, got, "/cdn/"]);
    let folder = hub.repo(REPO, "main").cache_folder();
    let blobs: Vec<_> = std::fs::read_dir(folder.join("blobs")).unwrap().collect();
    assert!(blobs.is_empty(), "{blobs:?}");
    assert!(!folder.join("snapshots").exists());

    assert_eq!(read(get(&hub, REPO, "main", WEIGHTS).unwrap()), weights());
}

#[test]
fn a_transient_server_error_is_retried_once() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    hub_server.inject(CONFIG, Fault::Status(503), 1);
    assert_eq!(read(get(&hub, REPO, "main", CONFIG).unwrap()), config());
    hub_server.inject(CONFIG, Fault::Status(503), 2);
    std::fs::remove_dir_all(cache.path().join("models--acme--tiny")).unwrap();
    let e = get(&hub, REPO, "main", CONFIG).unwrap_err();
    assert!(matches!(e, HubError::Status { status: 503, .. }), "{e:?}");
    let heads = hub_server
        .requests()
        .iter()
        .filter(|r| r.method == "HEAD")
        .count();
    // First call: 503, then the retry's 307 and the HEAD it leads to; second call: 503 twice.
    assert_eq!(heads, 3 + 2, "bounded: one retry per call");
}

#[test]
fn a_cached_commit_needs_no_request() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let endpoint = hub_server.endpoint();
    let hub = Hub::new(settings(&endpoint, cache.path()));
    get(&hub, REPO, "main", WEIGHTS).unwrap();
    let commit = hub_server.commit(REPO, "main");
    hub_server.clear_requests();
    assert_eq!(read(get(&hub, REPO, &commit, WEIGHTS).unwrap()), weights());
    assert!(
        hub_server.requests().is_empty(),
        "{:?}",
        hub_server.requests()
    );
    drop(hub_server);
    let nobody = Hub::new(settings(&dead_endpoint(), cache.path()));
    assert_eq!(
        read(get(&nobody, REPO, &commit, WEIGHTS).unwrap()),
        weights()
    );
}

#[test]
fn network_down_falls_back_to_the_cache_or_names_the_url() {
    let cache = tempfile::tempdir().unwrap();
    let endpoint = dead_endpoint();
    let hub = Hub::new(settings(&endpoint, cache.path()));
    let e = get(&hub, REPO, "main", CONFIG).unwrap_err();
    assert!(matches!(e, HubError::Network { .. }), "{e:?}");
    assert_mentions(
        &e.to_string(),
        &[
            CONFIG,
            REPO,
            &format!("{endpoint}/{REPO}/resolve/main/{CONFIG}"),
            "HF_HUB_OFFLINE",
        ],
    );
    assert_eq!(
        e.hint().kind,
        ErrorKind::ModelUnavailable {
            repo: REPO.into(),
            offline: false
        }
    );

    let hub_server = HubServer::start(spec());
    get(
        &Hub::new(settings(&hub_server.endpoint(), cache.path())),
        REPO,
        "main",
        CONFIG,
    )
    .unwrap();
    drop(hub_server);
    assert_eq!(read(get(&hub, REPO, "main", CONFIG).unwrap()), config());
}

#[test]
fn a_redirect_without_location_is_an_error_not_a_panic() {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let endpoint = format!("http://{}", listener.local_addr().unwrap());
    let server = std::thread::spawn(move || {
        // One answer: the client must give up on it, not retry.
        let (mut s, _) = listener.accept().unwrap();
        let mut buf = [0u8; 4096];
        let _ = s.read(&mut buf);
        let _ =
            s.write_all(b"HTTP/1.1 302 Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n");
    });
    let cache = tempfile::tempdir().unwrap();
    let e = get(
        &Hub::new(settings(&endpoint, cache.path())),
        REPO,
        "main",
        CONFIG,
    )
    .unwrap_err();
    assert!(matches!(e, HubError::BadResponse { .. }), "{e:?}");
    assert_mentions(&e.to_string(), &["without a Location", &endpoint]);
    server.join().unwrap();
}

#[test]
fn cached_repos_lists_refs_snapshots_and_counts_shared_blobs_once() {
    let hub_server = HubServer::start(spec());
    let cache = tempfile::tempdir().unwrap();
    let hub = Hub::new(settings(&hub_server.endpoint(), cache.path()));
    for (rev, file) in [
        ("main", CONFIG),
        ("main", WEIGHTS),
        ("refs/pr/1", CONFIG),
        ("refs/pr/1", WEIGHTS),
    ] {
        get(&hub, REPO, rev, file).unwrap();
    }
    std::fs::create_dir_all(cache.path().join(".locks")).unwrap();
    std::fs::write(cache.path().join("CACHEDIR.TAG"), "Signature").unwrap();
    let repos = cached_repos(cache.path()).unwrap();
    assert_eq!(repos.len(), 1);
    let r = &repos[0];
    assert_eq!((r.repo_id.as_str(), r.kind), (REPO, RepoKind::Model));
    let main = hub_server.commit(REPO, "main");
    let pr = hub_server.commit(REPO, "refs/pr/1");
    assert_eq!(r.refs.get("main"), Some(&main));
    assert_eq!(r.refs.get("refs/pr/1"), Some(&pr));
    assert_eq!(r.snapshots.len(), 2);
    for snap in &r.snapshots {
        let names: Vec<_> = snap.files.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, [CONFIG, WEIGHTS]);
    }
    let want = (config().len() + CONFIG_PR.len() + weights().len()) as u64;
    assert_eq!(
        r.size_on_disk, want,
        "the weights blob is shared by both snapshots"
    );
}

// ---- Interop with Python's huggingface_hub ----------------------------------------------------

const PY_SCRIPT: &str = r#"
import json, sys
from huggingface_hub import hf_hub_download, try_to_load_from_cache
mode, repo, rev, files = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4:]
out = {}
for f in files:
    cached = try_to_load_from_cache(repo, f, revision=rev)
    if mode == "offline" and cached is not None and not isinstance(cached, str):
        out[f] = "NO_EXIST"
        continue
    try:
        out[f] = hf_hub_download(repo, f, revision=rev)
    except Exception as e:
        if mode == "online" and "EntryNotFound" in type(e).__name__:
            out[f] = None
        else:
            raise
print(json.dumps(out))
"#;

/// The interpreter to use (`T2TF_PYTHON`, else `python3`). Tests calling this are ignored
/// where the build found none that imports huggingface_hub (`cfg(t2tf_python_hub)`,
/// build.rs); where they run, its absence fails them.
fn python() -> String {
    let python = std::env::var("T2TF_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&python)
        .args(["-c", "import huggingface_hub"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "{python} cannot import huggingface_hub (build.rs found one that could, or \
         T2TF_REQUIRE_PYTHON_HUB requires it; set T2TF_PYTHON to an interpreter that has it)"
    );
    python
}

/// Run the script with the cache and endpoint given and nothing else from this environment's
/// Hugging Face settings; returns file → path (or null / "NO_EXIST").
fn run_python(
    python: &str,
    endpoint: &str,
    cache: &Path,
    offline: bool,
    rev: &str,
    files: &[&str],
) -> HashMap<String, Option<String>> {
    let home = cache.parent().unwrap().join("py-home");
    let mut cmd = Command::new(python);
    for var in [
        "HF_TOKEN",
        "HUGGING_FACE_HUB_TOKEN",
        "HF_TOKEN_PATH",
        "HF_HUB_OFFLINE",
        "TRANSFORMERS_OFFLINE",
    ] {
        cmd.env_remove(var);
    }
    cmd.env("HF_ENDPOINT", endpoint)
        .env("HF_HUB_CACHE", cache)
        .env("HF_HOME", &home)
        .env("HF_HUB_DISABLE_TELEMETRY", "1")
        .env("HF_HUB_DISABLE_UPDATE_CHECK", "1")
        .env("HF_HUB_DISABLE_PROGRESS_BARS", "1")
        .env("HF_HUB_DISABLE_XET", "1")
        .env("NO_PROXY", "127.0.0.1,localhost")
        .args([
            "-c",
            PY_SCRIPT,
            if offline { "offline" } else { "online" },
            REPO,
            rev,
        ])
        .args(files);
    if offline {
        cmd.env("HF_HUB_OFFLINE", "1");
    }
    let out = cmd.output().expect("run python");
    assert!(
        out.status.success(),
        "python failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    let last = stdout.lines().last().unwrap_or("{}");
    serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {stdout}"))
}

#[test]
#[cfg_attr(
    not(t2tf_python_hub),
    ignore = "needs a python3 (or $T2TF_PYTHON) with huggingface_hub"
)]
fn pythons_download_is_found_by_us_offline() {
    let python = python();
    let hub_server = HubServer::start(spec());
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("hub");
    let files = [CONFIG, WEIGHTS, NESTED, "pytorch_model.bin"];
    let got = run_python(
        &python,
        &hub_server.endpoint(),
        &cache,
        false,
        "main",
        &files,
    );
    assert_eq!(got["pytorch_model.bin"], None);
    assert!(got[WEIGHTS].is_some());
    let python_asked = hub_server.requests().iter().any(|r| {
        r.path.starts_with("/cdn/")
            && r.header("user-agent")
                .is_some_and(|u| u.contains("hf_hub/"))
    });
    assert!(python_asked, "Python did not download through the stand-in");
    got_pr(&python, &hub_server, &cache);

    let off = offline(&cache);
    assert_eq!(read(get(&off, REPO, "main", CONFIG).unwrap()), config());
    assert_eq!(read(get(&off, REPO, "main", WEIGHTS).unwrap()), weights());
    assert_eq!(
        read(get(&off, REPO, "main", NESTED).unwrap()),
        blob(1000, 3)
    );
    assert_eq!(get(&off, REPO, "main", "pytorch_model.bin").unwrap(), None);
    assert_eq!(
        read(get(&off, REPO, "refs/pr/1", CONFIG).unwrap()),
        CONFIG_PR
    );

    // Online, the snapshot Python made is used as is: a HEAD, no GET.
    hub_server.clear_requests();
    let online = Hub::new(settings(&hub_server.endpoint(), &cache));
    assert_eq!(
        read(get(&online, REPO, "main", WEIGHTS).unwrap()),
        weights()
    );
    assert!(hub_server.requests().iter().all(|r| r.method == "HEAD"));
}

/// Python fetches `config.json` at `refs/pr/1` into `cache`.
fn got_pr(python: &str, hub_server: &HubServer, cache: &Path) {
    let got = run_python(
        python,
        &hub_server.endpoint(),
        cache,
        false,
        "refs/pr/1",
        &[CONFIG],
    );
    assert!(got[CONFIG].is_some());
}

#[test]
#[cfg_attr(
    not(t2tf_python_hub),
    ignore = "needs a python3 (or $T2TF_PYTHON) with huggingface_hub"
)]
fn our_download_is_found_by_python_offline() {
    let python = python();
    let hub_server = HubServer::start(spec());
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("hub");
    let hub = Hub::new(settings(&hub_server.endpoint(), &cache));
    for file in [CONFIG, WEIGHTS, NESTED] {
        get(&hub, REPO, "main", file).unwrap().unwrap();
    }
    assert_eq!(get(&hub, REPO, "main", "pytorch_model.bin").unwrap(), None);
    get(&hub, REPO, "refs/pr/1", CONFIG).unwrap().unwrap();
    drop(hub_server);

    let files = [CONFIG, WEIGHTS, NESTED, "pytorch_model.bin"];
    let got = run_python(&python, "http://127.0.0.1:9", &cache, true, "main", &files);
    let bytes = |f: &str| std::fs::read(got[f].as_deref().expect("a path")).unwrap();
    assert_eq!(bytes(CONFIG), config());
    assert_eq!(bytes(WEIGHTS), weights());
    assert_eq!(bytes(NESTED), blob(1000, 3));
    assert_eq!(got["pytorch_model.bin"].as_deref(), Some("NO_EXIST"));
    let got = run_python(
        &python,
        "http://127.0.0.1:9",
        &cache,
        true,
        "refs/pr/1",
        &[CONFIG],
    );
    assert_eq!(
        std::fs::read(got[CONFIG].as_deref().unwrap()).unwrap(),
        CONFIG_PR
    );
}
