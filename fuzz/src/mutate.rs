//! Byte mutations of a seed, deterministic for a given generator: the usual ones of a mutation fuzzer (bit flips,
//! interesting integers, insertions, deletions, splices with another seed) and, for text formats (JSON, TOML),
//! token-aware ones that put the numbers and strings parsers and validators trip on where a number or a string was.
//! Positions favour the first and last 4 KiB, where the headers of safetensors and parquet files are.

use rand::Rng;
use rand::rngs::StdRng;

/// Numbers as text: overflow, NaN, negative, zero, the edges of the integer types.
const NUMBERS: &[&str] = &[
    "0",
    "-1",
    "1",
    "-0",
    "2",
    "1e300",
    "-1e300",
    "1e-300",
    "nan",
    "inf",
    "-inf",
    "65536",
    "4294967296",
    "4294967295",
    "2147483648",
    "9223372036854775807",
    "9223372036854775808",
    "18446744073709551615",
    "18446744073709551616",
    "-9223372036854775808",
    "1000000000",
    "1.5",
    "0.5",
    "1e9",
    "1e5",
    "100000",
    "3",
];
/// Strings: paths out of a folder, placeholders, empty, long.
const STRINGS: &[&str] = &[
    "",
    "../../../etc/passwd",
    "/etc/passwd",
    "..",
    ".",
    "a/../../b",
    "{video_key}",
    "{chunk_index:03d}",
    "{",
    "video",
    "float32",
    "float64",
    "int64",
    "string",
    "image",
    "mars",
    "fm",
    "a2a",
    "noise-a2a",
    "vision",
    "state-mlp",
    "spatial-softmax",
    "avg-pool",
    "x",
    "\u{0}",
    "é",
    "v3.0",
    "v2.1",
    "clamp",
    "reject",
    "fci",
    "ros2",
    "sim",
    "fr3",
];
const BYTES: &[u8] = &[0, 1, 0x7f, 0x80, 0xff, b'0', b'9', b'-', b'.', b'e', b'{', b'}', b'[', b']', b'"', b',', b':'];
const INTS: &[u64] = &[
    0,
    1,
    2,
    0x7f,
    0x80,
    0xff,
    0x100,
    0x7fff,
    0x8000,
    0xffff,
    0x1_0000,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x1_0000_0000,
    i64::MAX as u64,
    1 << 63,
    u64::MAX,
    u64::MAX - 1,
];

/// A mutated copy of `seed`: 1 to 8 stacked mutations (`others`: seeds to splice with).
pub fn mutate(rng: &mut StdRng, seed: &[u8], others: &[&[u8]], text: bool) -> Vec<u8> {
    let mut out = seed.to_vec();
    let n = 1 << rng.random_range(0..4);
    for _ in 0..rng.random_range(1..=n) {
        if text && rng.random_bool(0.6) {
            text_op(rng, &mut out);
        } else {
            byte_op(rng, &mut out, others);
        }
    }
    out
}

/// A position in `0..len` (`len` > 0), near the start or the end half of the time.
fn pos(rng: &mut StdRng, len: usize) -> usize {
    match rng.random_range(0..4) {
        0 => rng.random_range(0..len.min(4096)),
        1 => len - 1 - rng.random_range(0..len.min(4096)),
        _ => rng.random_range(0..len),
    }
}

