//! [`FrameRequest`]: everything one frame of a [`crate::Scene`] is rendered with, and
//! [`Cull`], the cull mode with the bounds it reads.

use crate::cull::{CullMode, Predictor};
use crate::distribute::Curve;
use crate::render::Camera;

use super::{Engine, Pofs};

/// How a frame culls bricks. The POF modes carry the POFs they read, taken from the scene
/// ([`crate::Scene::pofs`]), so a POF mode without POFs cannot be asked for.
#[derive(Clone, Copy, Debug, Default)]
pub enum Cull<'a> {
    /// No culling: every non-empty brick is rendered.
    #[default]
    None,
    /// The sequential oracle: bricks rendered front to back, each tested against the
    /// opacity actually composited; needs no POFs, and shows how close POF culling gets.
    Exact,
    /// Conservative POF culling: a brick is culled only where its POFs prove it hidden.
    Pof(&'a Pofs),
    /// Aggressive POF-set culling: culls more, but an estimate, not a bound (a few pixels
    /// may break the threshold rule). Reads POF sets where the POFs hold them.
    PofSet(&'a Pofs),
    /// Predict, verify, repair: `Predict` guesses the cull, tile owners verify it while
    /// compositing and what it culled wrongly is rendered and blended in, so the threshold
    /// rule holds whatever the guess.
    Verified(Predict<'a>),
}

/// What predicts a [`Cull::Verified`] frame's cull; the POF predictors carry the POFs
/// they read ([`Predictor`] names them).
#[derive(Clone, Copy, Debug, Default)]
pub enum Predict<'a> {
    /// The low-resolution proxy ([`Predictor::Proxy`], the best: [`Predictor::BEST`]).
    #[default]
    Proxy,
    /// The conservative POF cull.
    Pof(&'a Pofs),
    /// The POF-set estimate.
    PofSet(&'a Pofs),
    /// The bricks the scene's previous verified frame needed ([`Predictor::Previous`]).
    Previous,
    /// Culls nothing.
    Nothing,
    /// Culls everything (a worst case: everything that shows is repaired).
    Everything,
    /// Culls each brick with probability ½, by a hash of the seed and the brick.
    Random(u64),
}

impl<'a> Predict<'a> {
    /// The predictor, as the frame statistics name it.
    #[must_use]
    pub fn predictor(self) -> Predictor {
        match self {
            Predict::Proxy => Predictor::Proxy,
            Predict::Pof(_) => Predictor::Pof,
            Predict::PofSet(_) => Predictor::PofSet,
            Predict::Previous => Predictor::Previous,
            Predict::Nothing => Predictor::Nothing,
            Predict::Everything => Predictor::Everything,
            Predict::Random(seed) => Predictor::Random(seed),
        }
    }

    /// The POFs it reads, if any.
    #[must_use]
    pub fn pofs(self) -> Option<&'a Pofs> {
        match self {
            Predict::Pof(p) | Predict::PofSet(p) => Some(p),
            _ => None,
        }
    }

    /// `predictor` with `pofs`; `None` when it reads POFs and there are none.
    #[must_use]
    pub fn from_predictor(predictor: Predictor, pofs: Option<&'a Pofs>) -> Option<Self> {
        Some(match predictor {
            Predictor::Proxy => Predict::Proxy,
            Predictor::Pof => Predict::Pof(pofs?),
            Predictor::PofSet => Predict::PofSet(pofs?),
            Predictor::Previous => Predict::Previous,
            Predictor::Nothing => Predict::Nothing,
            Predictor::Everything => Predict::Everything,
            Predictor::Random(seed) => Predict::Random(seed),
        })
    }
}

impl<'a> Cull<'a> {
    /// The mode, as the frame statistics name it.
    #[must_use]
    pub fn mode(self) -> CullMode {
        match self {
            Cull::None => CullMode::None,
            Cull::Exact => CullMode::Exact,
            Cull::Pof(_) => CullMode::Pof,
            Cull::PofSet(_) => CullMode::PofSet,
            Cull::Verified(_) => CullMode::Verified,
        }
    }

    /// The POFs the mode reads, if any.
    #[must_use]
    pub fn pofs(self) -> Option<&'a Pofs> {
        match self {
            Cull::None | Cull::Exact => None,
            Cull::Pof(p) | Cull::PofSet(p) => Some(p),
            Cull::Verified(p) => p.pofs(),
        }
    }

    /// The predictor of a [`Cull::Verified`] frame ([`Predictor::BEST`] for the others,
    /// which predict with their own cull).
    #[must_use]
    pub fn predictor(self) -> Predictor {
        match self {
            Cull::Verified(p) => p.predictor(),
            _ => Predictor::BEST,
        }
    }

    /// `mode` with `pofs` (verified: with the best predictor, [`Predictor::BEST`]); `None`
    /// when `mode` reads POFs and there are none.
    #[must_use]
    pub fn from_mode(mode: CullMode, pofs: Option<&'a Pofs>) -> Option<Self> {
        match mode {
            CullMode::None => Some(Cull::None),
            CullMode::Exact => Some(Cull::Exact),
            CullMode::Pof => pofs.map(Cull::Pof),
            CullMode::PofSet => pofs.map(Cull::PofSet),
            CullMode::Verified => {
                Predict::from_predictor(Predictor::BEST, pofs).map(Cull::Verified)
            }
        }
    }
}

/// One frame: the camera, the look (weights and shading) and how to cull and distribute.
///
/// ```
/// # use pofvr::{Camera, Cull, FrameRequest, Projection};
/// # let volume = pofvr::volume::phantom::Phantom::SheppLogan.generate(8);
/// let camera = Camera::orbit(&volume, 30.0, 20.0, 64, 64, Projection::Orthographic);
/// let request = FrameRequest::new(&camera).weights(&[1.0, 0.5]).shade(true).cull(Cull::Exact);
/// assert_eq!(request.threshold, 0.95);
/// ```
#[derive(Clone, Debug)]
pub struct FrameRequest<'a> {
    /// The camera.
    pub camera: &'a Camera,
    /// One weight per basis; `None`: the family's own ([`crate::Scene::default_weights`]).
    pub weights: Option<&'a [f32]>,
    /// Gradient (Lambertian, headlight) shading. Default off.
    pub shade: bool,
    /// How bricks are culled. Default [`Cull::None`].
    pub cull: Cull<'a>,
    /// Opacity at or above which a pixel hides what lies behind it, in (0, 1]. Default 0.95.
    pub threshold: f32,
    /// Ranks the frame is rendered with (threads of this process, or the size of the
    /// communicator for [`crate::Scene::render_on`]); the image is the same for any count.
    /// Default 1.
    pub ranks: usize,
    /// The curve bricks are dealt to ranks along. Default [`Curve::Hilbert`].
    pub curve: Curve,
    /// Owners per brick: 1 renders each brick on the rank it was dealt to; 2 on the less
    /// loaded of two ([`crate::distribute::BrickAssignment`]). Default 1.
    pub replicas: usize,
    /// The renderer. Default `None`: [`Engine::March`] for one rank with no culling on a
    /// scene that holds the whole volume, [`Engine::Bricks`] otherwise.
    pub engine: Option<Engine>,
    /// Whether tile owners verify the cull while compositing and the frame repairs what it
    /// culled wrongly: so the threshold rule holds for [`Cull::PofSet`] too. Always on for
    /// [`Cull::Verified`]. Default off.
    pub verify: bool,
}

