//! A stand-in for the Hugging Face Hub, for tests: plain HTTP on `127.0.0.1`, one connection at
//! a time, every answer `Connection: close`, stopped when dropped.
//!
//! ```ignore
//! let mut spec = HubSpec::new().lfs_threshold(64);          // files of 64 bytes and more are LFS
//! let main = spec.repo("owner/tiny").revision("main", [("config.json", b"{}".to_vec())]);
//! spec.repo("owner/tiny").revision("refs/pr/1", [("config.json", b"{\"x\":1}".to_vec())]);
//! spec.repo("owner/gated").gated("hf_good").revision("main", [("a.txt", b"a".to_vec())]);
//! spec.repo("owner/clip").revision("main", files_in(Path::new("tests/fixtures/some_model")));
//! let hub = HubServer::start(spec);
//! // HF_ENDPOINT = hub.endpoint(); main == hub.commit("owner/tiny", "main")
//! hub.inject("model.safetensors", Fault::CutAfter(100), 1);  // first GET stops after 100 bytes
//! let log = hub.requests();                                   // method, path, host, headers
//! ```
//!
//! What it serves, as huggingface.co does:
//! - `HEAD|GET /{repo}/resolve/{revision}/{file}` (revision percent-encoded, so `refs%2Fpr%2F1`):
//!   - a file below the LFS threshold: `307`, relative `Location:
//!     /api/resolve-cache/models/{repo}/{commit}/{file}`, `X-Repo-Commit`, `ETag` (40 hex, like a
//!     git blob sha1); that path serves the bytes with the same headers;
//!   - an LFS file: `302`, absolute `Location: http://localhost:{port}/cdn/{sha256}?…` (another
//!     host name, same server), `X-Repo-Commit`, `X-Linked-Etag` (the sha256), `X-Linked-Size`,
//!     and an `ETag` that is *not* the blob's (as the Hub's pointer-file etag); `/cdn/` serves
//!     the bytes;
//!   - 404 `X-Error-Code: EntryNotFound` (with `X-Repo-Commit`) or `RevisionNotFound`;
//!     unknown repo: `RepoNotFound`, 401 without a token, 404 with one; a gated repo: 401
//!     `GatedRepo` without a token, 403 with a wrong one.
//! - `Range: bytes=N-` (or `N-M`) → 206 with `Content-Range`; past the end → 416.
//! - Faults injected per file name ([`Fault`]): cut bodies, wrong bytes, ignored ranges,
//!   statuses, bodies without end, gzip bombs, bodies dripping a byte at a time, bodies longer
//!   than the HEAD declared.
//! - `GET /api/models/{repo}/revision/{revision}` → `{"sha": …, "siblings": [{"rfilename": …}]}`.
//!
//! Commits are 40 hex digits derived from the repo id and its files, so two revisions with the
//! same files share a commit.

// Each test crate that includes this module uses only part of it.
#![allow(dead_code)]

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use sha2::{Digest, Sha256};

/// Files of this many bytes and more are served as LFS files unless [`HubSpec::lfs_threshold`]
/// says otherwise.
pub const DEFAULT_LFS_THRESHOLD: usize = 1024;

/// What the server holds: repos, their revisions and files.
#[derive(Clone, Debug)]
pub struct HubSpec {
    repos: BTreeMap<String, RepoSpec>,
    lfs_threshold: usize,
}

/// One repo: revision names → commits → files.
#[derive(Clone, Debug, Default)]
pub struct RepoSpec {
    id: String,
    revisions: BTreeMap<String, String>,
    commits: BTreeMap<String, BTreeMap<String, Vec<u8>>>,
    gated_token: Option<String>,
}

impl Default for HubSpec {
    fn default() -> Self {
        HubSpec::new()
    }
}

impl HubSpec {
    /// No repos; LFS from [`DEFAULT_LFS_THRESHOLD`] bytes.
    pub fn new() -> HubSpec {
        HubSpec {
            repos: BTreeMap::new(),
            lfs_threshold: DEFAULT_LFS_THRESHOLD,
        }
    }

    /// Files of `bytes` bytes and more are LFS files (302 to the CDN host, sha256 etag).
    pub fn lfs_threshold(mut self, bytes: usize) -> HubSpec {
        self.lfs_threshold = bytes;
        self
    }

