//! Settings from the environment, read the way `huggingface_hub` reads them (its `constants.py`
//! and `utils/_auth.py`), so that `t2tf` and Python share one cache, token and endpoint.

use std::path::{Path, PathBuf};
use std::time::Duration;

use super::HubSettings;

/// The public Hub.
pub(crate) const DEFAULT_ENDPOINT: &str = "https://huggingface.co";
/// The stall timeout unless `T2TF_HUB_STALL_TIMEOUT` says otherwise.
pub const DEFAULT_STALL: Duration = Duration::from_secs(30);

/// The stall timeout from `T2TF_HUB_STALL_TIMEOUT`'s value; the default when unset or not a
/// positive number of seconds (up to a day).
fn stall_timeout(value: Option<String>) -> Duration {
    value
        .and_then(|v| v.trim().parse::<f64>().ok())
        .filter(|s| s.is_finite() && *s > 0.0 && *s <= 86_400.0)
        .map_or(DEFAULT_STALL, Duration::from_secs_f64)
}

impl HubSettings {
    /// Settings from this process's environment; see [`HubSettings::from_lookup`].
    pub fn from_env() -> HubSettings {
        HubSettings::from_lookup(|name| std::env::var(name).ok())
    }

    /// The settings of an environment that sets none of the variables: the public Hub,
    /// Python's default cache folder under the user's home, no token, online, with progress,
    /// the default stall timeout.
    pub fn defaults() -> HubSettings {
        HubSettings::from_lookup(|_| None)
    }

    /// Settings from the variables `lookup` returns (empty values count as unset):
    ///
    /// - endpoint: `HF_ENDPOINT` (trailing `/` trimmed), else <https://huggingface.co>;
    /// - cache: `HF_HUB_CACHE`, else `HUGGINGFACE_HUB_CACHE`, else `$HF_HOME/hub`, where `HF_HOME`
    ///   defaults to `$XDG_CACHE_HOME/huggingface`, else `~/.cache/huggingface`;
    /// - token: `HF_TOKEN`, else `HUGGING_FACE_HUB_TOKEN`, else the file `HF_TOKEN_PATH`, else
    ///   `$HF_HOME/token` (what `huggingface-cli login` writes), trimmed;
    /// - offline: `HF_HUB_OFFLINE` (else `TRANSFORMERS_OFFLINE`) is 1, true, yes or on;
    /// - progress: unless `HF_HUB_DISABLE_PROGRESS_BARS` is true;
    /// - stall timeout: `T2TF_HUB_STALL_TIMEOUT` seconds (above 0, up to a day), else 30.
    ///
    /// A leading `~` in a path is the home directory, found as Python's `expanduser` finds it:
    /// `HOME` on Unix; `USERPROFILE`, else `HOMEDRIVE` + `HOMEPATH`, on Windows (where Python
    /// ignores `HOME`); else the system's record of the user.
    pub fn from_lookup(lookup: impl Fn(&str) -> Option<String>) -> HubSettings {
        let var = |name: &str| lookup(name).filter(|v| !v.trim().is_empty());
        let home = home_from(&var, cfg!(windows)).or_else(t2tf_core::platform::home_dir);
        let path = |v: String| expand_home(&v, home.as_deref());
        let hf_home = var("HF_HOME").map(path).unwrap_or_else(|| {
            let cache = var("XDG_CACHE_HOME")
                .map(path)
                .unwrap_or_else(|| home.clone().unwrap_or_default().join(".cache"));
            cache.join("huggingface")
        });
        let cache_dir = var("HF_HUB_CACHE")
            .or_else(|| var("HUGGINGFACE_HUB_CACHE"))
            .map(path)
            .unwrap_or_else(|| hf_home.join("hub"));
        let token_path = var("HF_TOKEN_PATH")
            .map(path)
            .unwrap_or_else(|| hf_home.join("token"));
        let token = var("HF_TOKEN")
            .or_else(|| var("HUGGING_FACE_HUB_TOKEN"))
            .or_else(|| std::fs::read_to_string(&token_path).ok())
            .map(|t| t.trim().to_string())
            .filter(|t| !t.is_empty());
        let offline = is_true(var("HF_HUB_OFFLINE").or_else(|| var("TRANSFORMERS_OFFLINE")));
        HubSettings {
            endpoint: var("HF_ENDPOINT")
                .map(|e| e.trim().trim_end_matches('/').to_string())
                .unwrap_or_else(|| DEFAULT_ENDPOINT.to_string()),
            cache_dir,
            token,
            offline,
            progress: !is_true(var("HF_HUB_DISABLE_PROGRESS_BARS")),
            stall_timeout: stall_timeout(lookup("T2TF_HUB_STALL_TIMEOUT")),
            on_event: None,
        }
    }
}

/// The home folder from the environment as Python's `expanduser` reads it on Unix
/// (`windows == false`) or on Windows.
fn home_from(var: &impl Fn(&str) -> Option<String>, windows: bool) -> Option<PathBuf> {
    if !windows {
        return var("HOME").map(PathBuf::from);
    }
    var("USERPROFILE")
        .or_else(|| Some(var("HOMEDRIVE")? + &var("HOMEPATH")?))
        .map(PathBuf::from)
}

/// `huggingface_hub`'s truth values for flags.
fn is_true(value: Option<String>) -> bool {
    value.is_some_and(|v| {
        matches!(
            v.trim().to_ascii_lowercase().as_str(),
            "1" | "true" | "yes" | "on"
        )
    })
}