fn byte_op(rng: &mut StdRng, b: &mut Vec<u8>, others: &[&[u8]]) {
    if b.is_empty() {
        b.push(rng.random());
        return;
    }
    let at = pos(rng, b.len());
    match rng.random_range(0..10) {
        0 => b[at] ^= 1 << rng.random_range(0..8),
        1 => b[at] = rng.random(),
        2 => b[at] = BYTES[rng.random_range(0..BYTES.len())],
        3 => {
            let end = (at + rng.random_range(1..=64)).min(b.len());
            b.drain(at..end);
        }
        4 => {
            let fill: Vec<u8> = (0..rng.random_range(1..=16)).map(|_| rng.random()).collect();
            b.splice(at..at, fill);
        }
        5 => {
            let end = (at + rng.random_range(1..=64)).min(b.len());
            let copy = b[at..end].to_vec();
            let to = pos(rng, b.len());
            b.splice(to..to, copy);
        }
        6 => {
            let v = INTS[rng.random_range(0..INTS.len())];
            let width = [1usize, 2, 4, 8][rng.random_range(0..4)];
            let bytes = if rng.random_bool(0.5) { v.to_le_bytes() } else { v.to_be_bytes() };
            let bytes = if rng.random_bool(0.5) { &bytes[..width] } else { &bytes[8 - width..] };
            let end = (at + width).min(b.len());
            b.splice(at..end, bytes.iter().copied());
        }
        7 => b.truncate(at),
        8 if !others.is_empty() => {
            let other = others[rng.random_range(0..others.len())];
            if !other.is_empty() {
                let from = rng.random_range(0..other.len());
                let len = rng.random_range(1..=(other.len() - from).min(256));
                b.splice(at..(at + len).min(b.len()), other[from..from + len].iter().copied());
            }
        }
        _ => {
            let delta = rng.random_range(1..=16u8);
            b[at] = if rng.random_bool(0.5) { b[at].wrapping_add(delta) } else { b[at].wrapping_sub(delta) };
        }
    }
}

/// Token-aware mutations of text: a number, a string or a line replaced, a line doubled or dropped.
fn text_op(rng: &mut StdRng, b: &mut Vec<u8>) {
    if b.is_empty() {
        b.extend_from_slice(NUMBERS[rng.random_range(0..NUMBERS.len())].as_bytes());
        return;
    }
    let at = pos(rng, b.len());
    match rng.random_range(0..4) {
        0 => {
            if let Some((start, end)) = token(b, at, |c| c.is_ascii_digit() || b"+-.eE".contains(&c)) {
                let n = NUMBERS[rng.random_range(0..NUMBERS.len())];
                b.splice(start..end, n.bytes());
            }
        }
        1 => {
            if let Some((start, end)) = quoted(b, at) {
                let s = STRINGS[rng.random_range(0..STRINGS.len())];
                b.splice(start..end, s.bytes());
            }
        }
        2 => {
            let (start, end) = line(b, at);
            let copy = b[start..end].to_vec();
            b.splice(end..end, copy);
        }
        _ => {
            let (start, end) = line(b, at);
            b.drain(start..end);
        }
    }
}

/// The run of bytes around (or after) `at` that `is` accepts.
fn token(b: &[u8], at: usize, is: impl Fn(u8) -> bool) -> Option<(usize, usize)> {
    let start = (at..b.len()).find(|&i| is(b[i]))?;
    let end = (start..b.len()).find(|&i| !is(b[i])).unwrap_or(b.len());
    Some((start, end))
}

/// The inside of the next double-quoted string from `at`.
fn quoted(b: &[u8], at: usize) -> Option<(usize, usize)> {
    let open = (at..b.len()).find(|&i| b[i] == b'"')? + 1;
    let close = (open..b.len()).find(|&i| b[i] == b'"')?;
    Some((open, close))
}

/// The line holding `at`, with its newline.
fn line(b: &[u8], at: usize) -> (usize, usize) {
    let start = b[..at].iter().rposition(|&c| c == b'\n').map_or(0, |i| i + 1);
    let end = b[at..].iter().position(|&c| c == b'\n').map_or(b.len(), |i| at + i + 1);
    (start, end)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn the_same_generator_makes_the_same_mutants_and_they_differ_from_the_seed() {
        let seed = br#"{"fps": 10, "data_path": "data/file.parquet"}"#;
        let run = || {
            let mut rng = StdRng::seed_from_u64(7);
            (0..200).map(|_| mutate(&mut rng, seed, &[], true)).collect::<Vec<_>>()
        };
        let (a, b) = (run(), run());
        assert_eq!(a, b);
        assert!(a.iter().filter(|m| m.as_slice() != seed).count() > 150);
    }
}
