//! The knobs of the POF precompute.

use super::Encoding;

/// How the builder obtains each cell's least optical depth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum PofMethod {
    /// A rigorous lower bound over every ray position, lattice phase and direction of the
    /// measured grid (box minima of per-cell value ranges): fast, but loose.
    #[default]
    Bound,
    /// The optical depth the ray caster's own samples give, measured on a grid of parallel
    /// rays and lattice phases and kept at `margin`: tight, an empirical bound.
    Sampled,
    /// A *typical* value, not a bound: per view cell, the [`TYPICAL_QUANTILE`] of the
    /// optical depths the ray caster's samples give on the core rays that see the basis at
    /// all (the paper's "minimum over non-empty pixels", lifted from the minimum to a low
    /// quantile), measured at the cell's centre direction on a coarse ray grid. A
    /// predictor for `--cull verified`, cheap to build; culling with it unverified breaks
    /// the threshold rule.
    Typical,
}

impl PofMethod {
    /// Every method.
    pub const ALL: [PofMethod; 3] = [PofMethod::Bound, PofMethod::Sampled, PofMethod::Typical];

    /// The name used on the command line and in `pof info`.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            PofMethod::Bound => "bound",
            PofMethod::Sampled => "sampled",
            PofMethod::Typical => "typical",
        }
    }

    pub(crate) fn code(self) -> u8 {
        match self {
            PofMethod::Bound => 0,
            PofMethod::Sampled => 1,
            PofMethod::Typical => 2,
        }
    }

    pub(crate) fn from_code(c: u8) -> Option<Self> {
        Some(match c {
            0 => PofMethod::Bound,
            1 => PofMethod::Sampled,
            2 => PofMethod::Typical,
            _ => return None,
        })
    }
}

impl std::fmt::Display for PofMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for PofMethod {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        PofMethod::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("unknown POF method {s:?}: expected bound, sampled or typical"))
    }
}

/// Knobs of the precompute.
#[derive(Clone, Debug, PartialEq)]
pub struct PofSettings {
    /// How cell values are obtained. Default [`PofMethod::Bound`].
    pub method: PofMethod,
    /// Sample views over (θ, φ): θ ∈ [0, π] in `views[0]` rows, φ ∈ [0, 2π) in `views[1]`
    /// columns. Default `[36, 36]`.
    pub views: [usize; 2],
    /// How each POF is stored. Default [`Encoding::Table`].
    pub encoding: Encoding,
    /// Also store POF sets (the aggressive multi-basis mode). Default false.
    pub sets: bool,
    /// The renderer's sample distance, in units of the smallest spacing. Default 1.
    pub step: f32,
    /// The renderer's early-termination threshold; lookups are capped here. Default 0.99.
    pub ert: f32,
    /// Core length `L` in `t` units; `None` = half a brick. Default `None`.
    ///
    /// Longer cores give higher POFs over fewer pixels: half a brick keeps most of the gain
    /// while the core stays the larger part of the footprint.
    pub core_length: Option<f32>,
    /// `Bound`: edge of the entry-face patches the bound is evaluated on, in voxels (≤ 0.5
    /// keeps a patch inside at most two cells per axis for step ≤ 0.5). Default 0.5.
    /// `Sampled`: spacing of the measured parallel rays, in voxels. Default
    /// [`SAMPLED_PITCH`].
    pub pitch: f32,
    /// `Sampled` only: lattice phases measured per ray, evenly spread over a step (an
    /// evenly spread set is symmetric under reversal, which lets one hemisphere of
    /// directions stand for both). Default [`SAMPLED_PHASES`].
    pub phases: usize,
    /// Directions measured per cell edge: a cell's value is the minimum over a
    /// `(subdiv+1)²` grid of directions including its borders (`Typical`: over the centres
    /// of `subdiv²` sub-cells). Default 2 (`Typical`: 1, the cell's centre).
    pub subdiv: usize,
    /// Fraction of the measured optical depth kept, for directions between the measured
    /// ones (and, for `Sampled`, for ray positions and phases between the measured ones).
    /// Applied to optical depth so that Eq. 3 stays exact for one basis. Default 0.9
    /// (`Bound`) or [`SAMPLED_MARGIN`] (`Sampled`).
    pub margin: f32,
    /// Also store the POF of the whole family at the build's weights `a` (the *joint*
    /// POF), for families of two or more bases. Default true.
    ///
    /// Per-basis POFs are loose when the bases take turns along a ray (grey and white
    /// matter): each basis's minimum is on a ray where the other carries the opacity, and
    /// Eq. 3 combines the two minima. Opacity only grows with every weight, so for any
    /// weights `w` the joint POF scaled to `c = minᵢ wᵢ/aᵢ` is still a lower bound, and a
    /// lookup takes the larger of it and Eq. 3 (exact again for weights along `a`).
    pub joint: bool,
}

/// Most bases a joint POF is stored for (the anchor weights live in the file header).
pub const JOINT_MAX_BASES: usize = 16;

/// Default ray spacing of the sampled method, in voxels.
pub const SAMPLED_PITCH: f32 = 1.0;
/// Default lattice phases of the sampled method.
pub const SAMPLED_PHASES: usize = 2;
/// Default optical-depth margin of the sampled method.
pub const SAMPLED_MARGIN: f32 = 0.7;
/// Default ray spacing of the typical method, in voxels: a quantile needs a sample of the
/// rays, not all of them.
pub const TYPICAL_PITCH: f32 = 3.0;
/// The quantile of the non-empty core rays' optical depths the typical method keeps
/// (0 would be the paper's minimum over non-empty pixels). Not tuned yet: measure
/// others with `pofvr bench cull --sweep 24 --predictor pof` (docs/culling.md).
pub const TYPICAL_QUANTILE: f64 = 0.1;

impl Default for PofSettings {
    fn default() -> Self {
        Self::for_method(PofMethod::default())
    }
}

impl PofSettings {
    /// The defaults of `method`: pitch, phases and margin differ between methods.
    #[must_use]
    pub fn for_method(method: PofMethod) -> Self {
        let (pitch, phases, subdiv, margin) = match method {
            PofMethod::Bound => (0.5, 1, 2, 0.9),
            PofMethod::Sampled => (SAMPLED_PITCH, SAMPLED_PHASES, 2, SAMPLED_MARGIN),
            // One direction per cell (its centre), one phase, the depth as measured.
            PofMethod::Typical => (TYPICAL_PITCH, 1, 1, 1.0),
        };
        PofSettings {
            method,
            views: [36, 36],
            encoding: Encoding::Table,
            sets: false,
            step: 1.0,
            ert: 0.99,
            core_length: None,
            pitch,
            phases,
            subdiv,
            margin,
            joint: true,
        }
    }
}
