//! Quantities written for people: byte sizes in binary units, numbers in messages.

/// Bytes as `512 B`, `1.5 KiB`, `577.0 MiB`, … `EiB` (one decimal; an exponent past 10⁴ EiB,
/// which only absurd sizes from a broken header reach).
pub fn human_bytes(bytes: u128) -> String {
    const UNITS: [&str; 7] = ["B", "KiB", "MiB", "GiB", "TiB", "PiB", "EiB"];
    let mut x = bytes as f64;
    let mut u = 0;
    while x >= 1024.0 && u + 1 < UNITS.len() {
        x /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{bytes} B")
    } else if x < 10_000.0 {
        format!("{x:.1} {}", UNITS[u])
    } else {
        format!("{x:.2e} {}", UNITS[u])
    }
}

/// A number for a message, exactly as it round-trips, and short: `0.25`, `45607`, `5e-324`
/// (Rust's `{}` writes 5e-324 with 323 zeros, and 1e300 with 300 digits).
pub fn number(v: f64) -> String {
    let plain = format!("{v}");
    if plain.len() <= 20 {
        plain
    } else {
        format!("{v:e}")
    }
}

#[cfg(test)]
mod tests {
    use super::{human_bytes, number};

    #[test]
    fn numbers_are_short_and_exact() {
        for (v, text) in [
            (0.0, "0"),
            (45607.0, "45607"),
            (0.25, "0.25"),
            (5e-324, "5e-324"),
            (1e300, "1e300"),
            (-1.5e-20, "-1.5e-20"),
        ] {
            assert_eq!(number(v), text);
            assert_eq!(number(v).parse::<f64>().unwrap(), v);
        }
    }

    #[test]
    fn sizes_read_well() {
        assert_eq!(human_bytes(512), "512 B");
        assert_eq!(human_bytes(2048), "2.0 KiB");
        assert_eq!(human_bytes(605_000_000), "577.0 MiB");
        assert_eq!(human_bytes(16 << 30), "16.0 GiB");
        assert_eq!(human_bytes(u128::MAX), "2.95e20 EiB");
    }
}
