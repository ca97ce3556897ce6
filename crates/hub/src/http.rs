//! Requests to the Hub, as `huggingface_hub` makes them: a HEAD on `/resolve/` that follows the
//! Hub's own redirects (relative, or to a Hub origin) and stops at the first redirect elsewhere
//! (the CDN), whose `Location` is where the bytes are fetched from, without the token.
//!
//! Bodies come as they are stored: `Accept-Encoding: identity` is asked for and a body with any
//! other `Content-Encoding` is refused, so a small compressed answer can never inflate past the
//! sizes `download` checks. A read of a body waits at most the stall timeout
//! (`T2TF_HUB_STALL_TIMEOUT` seconds, default 30), which `download` also holds the whole
//! transfer's progress to; an answer's headers must come within 30 s.

use std::time::Duration;

use ureq::http::{Response, Uri};
use ureq::{Agent, Body};

use super::HubError;

/// Hops followed before giving up (Python's `_MAX_REDIRECTS`).
const MAX_REDIRECTS: usize = 5;
/// Origins that always get the token, besides the endpoint's own (as `huggingface_hub`).
const HUB_ORIGINS: [&str; 2] = ["https://huggingface.co", "https://hf.co"];

/// An HTTP client bound to one endpoint and token.
pub(crate) struct Client {
    agent: Agent,
    endpoint: String,
    token: Option<String>,
    /// The longest a read may wait, and the time a download must get 1 KiB within.
    pub(crate) stall: Duration,
}

/// The file a request is about, for error messages.
pub(crate) struct Target<'a> {
    pub repo: &'a str,
    pub revision: &'a str,
    pub file: &'a str,
}

/// What a HEAD on `/resolve/` says about a file.
#[derive(Debug)]
pub(crate) struct Metadata {
    /// `X-Repo-Commit`: the commit the revision resolved to.
    pub commit: String,
    /// `X-Linked-Etag`, else `ETag`: the blob name (sha256 for LFS files).
    pub etag: String,
    /// `X-Linked-Size`, else `Content-Length` of a non-redirect answer.
    pub size: Option<u64>,
    /// Where to GET the bytes.
    pub location: String,
}

/// The outcome of a HEAD.
#[derive(Debug)]
pub(crate) enum Head {
    Found(Metadata),
    /// 404 `EntryNotFound`, with the commit if the Hub named it.
    EntryNotFound {
        commit: Option<String>,
    },
}

impl Client {
    /// A client with bounded timeouts (`stall`: the longest a read may wait); redirects and
    /// statuses are handled here, not by ureq.
    pub(crate) fn new(endpoint: &str, token: Option<String>, stall: Duration) -> Client {
        let agent = Agent::config_builder()
            .max_redirects(0)
            .http_status_as_error(false)
            .timeout_resolve(Some(Duration::from_secs(10)))
            .timeout_connect(Some(Duration::from_secs(10)))
            .timeout_recv_response(Some(Duration::from_secs(30)))
            .timeout_per_read(Some(stall))
            .user_agent(concat!("t2tf/", env!("CARGO_PKG_VERSION")))
            // Compression would make sizes and ranges those of the compressed stream.
            .accept_encoding("identity")
            .build()
            .into();
        Client {
            agent,
            endpoint: endpoint.to_string(),
            token,
            stall,
        }
    }

    /// `{endpoint}/{repo}/resolve/{revision}/{file}`, quoted as `huggingface_hub.hf_hub_url`
    /// does (the revision with no safe characters, so `refs/pr/1` is one segment).
    pub(crate) fn file_url(&self, repo: &str, revision: &str, file: &str) -> String {
        format!(
            "{}/{repo}/resolve/{}/{}",
            self.endpoint,
            quote(revision, ""),
            quote(file, "/")
        )
    }

    /// HEAD `url`, following the Hub's redirects.
    pub(crate) fn head(&self, url: &str, target: &Target) -> Result<Head, HubError> {
        let mut url = url.to_string();
        for _ in 0..=MAX_REDIRECTS {
            let response = self.send("HEAD", &url, 0, target)?;
            let status = response.status().as_u16();
            if !is_redirect(status) {
                if (200..300).contains(&status) {
                    return metadata(&response, &url, url.clone()).map(Head::Found);
                }
                if header(&response, "x-error-code").as_deref() == Some("EntryNotFound") {
                    let commit = header(&response, "x-repo-commit");
                    return Ok(Head::EntryNotFound {
                        commit: commit.filter(|c| is_path_component(c)),
                    });
                }
                return Err(self.status_error(&response, &url, target));
            }
            let next = redirect_target(&response, &url)?;
            if !self.is_hub_origin(&next) {
                return metadata(&response, &url, next).map(Head::Found);
            }
            url = next;
        }
        Err(too_many_redirects(&url))
    }

