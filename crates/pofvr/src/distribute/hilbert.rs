//! The 3D Hilbert curve over a `2^bits`-cube, by Skilling's transpose algorithm
//! (J. Skilling, "Programming the Hilbert curve", AIP Conf. Proc. 707, 2004).
//!
//! The "transpose" form spreads a Hilbert index over three words: bit `q` of words
//! `0, 1, 2` are index bits `3q + 2, 3q + 1, 3q`. Skilling's two loops convert between that
//! form and plain coordinates in `O(bits)` without tables, and consecutive indices are always
//! face-adjacent cells.

/// Bits per coordinate that fit a 64-bit index.
pub const MAX_BITS: u32 = 21;

/// The Hilbert index of cell `c` in the `2^bits`-cube; `None` when `bits > MAX_BITS` or a
/// coordinate lies outside the cube.
#[must_use]
pub fn index(c: [u32; 3], bits: u32) -> Option<u64> {
    if bits > MAX_BITS || c.iter().any(|&v| u64::from(v) >> bits != 0) {
        return None;
    }
    if bits == 0 {
        return Some(0);
    }
    let mut x = c;
    axes_to_transpose(&mut x, bits);
    Some(from_transpose(x, bits))
}

/// The cell of Hilbert index `h` in the `2^bits`-cube; `None` when `bits > MAX_BITS` or
/// `h >= 8^bits`.
#[must_use]
pub fn coords(h: u64, bits: u32) -> Option<[u32; 3]> {
    if bits > MAX_BITS || h >> (3 * bits) != 0 {
        return None;
    }
    if bits == 0 {
        return Some([0; 3]);
    }
    let mut x = to_transpose(h, bits);
    transpose_to_axes(&mut x, bits);
    Some(x)
}

fn from_transpose(x: [u32; 3], bits: u32) -> u64 {
    let mut h = 0u64;
    for q in (0..bits).rev() {
        for w in x {
            h = (h << 1) | u64::from((w >> q) & 1);
        }
    }
    h
}

fn to_transpose(h: u64, bits: u32) -> [u32; 3] {
    let mut x = [0u32; 3];
    for q in 0..bits {
        for (i, w) in x.iter_mut().enumerate() {
            // Word 0 holds the most significant of each level's three bits.
            let bit = (h >> (3 * q + 2 - i as u32)) & 1;
            *w |= u32::from(bit == 1) << q;
        }
    }
    x
}

fn axes_to_transpose(x: &mut [u32; 3], bits: u32) {
    let m = 1u32 << (bits - 1);
    // Inverse undo excess work.
    let mut q = m;
    while q > 1 {
        let p = q - 1;
        for i in 0..3 {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1;
    }
    // Gray encode.
    x[1] ^= x[0];
    x[2] ^= x[1];
    let mut t = 0;
    let mut q = m;
    while q > 1 {
        if x[2] & q != 0 {
            t ^= q - 1;
        }
        q >>= 1;
    }
    for w in x.iter_mut() {
        *w ^= t;
    }
}

fn transpose_to_axes(x: &mut [u32; 3], bits: u32) {
    // Gray decode by h ^ (h / 2).
    let t = x[2] >> 1;
    x[2] ^= x[1];
    x[1] ^= x[0];
    x[0] ^= t;
    // Undo excess work.
    let mut q = 2u32;
    while q < 1 << bits {
        let p = q - 1;
        for i in (0..3).rev() {
            if x[i] & q != 0 {
                x[0] ^= p;
            } else {
                let t = (x[0] ^ x[i]) & p;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q <<= 1;
    }
}
