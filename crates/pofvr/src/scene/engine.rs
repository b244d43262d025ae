//! [`Engine`]: which renderer makes a frame.

/// Which renderer makes a frame. Both give the reference's image.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Engine {
    /// One process, no culling: each pixel's ray walks the whole volume front to back,
    /// jumping over empty space and stopping at its own termination
    /// ([`crate::render::RayCaster::render_march`]).
    March,
    /// The paper's brick path: bricks culled, dealt to ranks, ray-cast one by one and
    /// composited; what ranks, MPI and the cull modes need.
    Bricks,
}

impl Engine {
    /// The name `--stats` and the command line use.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Engine::March => "march",
            Engine::Bricks => "bricks",
        }
    }
}

impl std::str::FromStr for Engine {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().as_str() {
            "march" => Ok(Engine::March),
            "bricks" => Ok(Engine::Bricks),
            _ => Err(format!("unknown engine {s:?}: expected march or bricks")),
        }
    }
}