    /// GET `url` from byte `start` on, following redirects (the token only goes to Hub origins).
    /// Answers other than 200, 206 and 416 become errors.
    pub(crate) fn get(
        &self,
        url: &str,
        start: u64,
        target: &Target,
    ) -> Result<Response<Body>, HubError> {
        let mut url = url.to_string();
        for _ in 0..=MAX_REDIRECTS {
            let response = self.send("GET", &url, start, target)?;
            let status = response.status().as_u16();
            if is_redirect(status) {
                url = redirect_target(&response, &url)?;
                continue;
            }
            if matches!(status, 200 | 206 | 416) {
                return identity(response, &url);
            }
            return Err(self.status_error(&response, &url, target));
        }
        Err(too_many_redirects(&url))
    }

    fn send(
        &self,
        method: &str,
        url: &str,
        start: u64,
        target: &Target,
    ) -> Result<Response<Body>, HubError> {
        let mut request = if method == "HEAD" {
            self.agent.head(url)
        } else {
            self.agent.get(url)
        };
        if let Some(token) = self.token_for(url) {
            request = request.header("Authorization", format!("Bearer {token}"));
        }
        if start > 0 {
            request = request.header("Range", format!("bytes={start}-"));
        }
        request.call().map_err(|e| HubError::Network {
            repo: target.repo.to_string(),
            file: target.file.to_string(),
            url: url.to_string(),
            reason: e.to_string(),
        })
    }

    /// The token, when there is one and `url` is on the Hub (never a CDN or other host).
    fn token_for(&self, url: &str) -> Option<&str> {
        self.token.as_deref().filter(|_| self.is_hub_origin(url))
    }

    fn is_hub_origin(&self, url: &str) -> bool {
        let Some(o) = origin(url) else { return false };
        origin(&self.endpoint).as_ref() == Some(&o)
            || HUB_ORIGINS.iter().any(|h| origin(h).as_ref() == Some(&o))
    }

    /// The error an unexpected status stands for, from `X-Error-Code` and whether a token went out.
    fn status_error(&self, response: &Response<Body>, url: &str, target: &Target) -> HubError {
        let status = response.status().as_u16();
        let token_sent = self.token_for(url).is_some();
        let repo = target.repo.to_string();
        let url = url.to_string();
        let page = format!("{}/{}", self.endpoint, target.repo);
        match header(response, "x-error-code").as_deref() {
            Some("RevisionNotFound") => HubError::RevisionNotFound {
                repo,
                revision: target.revision.to_string(),
                url,
                status,
            },
            Some("RepoNotFound") => HubError::RepoNotFound {
                repo,
                url,
                status,
                hint: if token_sent {
                    "if it is private, the token in use cannot see it"
                } else {
                    "if it is private or gated, set HF_TOKEN or log in with `huggingface-cli login`"
                },
            },
            code if code == Some("GatedRepo") || status == 401 || status == 403 => {
                if token_sent {
                    HubError::AccessDenied {
                        repo,
                        url,
                        status,
                        page,
                    }
                } else {
                    HubError::AuthRequired {
                        repo,
                        url,
                        status,
                        page,
                    }
                }
            }
            code => HubError::Status {
                url,
                status,
                detail: match (code, header(response, "x-error-message")) {
                    (_, Some(m)) => format!(": {}", one_line(&m)),
                    (Some(c), None) => format!(": {}", one_line(c)),
                    (None, None) => String::new(),
                },
            },
        }
    }
}

/// `response` when its body is not compressed; a `Content-Encoding` other than `identity` (we
/// asked for identity) is refused before a byte is read, so no compressed bomb is inflated.
fn identity(response: Response<Body>, url: &str) -> Result<Response<Body>, HubError> {
    match header(&response, "content-encoding") {
        Some(e) if !e.trim().is_empty() && !e.trim().eq_ignore_ascii_case("identity") => {
            Err(HubError::BadResponse {
                url: url.to_string(),
                reason: format!(
                    "the body is compressed (Content-Encoding: {}) though identity was asked for; \
                     t2tf does not inflate downloads",
                    one_line(&e)
                ),
            })
        }
        _ => Ok(response),
    }
}

fn is_redirect(status: u16) -> bool {
    matches!(status, 301 | 302 | 303 | 307 | 308)
}

fn too_many_redirects(url: &str) -> HubError {
    HubError::BadResponse {
        url: url.to_string(),
        reason: format!("more than {MAX_REDIRECTS} redirects"),
    }
}

/// The absolute URL a redirect points to.
fn redirect_target(response: &Response<Body>, url: &str) -> Result<String, HubError> {
    let location = header(response, "location").ok_or_else(|| HubError::BadResponse {
        url: url.to_string(),
        reason: format!(
            "HTTP {} redirect without a Location header",
            response.status().as_u16()
        ),
    })?;
    join_url(url, &location).ok_or_else(|| HubError::BadResponse {
        url: url.to_string(),
        reason: format!("cannot follow the redirect to {location:?}"),
    })
}

