//! The Z (Morton) curve: a cell's key interleaves the bits of its coordinates.
//!
//! Bit `3·q + a` of the key is bit `q` of coordinate `a` (x = 0, y = 1, z = 2), so x varies
//! fastest at every level. Keys of cells in a `2^b`-cube are exactly `0..8^b`, which lets
//! [`super::SfcOrder`] sort the in-range cells of any box by key and skip the rest.

/// Bits per coordinate that fit a 64-bit key.
pub const MAX_BITS: u32 = 21;

/// Spreads the low 21 bits of `v` so that bit `q` lands on bit `3q`.
fn spread(v: u32) -> u64 {
    let mut x = u64::from(v) & 0x1f_ffff;
    x = (x | (x << 32)) & 0x001f_0000_0000_ffff;
    x = (x | (x << 16)) & 0x001f_0000_ff00_00ff;
    x = (x | (x << 8)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x << 2)) & 0x1249_2492_4924_9249;
    x
}

/// Inverse of [`spread`]: gathers bits `3q` into bit `q`.
fn compact(v: u64) -> u32 {
    let mut x = v & 0x1249_2492_4924_9249;
    x = (x | (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x | (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x | (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x | (x >> 16)) & 0x001f_0000_0000_ffff;
    x = (x | (x >> 32)) & 0x1f_ffff;
    x as u32
}

/// The Morton key of cell `c`; `None` when a coordinate needs more than [`MAX_BITS`] bits.
#[must_use]
pub fn encode(c: [u32; 3]) -> Option<u64> {
    if c.iter().any(|&v| v >> MAX_BITS != 0) {
        return None;
    }
    Some(spread(c[0]) | (spread(c[1]) << 1) | (spread(c[2]) << 2))
}

/// The cell of Morton key `key`; bit 63, which no 21-bit cell uses, is ignored.
#[must_use]
pub fn decode(key: u64) -> [u32; 3] {
    [compact(key), compact(key >> 1), compact(key >> 2)]
}
