//! Seeded mutation of seed inputs: byte-level edits for the binary formats and token- and
//! line-level edits for the text headers, where a plain bit flip rarely reaches a number.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// Numbers that break parsers: zero, negatives, limits of every integer width, values
/// that overflow a product of three dims, non-finite and denormal floats.
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1",
    "2",
    "3",
    "-0",
    "255",
    "256",
    "65535",
    "65536",
    "2147483647",
    "2147483648",
    "4294967295",
    "4294967296",
    "9223372036854775807",
    "18446744073709551615",
    "18446744073709551616",
    "1000000",
    "99999999999",
    "1e400",
    "-1e400",
    "1e-45",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "1e38",
    "0.0",
    "1.5",
    "",
    "1 1",
    "4 4 4 4",
];

/// Whole header values worth splicing in.
const TOKENS: &[&str] = &[
    "gzip",
    "gz",
    "raw",
    "ascii",
    "text",
    "bzip2",
    "LIST",
    "LOCAL",
    "big",
    "little",
    "uchar",
    "short",
    "ushort",
    "int",
    "float",
    "double",
    "MET_FLOAT",
    "MET_UCHAR",
    "MET_SHORT",
    "MET_DOUBLE",
    "True",
    "False",
    "d.raw",
    "d.raw.gz",
    "missing.raw",
    "../d.raw",
    "/proc/self/mem",
    "%d.raw 0 2 1",
    "(1,0,0) (0,1,0) (0,0,1)",
    "(nan,0,0) (0,0,0) (0,0,0)",
    "none",
    "\n\n",
    "=",
    ":",
    ":=",
    "#",
    "&",
    "&&",
    "%",
    "%zz",
    "+",
    ",",
    ",,",
];

const BYTES: &[u8] = b"\0\n\r \t:=#,.-+e0123456789()&%\xff\x7f\x80";

/// 32-bit patterns for binary headers (NIfTI, .pof): sign bits, limits, NaN and infinity.
const WORDS: &[u32] = &[
    0,
    1,
    0xffff_ffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff,
    0x1_0000,
    348,
    352,
    0x7fc0_0000,
    0x7f80_0000,
    0xff80_0000,
    0x0000_0001,
    0x3f80_0000,
    0xbf80_0000,
    0x4f00_0000,
];

/// Input `n` of a run seeded `seed`: the same pair always gives the same bytes, so a
/// finding is replayed with `--only N`.
#[must_use]
pub fn input(seeds: &[Vec<u8>], seed: u64, n: u64, max_len: usize) -> Vec<u8> {
    let mut rng = StdRng::seed_from_u64(seed ^ n.wrapping_mul(0x9e37_79b9_7f4a_7c15));
    let mut data = seeds[rng.gen_range(0..seeds.len())].clone();
    let edits = 1 + rng.gen_range(0..4) + usize::from(rng.gen_bool(0.1)) * 8;
    for _ in 0..edits {
        edit(&mut rng, &mut data, seeds);
    }
    data.truncate(max_len);
    data
}

