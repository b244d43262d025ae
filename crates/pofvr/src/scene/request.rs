//! [`FrameRequest`]: everything one frame of a [`crate::Scene`] is rendered with, and
//! [`Cull`], the cull mode with the bounds it reads.

use crate::cull::CullMode;
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
        }
    }

    /// The POFs the mode reads, if any.
    #[must_use]
    pub fn pofs(self) -> Option<&'a Pofs> {
        match self {
            Cull::None | Cull::Exact => None,
            Cull::Pof(p) | Cull::PofSet(p) => Some(p),
        }
    }

    /// `mode` with `pofs`; `None` when `mode` reads POFs and there are none.
    #[must_use]
    pub fn from_mode(mode: CullMode, pofs: Option<&'a Pofs>) -> Option<Self> {
        match mode {
            CullMode::None => Some(Cull::None),
            CullMode::Exact => Some(Cull::Exact),
            CullMode::Pof => pofs.map(Cull::Pof),
            CullMode::PofSet => pofs.map(Cull::PofSet),
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

    /// With this many owners per brick.
    #[must_use]
    pub fn replicas(mut self, replicas: usize) -> Self {
        self.replicas = replicas;
        self
    }
}