    /// The repo `repo_id` (`owner/name`), created empty on first use.
    pub fn repo(&mut self, repo_id: &str) -> &mut RepoSpec {
        self.repos
            .entry(repo_id.to_string())
            .or_insert_with(|| RepoSpec {
                id: repo_id.to_string(),
                ..RepoSpec::default()
            })
    }
}

impl RepoSpec {
    /// Point `revision` (a branch such as `main`, a tag, or `refs/pr/N`) at a commit holding
    /// exactly `files` (names may contain `/`); returns the commit's sha.
    pub fn revision<N: Into<String>, B: Into<Vec<u8>>>(
        &mut self,
        revision: &str,
        files: impl IntoIterator<Item = (N, B)>,
    ) -> String {
        let files: BTreeMap<String, Vec<u8>> = files
            .into_iter()
            .map(|(n, b)| (n.into(), b.into()))
            .collect();
        let mut h = Sha256::new();
        h.update(self.id.as_bytes());
        for (name, bytes) in &files {
            h.update([0]);
            h.update(name.as_bytes());
            h.update((bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        }
        let commit = hex(&h.finalize())[..40].to_string();
        self.commits.insert(commit.clone(), files);
        self.revisions.insert(revision.to_string(), commit.clone());
        commit
    }

    /// Make the repo gated: only `Authorization: Bearer {token}` gets in.
    pub fn gated(&mut self, token: &str) -> &mut RepoSpec {
        self.gated_token = Some(token.to_string());
        self
    }

    fn commit_of(&self, revision: &str) -> Option<&str> {
        match self.revisions.get(revision) {
            Some(c) => Some(c),
            None => self
                .commits
                .get_key_value(revision)
                .map(|(c, _)| c.as_str()),
        }
    }
}

/// Every file under `dir` as (name relative to `dir` with `/`, bytes), sorted: a model folder
/// ready for [`RepoSpec::revision`].
pub fn files_in(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(folder) = stack.pop() {
        for entry in std::fs::read_dir(&folder).expect("readable folder") {
            let path = entry.expect("folder entry").path();
            if path.is_dir() {
                stack.push(path);
            } else {
                let name = path.strip_prefix(dir).expect("inside dir");
                let name: Vec<_> = name.iter().map(|c| c.to_string_lossy()).collect();
                out.push((name.join("/"), std::fs::read(&path).expect("readable file")));
            }
        }
    }
    out.sort();
    out
}

/// A misbehaviour for requests about one file name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// Announce the full length, send this many body bytes, close the connection.
    CutAfter(usize),
    /// Serve the right length with different bytes (a sha256 mismatch for LFS files).
    WrongBytes,
    /// Answer a `Range` request with 200 and the whole file.
    IgnoreRange,
    /// Answer with this status (also the HEAD on `/resolve/`), no body.
    Status(u16),
    /// Send the file, then filler bytes without end (no `Content-Length`, on a HEAD too; until
    /// the client hangs up, or 8 GiB).
    Endless,
    /// Send this many zero bytes gzip-compressed, with `Content-Encoding: gzip`.
    GzipBomb(u64),
    /// Send the body one byte per this many milliseconds (for at most 60 s).
    Drip(u64),
    /// Append this many bytes to the body (its `Content-Length` counts them; the HEAD's
    /// `X-Linked-Size` does not).
    ExtraBytes(usize),
}

/// One request as the server saw it.
#[derive(Clone, Debug)]
pub struct Request {
    pub method: String,
    /// Path and query, as sent (percent-encoded).
    pub path: String,
    /// The `Host` header.
    pub host: String,
    /// Header names in lower case.
    pub headers: Vec<(String, String)>,
}

impl Request {
    /// The first header of that (lower-case) name.
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_str())
    }
}