fn edit(rng: &mut StdRng, d: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    let len = d.len();
    let at = |rng: &mut StdRng| if len == 0 { 0 } else { rng.gen_range(0..len) };
    match rng.gen_range(0..13) {
        0 if len > 0 => {
            let i = at(rng);
            d[i] ^= 1 << rng.gen_range(0..8);
        }
        1 if len > 0 => {
            let i = at(rng);
            d[i] = BYTES[rng.gen_range(0..BYTES.len())];
        }
        2 => {
            let i = at(rng);
            let n = rng.gen_range(1..16);
            let bytes: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
            d.splice(i..i, bytes);
        }
        3 if len > 0 => {
            let i = at(rng);
            let n = rng.gen_range(1..=(len - i).min(64));
            d.drain(i..i + n);
        }
        4 if len > 0 => {
            let i = at(rng);
            let n = rng.gen_range(1..=(len - i).min(64));
            let chunk = d[i..i + n].to_vec();
            let j = at(rng);
            d.splice(j..j, chunk);
        }
        5 if len > 0 => {
            let cut = at(rng);
            d.truncate(cut);
        }
        6 => {
            let other = &seeds[rng.gen_range(0..seeds.len())];
            if !other.is_empty() {
                let i = rng.gen_range(0..other.len());
                let n = rng.gen_range(1..=(other.len() - i).min(128));
                let j = at(rng);
                d.splice(j..j, other[i..i + n].iter().copied());
            }
        }
        7 | 8 => replace_number(rng, d),
        9 => {
            let t = TOKENS[rng.gen_range(0..TOKENS.len())].as_bytes();
            replace_value(rng, d, t);
        }
        10 => line_edit(rng, d),
        11 if len >= 4 => {
            let i = rng.gen_range(0..=len - 4);
            let w = WORDS[rng.gen_range(0..WORDS.len())];
            d[i..i + 4].copy_from_slice(&w.to_le_bytes());
        }
        12 if len >= 2 => {
            let i = rng.gen_range(0..=len - 2);
            let w: i16 =
                [0, -1, 1, 7, 8, 3, i16::MAX, i16::MIN, 4, 16, 32, 64, 1024][rng.gen_range(0..13)];
            d[i..i + 2].copy_from_slice(&w.to_le_bytes());
        }
        _ => {}
    }
}

/// Replaces a run of digits (with its sign, point and exponent) by one of [`NUMBERS`].
fn replace_number(rng: &mut StdRng, d: &mut Vec<u8>) {
    let starts: Vec<usize> = (0..d.len())
        .filter(|&i| d[i].is_ascii_digit() && (i == 0 || !d[i - 1].is_ascii_digit()))
        .collect();
    if starts.is_empty() {
        return;
    }
    let s = starts[rng.gen_range(0..starts.len())];
    let mut e = s;
    while e < d.len() && (d[e].is_ascii_digit() || b".eE+-".contains(&d[e])) {
        e += 1;
    }
    let n = NUMBERS[rng.gen_range(0..NUMBERS.len())].as_bytes();
    d.splice(s..e, n.iter().copied());
}

/// Replaces what follows a `:` or `=` on some line by `value`.
fn replace_value(rng: &mut StdRng, d: &mut Vec<u8>, value: &[u8]) {
    let seps: Vec<usize> = (0..d.len())
        .filter(|&i| d[i] == b':' || d[i] == b'=')
        .collect();
    if seps.is_empty() {
        let i = if d.is_empty() {
            0
        } else {
            rng.gen_range(0..d.len())
        };
        d.splice(i..i, value.iter().copied());
        return;
    }
    let s = seps[rng.gen_range(0..seps.len())] + 1;
    let e = d[s..]
        .iter()
        .position(|&b| b == b'\n' || b == b'&')
        .map_or(d.len(), |p| s + p);
    let mut v = b" ".to_vec();
    v.extend_from_slice(value);
    d.splice(s..e, v);
}

/// Duplicates, deletes or swaps whole lines (a repeated or missing header field).
fn line_edit(rng: &mut StdRng, d: &mut Vec<u8>) {
    let mut lines: Vec<Vec<u8>> = d.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
    if lines.len() < 2 {
        return;
    }
    // Text headers end where the data starts: keep edits in the first lines.
    let n = lines.len().min(24);
    let (i, j) = (rng.gen_range(0..n), rng.gen_range(0..n));
    match rng.gen_range(0..3) {
        0 => {
            let l = lines[i].clone();
            lines.insert(j, l);
        }
        1 => {
            lines.remove(i);
        }
        _ => lines.swap(i, j),
    }
    *d = lines.join(&b'\n');
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_and_index_give_the_same_input() {
        let seeds = vec![b"sizes: 4 4 4\ntype: uchar\n".to_vec(), vec![1, 2, 3, 4, 5]];
        for n in 0..200 {
            assert_eq!(input(&seeds, 7, n, 1 << 16), input(&seeds, 7, n, 1 << 16));
        }
        let distinct: std::collections::HashSet<Vec<u8>> =
            (0..200).map(|n| input(&seeds, 7, n, 1 << 16)).collect();
        assert!(distinct.len() > 150, "{}", distinct.len());
    }
}
