//! Memory sizes as the command line writes them: `256M`, `4G`, `1.5G`, `65536`.

/// Parses a size in bytes: a number with an optional binary suffix `K`, `M`, `G` or `T`
/// (powers of 1024; `KB`, `MiB` and lowercase are accepted too).
///
/// # Errors
/// A message naming the text when it is not a positive size.
pub fn parse_size(text: &str) -> Result<u64, String> {
    let bad = |why: &str| format!("bad size {text:?}: {why} (expected e.g. 256M, 4G or 65536)");
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    if num.is_empty() {
        return Err(bad("no number"));
    }
    let shift = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 0,
        "k" | "kb" | "kib" => 10,
        "m" | "mb" | "mib" => 20,
        "g" | "gb" | "gib" => 30,
        "t" | "tb" | "tib" => 40,
        _ => return Err(bad("unknown unit")),
    };
    let value: f64 = num.parse().map_err(|_| bad("not a number"))?;
    let bytes = value * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(bad("out of range"));
    }
    Ok(bytes as u64)
}

#[cfg(test)]
mod test {
    use super::parse_size;

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_size("65536"), Ok(65536));
        assert_eq!(parse_size("256M"), Ok(256 << 20));
        assert_eq!(parse_size("4G"), Ok(4 << 30));
        assert_eq!(parse_size("4g"), Ok(4 << 30));
        assert_eq!(parse_size("512KiB"), Ok(512 << 10));
        assert_eq!(parse_size("1.5G"), Ok(3 << 29));
        assert_eq!(parse_size("2T"), Ok(2 << 40));
    }

    #[test]
    fn bad_sizes_are_errors_naming_the_text() {
        for bad in ["", "M", "12X", "-4G", "0", "1..2M", "G4"] {
            let e = parse_size(bad).expect_err(bad);
            assert!(e.contains(&format!("{bad:?}")), "{e}");
        }
    }
}