/// The running server.
pub struct HubServer {
    addr: SocketAddr,
    state: Arc<State>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

struct State {
    spec: HubSpec,
    port: u16,
    faults: Mutex<Vec<(String, Fault, usize)>>,
    log: Mutex<Vec<Request>>,
}

/// A lock that survives a panicked test thread.
fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

impl HubServer {
    /// Serve `spec` on a free port of 127.0.0.1.
    pub fn start(spec: HubSpec) -> HubServer {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1");
        let addr = listener.local_addr().expect("local address");
        let state = Arc::new(State {
            spec,
            port: addr.port(),
            faults: Mutex::new(Vec::new()),
            log: Mutex::new(Vec::new()),
        });
        let stop = Arc::new(AtomicBool::new(false));
        let thread = {
            let (state, stop) = (state.clone(), stop.clone());
            std::thread::spawn(move || {
                for stream in listener.incoming() {
                    if stop.load(Ordering::SeqCst) {
                        break;
                    }
                    if let Ok(stream) = stream {
                        serve(&state, stream);
                    }
                }
            })
        };
        HubServer {
            addr,
            state,
            stop,
            thread: Some(thread),
        }
    }

    /// `http://127.0.0.1:{port}`: what `HF_ENDPOINT` should be.
    pub fn endpoint(&self) -> String {
        format!("http://{}", self.addr)
    }

    /// `localhost:{port}`: the host name LFS downloads are redirected to.
    pub fn cdn_host(&self) -> String {
        format!("localhost:{}", self.addr.port())
    }

    /// The commit `revision` of `repo` points at.
    pub fn commit(&self, repo: &str, revision: &str) -> String {
        self.state.spec.repos[repo]
            .commit_of(revision)
            .expect("known revision")
            .to_string()
    }

    /// Misbehave on the next `times` requests to which `fault` applies for files named `file`.
    pub fn inject(&self, file: &str, fault: Fault, times: usize) {
        lock(&self.state.faults).push((file.to_string(), fault, times));
    }

    /// Every request so far, oldest first.
    pub fn requests(&self) -> Vec<Request> {
        lock(&self.state.log).clone()
    }

    /// Forget the requests so far.
    pub fn clear_requests(&self) {
        lock(&self.state.log).clear();
    }

    /// Whether any request to the CDN host carried an `Authorization` header.
    pub fn cdn_saw_authorization(&self) -> bool {
        self.requests()
            .iter()
            .any(|r| r.path.starts_with("/cdn/") && r.header("authorization").is_some())
    }
}

impl Drop for HubServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        // Wake the accept loop so it sees the flag.
        let _ = TcpStream::connect_timeout(&self.addr, Duration::from_secs(1));
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// An answer to write.
struct Reply {
    status: u16,
    headers: Vec<(String, String)>,
    body: Vec<u8>,
    /// Send only this many body bytes, then close.
    cut_after: Option<usize>,
    /// Follow the body with filler bytes without end, and send no `Content-Length`.
    endless: bool,
    /// Send the body one byte at a time with this pause before each.
    drip: Option<Duration>,
}

impl Reply {
    fn new(status: u16) -> Reply {
        Reply {
            status,
            headers: Vec::new(),
            body: Vec::new(),
            cut_after: None,
            endless: false,
            drip: None,
        }
    }

    fn header(mut self, name: &str, value: impl Into<String>) -> Reply {
        self.headers.push((name.to_string(), value.into()));
        self
    }

    fn error(status: u16, code: &str, message: &str) -> Reply {
        Reply::new(status)
            .header("X-Error-Code", code)
            .header("X-Error-Message", message)
    }
}

fn serve(state: &State, mut stream: TcpStream) {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(5)));
    let _ = stream.set_write_timeout(Some(Duration::from_secs(5)));
    let Some(request) = read_request(&mut stream) else {
        return;
    };
    lock(&state.log).push(request.clone());
    let reply = route(state, &request);
    let _ = write_reply(&mut stream, &request, reply);
}

