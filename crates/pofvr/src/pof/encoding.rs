//! How one POF (an `N × M` table of per-cell minimum opacities) is stored: the raw f32
//! table, a table quantised to u8 or u16 (always rounded down), or the paper's cubic
//! polynomial (see `cubic.rs`). No encoding ever returns more than the table it came from.

/// A POF storage encoding.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Encoding {
    /// One f32 per view cell.
    Table,
    /// One byte per view cell, `⌊α·255⌋/255`.
    U8,
    /// Two bytes per view cell, `⌊α·65535⌋/65535`.
    U16,
    /// Ten f32 coefficients of a cubic in (θ, φ), shifted down below every cell.
    Cubic,
}

impl Encoding {
    /// Every encoding, for benchmarks and tests.
    pub const ALL: [Encoding; 4] = [
        Encoding::Table,
        Encoding::U8,
        Encoding::U16,
        Encoding::Cubic,
    ];

    /// The name used on the command line and in files.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Encoding::Table => "table",
            Encoding::U8 => "u8",
            Encoding::U16 => "u16",
            Encoding::Cubic => "cubic",
        }
    }

    pub(crate) fn code(self) -> u8 {
        match self {
            Encoding::Table => 0,
            Encoding::U8 => 1,
            Encoding::U16 => 2,
            Encoding::Cubic => 3,
        }
    }

    pub(crate) fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0 => Encoding::Table,
            1 => Encoding::U8,
            2 => Encoding::U16,
            3 => Encoding::Cubic,
            _ => return None,
        })
    }

    /// Bytes of one encoded POF for a view grid.
    #[must_use]
    pub fn function_bytes(self, views: [u32; 2]) -> usize {
        let cells = views[0] as usize * views[1] as usize;
        match self {
            Encoding::Table => 4 * cells,
            Encoding::U8 => cells,
            Encoding::U16 => 2 * cells,
            Encoding::Cubic => 4 * super::cubic::COEFFS,
        }
    }
}

impl std::fmt::Display for Encoding {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Encoding {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "table" | "f32" => Ok(Encoding::Table),
            "u8" => Ok(Encoding::U8),
            "u16" => Ok(Encoding::U16),
            "cubic" | "poly" => Ok(Encoding::Cubic),
            other => Err(format!(
                "unknown encoding {other:?}, expected table, u8, u16 or cubic"
            )),
        }
    }
}

/// Appends the encoding of `table` (row-major `views[0] × views[1]` opacities in [0, 1)).
pub(crate) fn encode(enc: Encoding, table: &[f32], views: [u32; 2], out: &mut Vec<u8>) {
    match enc {
        Encoding::Table => {
            for a in table {
                out.extend_from_slice(&a.to_le_bytes());
            }
        }
        Encoding::U8 => {
            for a in table {
                out.push(quantise(*a, 255.0) as u8);
            }
        }
        Encoding::U16 => {
            for a in table {
                out.extend_from_slice(&(quantise(*a, 65535.0) as u16).to_le_bytes());
            }
        }
        Encoding::Cubic => {
            for c in super::cubic::fit_below(table, views) {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
}

/// `⌊α·q⌋`, and one less if float rounding of the decode would land above `α`.
fn quantise(a: f32, q: f32) -> u32 {
    let mut k = (a.clamp(0.0, 1.0) * q).floor() as u32;
    while k > 0 && k as f32 / q > a {
        k -= 1;
    }
    k
}

/// Appends one record: the encodings of `tables` (each as for [`encode`]), function after
/// function, or, `cell_major` with a table encoding, cell after cell with every function's
/// value of a cell side by side.
pub(crate) fn encode_record(
    enc: Encoding,
    tables: &[Vec<f32>],
    views: [u32; 2],
    cell_major: bool,
    out: &mut Vec<u8>,
) {
    if !cell_major || enc == Encoding::Cubic {
        for t in tables {
            encode(enc, t, views, out);
        }
        return;
    }
    let cells = views[0] as usize * views[1] as usize;
    let mut one = Vec::with_capacity(4);
    for c in 0..cells {
        for t in tables {
            one.clear();
            encode(enc, &t[c..=c], [1, 1], &mut one);
            out.extend_from_slice(&one);
        }
    }
}

/// Where in a record of `funcs` functions the value of function `f` in view cell `cell`
/// lies (the whole function for the cubic, whose value needs all its coefficients).
pub(crate) fn value_range(
    enc: Encoding,
    funcs: usize,
    f: usize,
    views: [u32; 2],
    (i, j): (usize, usize),
    cell_major: bool,
) -> std::ops::Range<usize> {
    let c = i * views[1] as usize + j;
    let size = enc.function_bytes(views);
    let elem = match enc {
        Encoding::Table => 4,
        Encoding::U16 => 2,
        Encoding::U8 => 1,
        Encoding::Cubic => return f * size..(f + 1) * size,
    };
    let at = if cell_major {
        (c * funcs + f) * elem
    } else {
        f * size + c * elem
    };
    at..at + elem
}

/// The stored value of function `f` of a record of `funcs` functions in view cell `cell`.
#[inline]
pub(crate) fn decode_in_record(
    enc: Encoding,
    rec: &[u8],
    funcs: usize,
    f: usize,
    views: [u32; 2],
    cell: (usize, usize),
    cell_major: bool,
) -> f32 {
    let r = value_range(enc, funcs, f, views, cell, cell_major);
    match enc {
        Encoding::Cubic => decode(enc, &rec[r], views, cell),
        // The range holds just this cell's value.
        _ => decode(enc, &rec[r], [1, 1], (0, 0)),
    }
}

/// The stored opacity of view cell `(i, j)`.
pub(crate) fn decode(enc: Encoding, bytes: &[u8], views: [u32; 2], (i, j): (usize, usize)) -> f32 {
    let c = i * views[1] as usize + j;
    match enc {
        Encoding::Table => f32::from_le_bytes([
            bytes[4 * c],
            bytes[4 * c + 1],
            bytes[4 * c + 2],
            bytes[4 * c + 3],
        ]),
        Encoding::U8 => f32::from(bytes[c]) / 255.0,
        Encoding::U16 => f32::from(u16::from_le_bytes([bytes[2 * c], bytes[2 * c + 1]])) / 65535.0,
        Encoding::Cubic => {
            let mut co = [0f32; super::cubic::COEFFS];
            for (k, x) in co.iter_mut().enumerate() {
                *x = f32::from_le_bytes([
                    bytes[4 * k],
                    bytes[4 * k + 1],
                    bytes[4 * k + 2],
                    bytes[4 * k + 3],
                ]);
            }
            super::cubic::eval_cell(&co, views, (i, j))
        }
    }
}
