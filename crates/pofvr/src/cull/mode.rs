//! The culling modes a frame can ask for.

/// How bricks are culled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CullMode {
    /// No culling: every non-empty brick is rendered.
    None,
    /// Conservative POF culling (Eq. 3 over the per-basis POFs).
    Pof,
    /// Aggressive POF-set culling (§3.2.2): the opacity at each basis's `q_min` pixel,
    /// which the paper calls "very likely" the block's opacity. An estimate, not a bound:
    /// where every basis is thin at some other pixel of the footprint it overestimates, and
    /// a few pixels may then break the threshold rule.
    PofSet,
    /// The sequential oracle: bricks are rendered front to back and tested against the
    /// opacity actually composited. Exists to measure how close POF culling gets.
    Exact,
    /// Predict, verify, repair: a [`super::Predictor`] culls, tile owners verify the
    /// prediction while compositing and the bricks it culled wrongly are rendered and
    /// blended in, so the threshold rule holds whatever the prediction.
    Verified,
}

impl CullMode {
    /// The flag spelling.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            CullMode::None => "none",
            CullMode::Pof => "pof",
            CullMode::PofSet => "pof-set",
            CullMode::Exact => "exact",
            CullMode::Verified => "verified",
        }
    }

    /// True when the mode reads precomputed POFs.
    #[must_use]
    pub fn needs_pofs(self) -> bool {
        matches!(self, CullMode::Pof | CullMode::PofSet)
    }
}

impl std::str::FromStr for CullMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "none" => Ok(CullMode::None),
            "pof" => Ok(CullMode::Pof),
            "pof-set" | "pofset" | "pof_set" => Ok(CullMode::PofSet),
            "exact" => Ok(CullMode::Exact),
            "verified" => Ok(CullMode::Verified),
            other => Err(format!(
                "unknown cull mode {other:?}, expected none, pof, pof-set, exact or verified"
            )),
        }
    }
}