impl<'a> FrameRequest<'a> {
    /// A frame seen by `camera` with the defaults: the family's weights, no shading, no
    /// culling, threshold 0.95, one rank.
    #[must_use]
    pub fn new(camera: &'a Camera) -> Self {
        FrameRequest {
            camera,
            weights: None,
            shade: false,
            cull: Cull::None,
            threshold: 0.95,
            ranks: 1,
            curve: Curve::Hilbert,
            replicas: 1,
            engine: None,
            verify: false,
        }
    }

    /// With these basis weights.
    #[must_use]
    pub fn weights(mut self, weights: &'a [f32]) -> Self {
        self.weights = Some(weights);
        self
    }

    /// With or without shading.
    #[must_use]
    pub fn shade(mut self, shade: bool) -> Self {
        self.shade = shade;
        self
    }

    /// Culled this way.
    #[must_use]
    pub fn cull(mut self, cull: Cull<'a>) -> Self {
        self.cull = cull;
        self
    }

    /// With this cull threshold.
    #[must_use]
    pub fn threshold(mut self, threshold: f32) -> Self {
        self.threshold = threshold;
        self
    }

    /// Rendered by this many ranks.
    #[must_use]
    pub fn ranks(mut self, ranks: usize) -> Self {
        self.ranks = ranks;
        self
    }

    /// With bricks dealt along this curve.
    #[must_use]
    pub fn curve(mut self, curve: Curve) -> Self {
        self.curve = curve;
        self
    }

    /// Rendered by this engine ([`crate::Scene::render`] refuses [`Engine::March`] with
    /// culling or more than one rank).
    #[must_use]
    pub fn engine(mut self, engine: Engine) -> Self {
        self.engine = Some(engine);
        self
    }

    /// Verified and repaired ([`FrameRequest::verify`]).
    #[must_use]
    pub fn verify(mut self, verify: bool) -> Self {
        self.verify = verify;
        self
    }

    /// With this many owners per brick.
    #[must_use]
    pub fn replicas(mut self, replicas: usize) -> Self {
        self.replicas = replicas;
        self
    }
}