fn read_request(stream: &mut TcpStream) -> Option<Request> {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 4096];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = stream.read(&mut chunk).ok()?;
        if n == 0 || buf.len() > 64 << 10 {
            return None;
        }
        buf.extend_from_slice(&chunk[..n]);
    }
    let text = String::from_utf8_lossy(&buf);
    let mut lines = text.split("\r\n");
    let mut first = lines.next()?.split(' ');
    let (method, path) = (first.next()?.to_string(), first.next()?.to_string());
    let headers: Vec<(String, String)> = lines
        .take_while(|l| !l.is_empty())
        .filter_map(|l| l.split_once(':'))
        .map(|(n, v)| (n.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let host = headers
        .iter()
        .find(|(n, _)| n == "host")
        .map_or(String::new(), |(_, v)| v.clone());
    Some(Request {
        method,
        path,
        host,
        headers,
    })
}

fn write_reply(stream: &mut TcpStream, request: &Request, reply: Reply) -> std::io::Result<()> {
    let mut head = format!("HTTP/1.1 {} {}\r\n", reply.status, reason(reply.status));
    for (n, v) in &reply.headers {
        head.push_str(&format!("{n}: {v}\r\n"));
    }
    if !reply.endless {
        head.push_str(&format!("Content-Length: {}\r\n", reply.body.len()));
    }
    head.push_str("Connection: close\r\n\r\n");
    stream.write_all(head.as_bytes())?;
    if request.method != "HEAD" {
        let n = reply
            .cut_after
            .unwrap_or(reply.body.len())
            .min(reply.body.len());
        match reply.drip {
            Some(pause) => {
                let start = std::time::Instant::now();
                for b in &reply.body[..n] {
                    if start.elapsed() > Duration::from_secs(60) {
                        break;
                    }
                    std::thread::sleep(pause);
                    stream.write_all(&[*b])?;
                    stream.flush()?;
                }
            }
            None => stream.write_all(&reply.body[..n])?,
        }
        if reply.endless {
            let filler = vec![b' '; 1 << 20];
            for _ in 0..8192 {
                stream.write_all(&filler)?;
            }
        }
    }
    stream.flush()
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        206 => "Partial Content",
        302 => "Found",
        307 => "Temporary Redirect",
        401 => "Unauthorized",
        403 => "Forbidden",
        404 => "Not Found",
        416 => "Range Not Satisfiable",
        _ => "Status",
    }
}

fn route(state: &State, req: &Request) -> Reply {
    if req.method != "GET" && req.method != "HEAD" {
        return Reply::new(405);
    }
    let path = req.path.split('?').next().unwrap_or("");
    if let Some(sha) = path.strip_prefix("/cdn/") {
        return cdn(state, req, sha);
    }
    if let Some(rest) = path.strip_prefix("/api/resolve-cache/models/") {
        return resolve_cache(state, req, rest);
    }
    if let Some(rest) = path.strip_prefix("/api/models/") {
        return revision_info(state, req, rest);
    }
    match path.split_once("/resolve/") {
        Some((repo, rest)) => resolve(state, req, repo.trim_start_matches('/'), rest),
        None => Reply::new(404),
    }
}

/// The repo, or the Hub's answer for an unknown or gated one.
fn access<'s>(state: &'s State, req: &Request, repo_id: &str) -> Result<&'s RepoSpec, Reply> {
    let token = req
        .header("authorization")
        .and_then(|v| v.strip_prefix("Bearer "));
    let Some(repo) = state.spec.repos.get(repo_id) else {
        let status = if token.is_some() { 404 } else { 401 };
        return Err(Reply::error(status, "RepoNotFound", "Repository not found"));
    };
    match (&repo.gated_token, token) {
        (Some(_), None) => Err(Reply::error(
            401,
            "GatedRepo",
            "Access to this gated repo is restricted",
        )),
        (Some(want), Some(got)) if want != got => Err(Reply::error(
            403,
            "GatedRepo",
            "Access to this gated repo is restricted",
        )),
        _ => Ok(repo),
    }
}

