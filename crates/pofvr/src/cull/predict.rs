//! What predicts the bricks a verified frame culls ([`Predictor`]), and the predictors
//! that need nothing but the frame's bricks.
//!
//! A prediction may be wrong either way: verification ([`super::verify`]) finds the bricks
//! it culled wrongly and the frame repairs them, so the image obeys the threshold rule
//! whatever the predictor. A better one only renders fewer bricks and repairs fewer.

use crate::brick::BrickId;
use crate::render::PixelRect;

use super::FrameBricks;

/// How a verified frame predicts which bricks are hidden.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Predictor {
    /// The low-resolution proxy marched per pixel ([`super::proxy::Proxy`]): needs no
    /// precomputation. The best by measurement ([`Predictor::BEST`]).
    Proxy,
    /// The conservative POF cull (needs POFs).
    Pof,
    /// The POF-set estimate (needs POFs).
    PofSet,
    /// The bricks the previous verified frame of the job needed: for orbits and dragging,
    /// where the view moves a little from frame to frame. The proxy's guess on a first
    /// frame.
    Previous,
    /// Culls nothing (verification then has nothing to test).
    Nothing,
    /// Culls every brick: everything that shows is repaired. A worst case, for tests.
    Everything,
    /// Culls each brick with probability ½, by a hash of the seed and the brick: a
    /// deliberately bad predictor, for tests.
    Random(u64),
}

impl Predictor {
    /// The predictor `--cull verified` uses: the one that renders fewest bricks for fewest
    /// repairs, by measurement (docs/culling.md).
    pub const BEST: Predictor = Predictor::Proxy;

    /// Every predictor's name, as [`std::str::FromStr`] reads them.
    pub const NAMES: &'static str =
        "proxy, pof, pof-set, previous, nothing, everything, random[:SEED]";

    /// The name (a random predictor's without its seed).
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Predictor::Proxy => "proxy",
            Predictor::Pof => "pof",
            Predictor::PofSet => "pof-set",
            Predictor::Previous => "previous",
            Predictor::Nothing => "nothing",
            Predictor::Everything => "everything",
            Predictor::Random(_) => "random",
        }
    }

    /// True when the predictor reads precomputed POFs.
    #[must_use]
    pub fn needs_pofs(self) -> bool {
        matches!(self, Predictor::Pof | Predictor::PofSet)
    }
}

impl Default for Predictor {
    fn default() -> Self {
        Predictor::BEST
    }
}

impl std::str::FromStr for Predictor {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let s = s.to_ascii_lowercase();
        if let Some(seed) = s.strip_prefix("random:") {
            return seed
                .parse()
                .map(Predictor::Random)
                .map_err(|_| format!("bad seed {seed:?} in predictor {s:?}, expected an integer"));
        }
        match s.as_str() {
            "proxy" => Ok(Predictor::Proxy),
            "pof" => Ok(Predictor::Pof),
            "pof-set" | "pofset" | "pof_set" => Ok(Predictor::PofSet),
            "previous" => Ok(Predictor::Previous),
            "nothing" => Ok(Predictor::Nothing),
            "everything" => Ok(Predictor::Everything),
            "random" => Ok(Predictor::Random(0)),
            other => Err(format!(
                "unknown predictor {other:?}, expected {}",
                Predictor::NAMES
            )),
        }
    }
}

/// The bricks over `tile` in visibility order.
#[must_use]
pub fn bricks_over_tile(bricks: &FrameBricks, tile: PixelRect) -> Vec<BrickId> {
    bricks
        .order
        .iter()
        .copied()
        .filter(|id| {
            bricks.footprints[id.index()]
                .and_then(|r| r.intersect(&tile))
                .is_some()
        })
        .collect()
}

/// Splits `over` into (visible, culled) by `culls`, keeping the order.
#[must_use]
pub fn split(over: &[BrickId], culls: impl Fn(BrickId) -> bool) -> (Vec<BrickId>, Vec<BrickId>) {
    over.iter().copied().partition(|b| !culls(*b))
}

/// True when the random predictor of `seed` culls brick `b` (splitmix64's finaliser of
/// the two: the same on every rank).
#[must_use]
pub fn random_culls(seed: u64, b: BrickId) -> bool {
    let mut z = seed ^ u64::from(b.0).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) & 1 == 1
}