/// `~` and `~/...` against `home` (as Python's `expanduser`); other paths unchanged.
fn expand_home(value: &str, home: Option<&Path>) -> PathBuf {
    match (value.strip_prefix('~'), home) {
        (Some(""), Some(home)) => home.to_path_buf(),
        (Some(rest), Some(home)) if rest.starts_with('/') || rest.starts_with('\\') => {
            home.join(&rest[1..])
        }
        _ => PathBuf::from(value),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::HashMap;

    fn settings(vars: &[(&str, &str)]) -> HubSettings {
        let map: HashMap<String, String> = vars
            .iter()
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        HubSettings::from_lookup(|k| map.get(k).cloned())
    }

    #[test]
    fn home_is_read_as_python_reads_it_on_each_system() {
        let vars = |pairs: &'static [(&'static str, &'static str)]| {
            move |k: &str| {
                pairs
                    .iter()
                    .find(|(n, _)| *n == k)
                    .map(|(_, v)| v.to_string())
            }
        };
        let all = vars(&[
            ("HOME", "/h"),
            ("USERPROFILE", r"C:\Users\ann"),
            ("HOMEDRIVE", "D:"),
            ("HOMEPATH", r"\ann"),
        ]);
        assert_eq!(home_from(&all, false), Some(PathBuf::from("/h")));
        assert_eq!(home_from(&all, true), Some(PathBuf::from(r"C:\Users\ann")));
        let drive = vars(&[("HOME", "/h"), ("HOMEDRIVE", "D:"), ("HOMEPATH", r"\ann")]);
        assert_eq!(home_from(&drive, true), Some(PathBuf::from(r"D:\ann")));
        assert_eq!(home_from(&vars(&[("HOME", "/h")]), true), None);
    }

    // The variables of a Unix session (Windows reads USERPROFILE, not HOME).
    #[cfg(unix)]
    #[test]
    fn defaults_follow_home_and_xdg() {
        let s = settings(&[("HOME", "/h")]);
        assert_eq!(s.endpoint, DEFAULT_ENDPOINT);
        assert!(!s.offline && s.progress);
        let home = ("HOME", "/h");
        let cases: [(&[(&str, &str)], &str); 5] = [
            (&[home], "/h/.cache/huggingface/hub"),
            (&[home, ("XDG_CACHE_HOME", "/x")], "/x/huggingface/hub"),
            (
                &[home, ("XDG_CACHE_HOME", "/x"), ("HF_HOME", "~/hf")],
                "/h/hf/hub",
            ),
            (
                &[("HF_HOME", "/hf"), ("HUGGINGFACE_HUB_CACHE", "/old")],
                "/old",
            ),
            (
                &[
                    ("HF_HOME", "/hf"),
                    ("HUGGINGFACE_HUB_CACHE", "/old"),
                    ("HF_HUB_CACHE", "/new"),
                ],
                "/new",
            ),
        ];
        for (env, cache) in cases {
            assert_eq!(settings(env).cache_dir, Path::new(cache), "{env:?}");
        }
    }

    #[test]
    fn endpoint_offline_and_progress_flags() {
        let s = settings(&[
            ("HF_ENDPOINT", "http://mirror:8080/"),
            ("HF_HUB_OFFLINE", "YES"),
        ]);
        assert_eq!(s.endpoint, "http://mirror:8080");
        assert!(s.offline);
        for (v, want) in [
            ("1", true),
            ("on", true),
            ("True", true),
            ("0", false),
            ("no", false),
            ("", false),
        ] {
            assert_eq!(settings(&[("HF_HUB_OFFLINE", v)]).offline, want, "{v}");
        }
        assert!(settings(&[("TRANSFORMERS_OFFLINE", "1")]).offline);
        assert!(!settings(&[("HF_HUB_DISABLE_PROGRESS_BARS", "1")]).progress);
    }

    #[test]
    fn token_from_env_then_file() {
        let dir = tempfile::tempdir().unwrap();
        let home = dir.path().to_str().unwrap();
        assert_eq!(settings(&[("HF_HOME", home)]).token, None);
        std::fs::write(dir.path().join("token"), "hf_file\n").unwrap();
        assert_eq!(
            settings(&[("HF_HOME", home)]).token.as_deref(),
            Some("hf_file")
        );
        let other = dir.path().join("other");
        std::fs::write(&other, "  hf_other ").unwrap();
        let s = settings(&[
            ("HF_HOME", home),
            ("HF_TOKEN_PATH", other.to_str().unwrap()),
        ]);
        assert_eq!(s.token.as_deref(), Some("hf_other"));
        let s = settings(&[("HF_HOME", home), ("HUGGING_FACE_HUB_TOKEN", "hf_old")]);
        assert_eq!(s.token.as_deref(), Some("hf_old"));
        let s = settings(&[
            ("HF_HOME", home),
            ("HF_TOKEN", "hf_env"),
            ("HUGGING_FACE_HUB_TOKEN", "x"),
        ]);
        assert_eq!(s.token.as_deref(), Some("hf_env"));
    }

    #[test]
    fn the_stall_timeout_comes_from_the_environment_or_defaults() {
        assert_eq!(stall_timeout(None), DEFAULT_STALL);
        assert_eq!(
            stall_timeout(Some("0.5".into())),
            Duration::from_millis(500)
        );
        for bad in ["", "0", "-1", "nan", "inf", "1e9", "soon"] {
            assert_eq!(stall_timeout(Some(bad.into())), DEFAULT_STALL, "{bad}");
        }
        let settings = HubSettings::from_lookup(|name| {
            (name == "T2TF_HUB_STALL_TIMEOUT").then(|| "2.5".to_string())
        });
        assert_eq!(settings.stall_timeout, Duration::from_millis(2500));
    }
}