/// `/{repo}/resolve/{revision}/{file}`: redirect to where the bytes are.
fn resolve(state: &State, req: &Request, repo_id: &str, rest: &str) -> Reply {
    let repo = match access(state, req, repo_id) {
        Ok(r) => r,
        Err(reply) => return reply,
    };
    let (revision, file) = rest.split_once('/').unwrap_or((rest, ""));
    let (revision, file) = (percent_decode(revision), percent_decode(file));
    let Some(commit) = repo.commit_of(&revision) else {
        return Reply::error(404, "RevisionNotFound", "Invalid rev id");
    };
    let Some(bytes) = repo.commits[commit].get(&file) else {
        return Reply::error(404, "EntryNotFound", "Entry not found")
            .header("X-Repo-Commit", commit);
    };
    if let Some(status) = take_status_fault(state, &file) {
        return Reply::new(status);
    }
    if bytes.len() < state.spec.lfs_threshold {
        let location = format!(
            "/api/resolve-cache/models/{repo_id}/{commit}/{}",
            quote_path(&file)
        );
        return Reply::new(307)
            .header("Location", location)
            .header("X-Repo-Commit", commit)
            .header("ETag", format!("\"{}\"", git_etag(bytes)));
    }
    let sha = hex(&Sha256::digest(bytes));
    let location = format!(
        "http://{}/cdn/{sha}?X-Amz-Signature=abc&response-content-disposition=attachment",
        format_args!("localhost:{}", state.port)
    );
    Reply::new(302)
        .header("Location", location)
        .header("X-Repo-Commit", commit)
        .header("X-Linked-Etag", format!("\"{sha}\""))
        .header("X-Linked-Size", bytes.len().to_string())
        .header("ETag", format!("\"{}\"", git_etag(sha.as_bytes())))
}

/// `/api/resolve-cache/models/{repo}/{commit}/{file}`: a small file's bytes.
fn resolve_cache(state: &State, req: &Request, rest: &str) -> Reply {
    let found = state.spec.repos.keys().find_map(|id| {
        let tail = rest.strip_prefix(id.as_str())?.strip_prefix('/')?;
        let (commit, file) = tail.split_once('/')?;
        Some((id.as_str(), commit.to_string(), percent_decode(file)))
    });
    let Some((repo_id, commit, file)) = found else {
        return Reply::new(404);
    };
    let repo = match access(state, req, repo_id) {
        Ok(r) => r,
        Err(reply) => return reply,
    };
    let Some(bytes) = repo.commits.get(&commit).and_then(|f| f.get(&file)) else {
        return Reply::error(404, "EntryNotFound", "Entry not found");
    };
    bytes_reply(state, req, &file, bytes)
        .header("X-Repo-Commit", commit)
        .header("ETag", format!("\"{}\"", git_etag(bytes)))
}

/// `/cdn/{sha256}`: an LFS file's bytes, whoever asks (like a signed CDN URL).
fn cdn(state: &State, req: &Request, sha: &str) -> Reply {
    let found = state.spec.repos.values().find_map(|repo| {
        repo.commits
            .values()
            .find_map(|files| files.iter().find(|(_, b)| hex(&Sha256::digest(b)) == sha))
    });
    match found {
        Some((file, bytes)) => bytes_reply(state, req, file, bytes),
        None => Reply::new(404),
    }
}

/// `/api/models/{repo}/revision/{revision}`: the commit and its file names.
fn revision_info(state: &State, req: &Request, rest: &str) -> Reply {
    let Some((repo_id, revision)) = rest.split_once("/revision/") else {
        return Reply::new(404);
    };
    let repo = match access(state, req, repo_id) {
        Ok(r) => r,
        Err(reply) => return reply,
    };
    let Some(commit) = repo.commit_of(&percent_decode(revision)) else {
        return Reply::error(404, "RevisionNotFound", "Invalid rev id");
    };
    let siblings: Vec<_> = repo.commits[commit]
        .keys()
        .map(|f| serde_json::json!({ "rfilename": f }))
        .collect();
    let body = serde_json::json!({ "id": repo_id, "sha": commit, "siblings": siblings });
    let mut reply = Reply::new(200).header("Content-Type", "application/json");
    reply.body = body.to_string().into_bytes();
    reply
}

