//! The memory budget: every size read from a file or a flag is checked here before it is
//! allocated, so a hostile header or a large flag ends in an error that says what was asked,
//! what is available and what to do, never in an allocation abort (exit 134).
//!
//! A [`Budget`] is a value: a fixed number of bytes (the CLI's `--max-memory`), or what the
//! system can give this process — the smaller of the available physical memory
//! ([`platform::available_memory`]) and the room left under the address-space limit
//! (`ulimit -v`, on Unix). Whoever reads sizes from a file or a caller
//! takes one and checks against it.

use crate::platform;
use crate::units::human_bytes as human;

/// What the budget refused.
#[derive(Debug, thiserror::Error)]
#[error(
    "{what} needs {} but only {} is available for it; {hint}",
    human(*.asked as u128), human(*.available as u128)
)]
pub struct MemoryError {
    /// What needed the memory.
    pub what: String,
    /// Bytes asked for.
    pub asked: u64,
    /// Bytes available.
    pub available: u64,
    /// What the user can do about it (an option named by its field, in backticks).
    pub hint: String,
    /// The option `hint` names, if any (`level`), for a front end's advice; the budget itself
    /// goes without saying.
    pub option: Option<&'static str>,
}

impl MemoryError {
    /// The same error, its `hint` naming `option`.
    pub fn about(self, option: &'static str) -> MemoryError {
        MemoryError {
            option: Some(option),
            ..self
        }
    }

    /// What a front end needs to word its advice: a larger budget (and `option`).
    pub fn hint(&self) -> crate::error::Hint {
        crate::error::Hint {
            kind: crate::error::ErrorKind::Memory {
                needed: self.asked,
                available: self.available,
            },
            option: self.option,
        }
    }
}

/// How many bytes a reader or renderer may allocate: a value handed to whatever allocates by
/// sizes it read from a file or was given, never a process-wide setting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Budget {
    /// A fixed number of bytes; `None`: what the system can give this process at each check.
    limit: Option<u64>,
}

impl Budget {
    /// What the system can give this process when asked: the smaller of the available
    /// physical memory and the room left under the address-space limit (`ulimit -v`, Unix).
    pub fn system() -> Budget {
        Budget { limit: None }
    }

    /// At most `bytes`.
    pub fn bytes(bytes: u64) -> Budget {
        Budget { limit: Some(bytes) }
    }

    /// `bytes` when given, else [`Budget::system`].
    pub fn new(bytes: Option<u64>) -> Budget {
        Budget { limit: bytes }
    }

    /// The fixed limit, if one was given.
    pub fn limit(&self) -> Option<u64> {
        self.limit
    }

    /// Bytes that may be allocated now.
    pub fn available(&self) -> u64 {
        self.limit.unwrap_or_else(system_available)
    }

    /// Check that `count` items of `item_bytes` each fit; `None` counts (an overflowed
    /// product) never do. `hint` says how to ask for less.
    pub fn check(
        &self,
        what: impl Into<String>,
        count: Option<u64>,
        item_bytes: u64,
        hint: &str,
    ) -> Result<(), MemoryError> {
        let asked = count.and_then(|c| c.checked_mul(item_bytes));
        let available = self.available();
        match asked {
            Some(a) if a <= available => Ok(()),
            _ => Err(MemoryError {
                what: what.into(),
                asked: asked.unwrap_or(u64::MAX),
                available,
                hint: hint.to_string(),
                option: None,
            }),
        }
    }
}

/// A size that does not parse ([`parse_size`]).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct SizeError(pub String);

/// The product of `dims`, `None` on overflow.
pub fn product(dims: &[usize]) -> Option<u64> {
    dims.iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(u64::try_from(d).ok()?))
}

/// Parse `--max-memory`: bytes, or a number with K, M, G or T (powers of 1024; a trailing B
/// or iB is accepted).
pub fn parse_size(s: &str) -> Result<u64, SizeError> {
    let t = s.trim();
    let t = t
        .strip_suffix("iB")
        .or_else(|| t.strip_suffix('B'))
        .unwrap_or(t);
    let (num, shift) = match t.chars().last().map(|c| c.to_ascii_uppercase()) {
        Some('K') => (&t[..t.len() - 1], 10),
        Some('M') => (&t[..t.len() - 1], 20),
        Some('G') => (&t[..t.len() - 1], 30),
        Some('T') => (&t[..t.len() - 1], 40),
        _ => (t, 0),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| SizeError(format!("\"{s}\" is not a size like 512M or 16G")))?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(SizeError(format!(
            "\"{s}\" is not a positive size like 512M or 16G"
        )));
    }
    Ok(bytes as u64)
}

/// The memory the system can give, capped by the room under the address-space limit;
/// `u64::MAX` where neither is known.
fn system_available() -> u64 {
    let mem = platform::available_memory().unwrap_or(u64::MAX);
    mem.min(platform::address_space_left().unwrap_or(u64::MAX))
}

/// Worker threads for `requested`: at most the logical CPUs (more only adds switching and
/// start-up time). Returns the count and whether it was capped (the caller says so).
pub fn thread_count(requested: usize) -> (usize, bool) {
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    if requested > cpus {
        (cpus, true)
    } else {
        (requested, false)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse() {
        assert_eq!(parse_size("512M"), Ok(512 << 20));
        assert_eq!(parse_size("16G"), Ok(16 << 30));
        assert_eq!(parse_size("1.5GiB"), Ok(3 << 29));
        assert_eq!(parse_size("4096"), Ok(4096));
        assert!(parse_size("-1G").is_err());
        assert!(parse_size("lots").is_err());
    }

    #[test]
    fn overflowing_requests_are_refused_with_the_numbers() {
        let b = Budget::system();
        let e = b
            .check("x", product(&[usize::MAX, 2]), 4, "ask for less")
            .unwrap_err();
        let m = e.to_string();
        assert!(m.contains("ask for less") && !m.contains("--"), "{m}");
        assert!(b.check("y", Some(1), 1, "").is_ok());
        let small = Budget::bytes(100);
        assert_eq!(small.available(), 100);
        assert!(small.check("z", Some(101), 1, "").is_err());
        assert!(small.check("z", Some(25), 4, "").is_ok());
    }

    #[test]
    fn humans_read_sizes() {
        assert_eq!(human(512), "512 B");
        assert_eq!(human(3 << 29), "1.5 GiB");
    }
}