/// File metadata from the answer to a HEAD on `url`; the GET goes to `location`.
fn metadata(response: &Response<Body>, url: &str, location: String) -> Result<Metadata, HubError> {
    let bad = |reason: &str| HubError::BadResponse {
        url: url.to_string(),
        reason: reason.to_string(),
    };
    let commit = header(response, "x-repo-commit")
        .ok_or_else(|| bad("no X-Repo-Commit header, so it is not a Hugging Face Hub answer"))?;
    let etag = header(response, "x-linked-etag")
        .or_else(|| header(response, "etag"))
        .map(|e| normalize_etag(&e))
        .ok_or_else(|| bad("no ETag header, so the file cannot be cached"))?;
    if !is_path_component(&commit) || !is_path_component(&etag) {
        return Err(bad("X-Repo-Commit or ETag is not a plain name"));
    }
    let length = || {
        if is_redirect(response.status().as_u16()) {
            None
        } else {
            header(response, "content-length")
        }
    };
    let size = header(response, "x-linked-size")
        .or_else(length)
        .and_then(|s| s.trim().parse().ok());
    Ok(Metadata {
        commit,
        etag,
        size,
        location,
    })
}

/// A response header as text.
pub(crate) fn header(response: &Response<Body>, name: &str) -> Option<String> {
    response
        .headers()
        .get(name)
        .and_then(|v| v.to_str().ok())
        .map(str::to_string)
}

/// An ETag without `W/` and quotes (Python's `_normalize_etag`).
pub(crate) fn normalize_etag(etag: &str) -> String {
    let e = etag.trim();
    e.strip_prefix("W/")
        .unwrap_or(e)
        .trim_matches('"')
        .to_string()
}

/// Safe as one path component in the cache (server data becomes folder and file names).
pub(crate) fn is_path_component(s: &str) -> bool {
    !s.is_empty()
        && s != "."
        && s != ".."
        && s.bytes()
            .all(|b| b.is_ascii_alphanumeric() || b"-_.".contains(&b))
}

/// Percent-encode all but unreserved characters and `safe` (Python's `urllib.parse.quote`).
pub(crate) fn quote(s: &str, safe: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || b"-._~".contains(&b) || safe.as_bytes().contains(&b) {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// (scheme, host, port) of an absolute URL, the port defaulted from the scheme.
fn origin(url: &str) -> Option<(String, String, u16)> {
    let uri: Uri = url.parse().ok()?;
    let scheme = uri.scheme_str()?.to_ascii_lowercase();
    let host = uri.host()?.to_ascii_lowercase();
    let port = uri
        .port_u16()
        .unwrap_or(if scheme == "https" { 443 } else { 80 });
    Some((scheme, host, port))
}

/// `location` resolved against `base` (absolute, scheme-relative, absolute-path or relative).
fn join_url(base: &str, location: &str) -> Option<String> {
    if location.contains("://") {
        return Some(location.to_string());
    }
    let uri: Uri = base.parse().ok()?;
    let scheme = uri.scheme_str()?;
    if let Some(rest) = location.strip_prefix("//") {
        return Some(format!("{scheme}://{rest}"));
    }
    let authority = uri.authority()?.as_str();
    if location.starts_with('/') {
        return Some(format!("{scheme}://{authority}{location}"));
    }
    let dir = uri.path().rsplit_once('/').map_or("", |(d, _)| d);
    Some(format!("{scheme}://{authority}{dir}/{location}"))
}

/// Header text is the server's: keep a message to one line.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_quote_like_python() {
        let c = Client::new("http://h:1", None, Duration::from_secs(1));
        assert_eq!(
            c.file_url("o/n", "refs/pr/15", "sub dir/a+b.json"),
            "http://h:1/o/n/resolve/refs%2Fpr%2F15/sub%20dir/a%2Bb.json"
        );
        assert_eq!(quote("v1.0~x_y-z", ""), "v1.0~x_y-z");
    }

    #[test]
    fn redirects_resolve_and_origins_compare() {
        let base = "http://127.0.0.1:8/o/n/resolve/main/f";
        assert_eq!(
            join_url(base, "/api/resolve-cache/x").as_deref(),
            Some("http://127.0.0.1:8/api/resolve-cache/x")
        );
        assert_eq!(
            join_url(base, "g").as_deref(),
            Some("http://127.0.0.1:8/o/n/resolve/main/g")
        );
        assert_eq!(join_url(base, "//cdn/x").as_deref(), Some("http://cdn/x"));
        assert_eq!(
            join_url(base, "https://cdn/x?a=1").as_deref(),
            Some("https://cdn/x?a=1")
        );
        let c = Client::new(
            "http://127.0.0.1:8",
            Some("t".into()),
            Duration::from_secs(1),
        );
        assert!(c.token_for(base).is_some());
        assert!(c.token_for("http://localhost:8/cdn/x").is_none());
        assert!(c.token_for("http://127.0.0.1:9/x").is_none());
        assert!(c.token_for("https://huggingface.co/x").is_some());
        assert!(c.token_for("https://huggingface.co:444/x").is_none());
    }

    #[test]
    fn etags_and_names() {
        assert_eq!(normalize_etag("W/\"abc\""), "abc");
        assert_eq!(normalize_etag("\"abc\""), "abc");
        assert!(is_path_component("0123abc"));
        for bad in ["", ".", "..", "a/b", "a\\b", "a b"] {
            assert!(!is_path_component(bad), "{bad}");
        }
    }
}