/// The bytes of `file`, honouring `Range` and the faults injected for it.
fn bytes_reply(state: &State, req: &Request, file: &str, bytes: &[u8]) -> Reply {
    if let Some(status) = take_status_fault(state, file) {
        return Reply::new(status);
    }
    let get = req.method == "GET";
    let mut data = bytes.to_vec();
    if get && take_fault(state, file, |f| f == Fault::WrongBytes).is_some() {
        data.iter_mut().for_each(|b| *b ^= 0x5a);
    }
    let range = req.header("range").and_then(parse_range);
    let ignore =
        range.is_some() && get && take_fault(state, file, |f| f == Fault::IgnoreRange).is_some();
    let mut reply = match range.filter(|_| !ignore) {
        Some((start, _)) if start >= data.len() => {
            return Reply::new(416).header("Content-Range", format!("bytes */{}", data.len()))
        }
        Some((start, end)) => {
            let end = end.unwrap_or(data.len() - 1).min(data.len() - 1);
            let mut r = Reply::new(206).header(
                "Content-Range",
                format!("bytes {start}-{end}/{}", data.len()),
            );
            r.body = data[start..=end].to_vec();
            r
        }
        None => {
            let mut r = Reply::new(200);
            r.body = data;
            r
        }
    };
    // Without end: no Content-Length, for the HEAD too.
    if take_fault(state, file, |f| f == Fault::Endless).is_some() {
        reply.endless = true;
    }
    if get {
        if let Some(Fault::CutAfter(n)) =
            take_fault(state, file, |f| matches!(f, Fault::CutAfter(_)))
        {
            reply.cut_after = Some(n);
        }
        if let Some(Fault::Drip(ms)) = take_fault(state, file, |f| matches!(f, Fault::Drip(_))) {
            reply.drip = Some(Duration::from_millis(ms));
        }
        if let Some(Fault::ExtraBytes(n)) =
            take_fault(state, file, |f| matches!(f, Fault::ExtraBytes(_)))
        {
            reply.body.extend(std::iter::repeat_n(b'x', n));
        }
        if let Some(Fault::GzipBomb(n)) =
            take_fault(state, file, |f| matches!(f, Fault::GzipBomb(_)))
        {
            reply.body = gzip_zeros(n);
            reply = reply.header("Content-Encoding", "gzip");
        }
    }
    reply.header("Accept-Ranges", "bytes")
}

/// `n` zero bytes, gzip-compressed (about 1,000 times smaller).
fn gzip_zeros(n: u64) -> Vec<u8> {
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    let zeros = vec![0u8; 1 << 20];
    let mut left = n;
    while left > 0 {
        let k = left.min(zeros.len() as u64) as usize;
        gz.write_all(&zeros[..k]).expect("in memory");
        left -= k as u64;
    }
    gz.finish().expect("in memory")
}

/// `bytes=N-` or `bytes=N-M`.
fn parse_range(value: &str) -> Option<(usize, Option<usize>)> {
    let (start, end) = value.trim().strip_prefix("bytes=")?.split_once('-')?;
    Some((start.parse().ok()?, end.parse().ok()))
}

fn take_status_fault(state: &State, file: &str) -> Option<u16> {
    match take_fault(state, file, |f| matches!(f, Fault::Status(_))) {
        Some(Fault::Status(s)) => Some(s),
        _ => None,
    }
}

/// Use up one of the pending faults for `file` that `wanted` accepts.
fn take_fault(state: &State, file: &str, wanted: impl Fn(Fault) -> bool) -> Option<Fault> {
    let mut faults = lock(&state.faults);
    let i = faults
        .iter()
        .position(|(f, fault, times)| f == file && *times > 0 && wanted(*fault))?;
    faults[i].2 -= 1;
    Some(faults[i].1)
}

/// A 40-hex etag for a small file, like git's blob sha1 (sha256 of the same header, cut).
fn git_etag(bytes: &[u8]) -> String {
    let mut h = Sha256::new();
    h.update(format!("blob {}\0", bytes.len()));
    h.update(bytes);
    hex(&h.finalize())[..40].to_string()
}

pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn quote_path(s: &str) -> String {
    s.bytes()
        .map(|b| {
            if b.is_ascii_alphanumeric() || b"-._~/".contains(&b) {
                (b as char).to_string()
            } else {
                format!("%{b:02X}")
            }
        })
        .collect()
}

fn percent_decode(s: &str) -> String {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hexpair = bytes
            .get(i + 1..i + 3)
            .and_then(|h| std::str::from_utf8(h).ok())
            .and_then(|h| u8::from_str_radix(h, 16).ok());
        match (bytes[i], hexpair) {
            (b'%', Some(v)) => {
                out.push(v);
                i += 3;
            }
            (b, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}
