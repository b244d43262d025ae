//! Built-in volumes for the demo and the tests, at any size.

use super::{Volume, VoxelData, Voxels};

/// Which built-in volume to generate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phantom {
    /// A 3D Shepp–Logan head (Kak–Slaney ellipsoids, Toft's high-contrast intensities),
    /// stored as u8: air 0, scalp/skull shell 250, brain ≈ 50, ventricles ≈ 0, small
    /// features 75–100.
    SheppLogan,
    /// The Shepp–Logan geometry with every ellipsoid's edge blended over six voxels
    /// (a smoothstep of the distance to its surface), stored as f32 on the same intensity
    /// scale (no integer terraces in the blends): surfaces with gradients a shaded render can light, and no single-voxel
    /// steps for a one-voxel sample distance to alias into rings.
    SmoothHead,
    /// The Marschner–Lobb test signal (f_M = 6, α = 0.25), stored as f32 in [0, 1].
    MarschnerLobb,
    /// A CT-like torso in Hounsfield units, stored as i16 (see [`Phantom::generate_dims`]):
    /// air −1000, skin, fat ≈ −100 and muscle ≈ 50, lungs ≈ −860 with branching vessels,
    /// heart, liver, spleen and kidneys, the column, ribs and the other bones (cortical
    /// ≈ 1100, cancellous ≈ 260), with seeded noise. Any grid, not only cubes.
    Body,
}

impl std::str::FromStr for Phantom {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_lowercase().replace(['-', '_'], "").as_str() {
            "shepplogan" | "head" => Ok(Phantom::SheppLogan),
            "smoothhead" | "smoothshepplogan" => Ok(Phantom::SmoothHead),
            "marschnerlobb" | "ml" => Ok(Phantom::MarschnerLobb),
            "body" | "torso" => Ok(Phantom::Body),
            other => Err(format!(
                "unknown phantom {other:?}, expected shepp-logan (head), smooth-head, marschner-lobb or body"
            )),
        }
    }
}

/// One ellipsoid: centre, semi-axes, rotation about z (degrees), added intensity.
struct Ellipsoid {
    c: [f64; 3],
    r: [f64; 3],
    phi_deg: f64,
    value: f64,
}

// Kak & Slaney's 3D Shepp–Logan geometry with Toft's intensities, on [-1, 1]^3.
const SHEPP_LOGAN: [Ellipsoid; 10] = [
    Ellipsoid {
        c: [0.0, 0.0, 0.0],
        r: [0.69, 0.92, 0.9],
        phi_deg: 0.0,
        value: 1.0,
    },
    Ellipsoid {
        c: [0.0, -0.0184, 0.0],
        r: [0.6624, 0.874, 0.88],
        phi_deg: 0.0,
        value: -0.8,
    },
    Ellipsoid {
        c: [0.22, 0.0, -0.25],
        r: [0.11, 0.31, 0.22],
        phi_deg: -18.0,
        value: -0.2,
    },
    Ellipsoid {
        c: [-0.22, 0.0, -0.25],
        r: [0.16, 0.41, 0.21],
        phi_deg: 18.0,
        value: -0.2,
    },
    Ellipsoid {
        c: [0.0, 0.35, -0.25],
        r: [0.21, 0.25, 0.35],
        phi_deg: 0.0,
        value: 0.1,
    },
    Ellipsoid {
        c: [0.0, 0.1, -0.25],
        r: [0.046, 0.046, 0.046],
        phi_deg: 0.0,
        value: 0.1,
    },
    Ellipsoid {
        c: [-0.08, -0.605, -0.25],
        r: [0.046, 0.023, 0.02],
        phi_deg: 0.0,
        value: 0.1,
    },
    Ellipsoid {
        c: [0.0, -0.1, -0.25],
        r: [0.046, 0.046, 0.046],
        phi_deg: 0.0,
        value: 0.1,
    },
    Ellipsoid {
        c: [0.06, -0.605, -0.25],
        r: [0.023, 0.023, 0.02],
        phi_deg: 0.0,
        value: 0.1,
    },
    Ellipsoid {
        c: [0.0, -0.605, -0.25],
        r: [0.023, 0.046, 0.02],
        phi_deg: 0.0,
        value: 0.1,
    },
];

impl Ellipsoid {
    /// How much of the ellipsoid covers `p`, from 1 inside to 0 outside with a smoothstep
    /// across its surface over the signed distance `±half`. The distance is the first-order
    /// estimate `f / |∇f|` with `f = √q − 1`, exact on spheres and close to the surface.
    fn cover(&self, p: [f64; 3], half: f64) -> f64 {
        let (s, c) = self.phi_deg.to_radians().sin_cos();
        let (dx, dy, dz) = (p[0] - self.c[0], p[1] - self.c[1], p[2] - self.c[2]);
        let l = [c * dx + s * dy, -s * dx + c * dy, dz];
        let u = [l[0] / self.r[0], l[1] / self.r[1], l[2] / self.r[2]];
        let root = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        if root < 1e-9 {
            return 1.0;
        }
        // ∇√q = (x/r₀², y/r₁², z/r₂²) / √q; the rotation keeps its length.
        let g = [u[0] / self.r[0], u[1] / self.r[1], u[2] / self.r[2]];
        let grad = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() / root;
        let dist = (root - 1.0) / grad;
        let t = (0.5 - dist / (2.0 * half)).clamp(0.0, 1.0);
        t * t * (3.0 - 2.0 * t)
    }
}

impl Phantom {
    /// True for the phantoms that take any grid (`X×Y×Z`); the others are cubes.
    #[must_use]
    pub fn any_grid(self) -> bool {
        self == Phantom::Body
    }

    /// Generates the phantom on a `dims` grid: the body on exactly that grid (its spacing in
    /// millimetres, a 400 mm field across x and 700 mm of torso along z); the cubic phantoms
    /// on `dims[0]`³.
    #[must_use]
    pub fn generate_dims(self, dims: [usize; 3]) -> Volume {
        match self {
            Phantom::Body => super::body::generate(dims),
            _ => self.generate(dims[0]),
        }
    }

    /// Generates the phantom on an `n × n × n` grid with unit spacing.
    ///
    /// # Panics
    /// Never for `n ≥ 2`; `n < 2` is clamped to 2.
    #[must_use]
    pub fn generate(self, n: usize) -> Volume {
        let n = n.max(2);
        if self == Phantom::Body {
            return super::body::generate([n; 3]);
        }
        let to_unit = |i: usize| 2.0 * i as f64 / (n - 1) as f64 - 1.0;
        let name = match self {
            Phantom::SheppLogan => format!("shepp-logan phantom {n}³"),
            Phantom::SmoothHead => format!("smooth shepp-logan phantom {n}³"),
            Phantom::MarschnerLobb => format!("marschner-lobb phantom {n}³"),
            Phantom::Body => unreachable!("generated above"),
        };
        let data = match self {
            Phantom::SheppLogan => {
                let mut v = vec![0u8; n * n * n];
                for (idx, out) in v.iter_mut().enumerate() {
                    let p = [
                        to_unit(idx % n),
                        to_unit((idx / n) % n),
                        to_unit(idx / (n * n)),
                    ];
                    let mut value = 0.0;
                    for e in &SHEPP_LOGAN {
                        let (s, c) = e.phi_deg.to_radians().sin_cos();
                        let (dx, dy, dz) = (p[0] - e.c[0], p[1] - e.c[1], p[2] - e.c[2]);
                        let (x, y) = (c * dx + s * dy, -s * dx + c * dy);
                        let q = (x / e.r[0]).powi(2) + (y / e.r[1]).powi(2) + (dz / e.r[2]).powi(2);
                        if q <= 1.0 {
                            value += e.value;
                        }
                    }
                    {
                        *out = (value * 250.0).round().clamp(0.0, 255.0) as u8;
                    }
                }
                VoxelData::U8(Voxels::owned(v))
            }
            Phantom::SmoothHead => {
                // Half-width of the blend: edges ramp over about six voxels, wide enough that the
                // trilinear gradient does not terrace where a surface crosses voxel layers.
                let half = 3.0 * 2.0 / (n - 1) as f64;
                let mut v = vec![0f32; n * n * n];
                for (idx, out) in v.iter_mut().enumerate() {
                    let p = [
                        to_unit(idx % n),
                        to_unit((idx / n) % n),
                        to_unit(idx / (n * n)),
                    ];
                    let value: f64 = SHEPP_LOGAN.iter().map(|e| e.value * e.cover(p, half)).sum();
                    *out = (value * 250.0).clamp(0.0, 255.0) as f32;
                }
                VoxelData::F32(Voxels::owned(v))
            }
            Phantom::MarschnerLobb => {
                let (fm, alpha) = (6.0_f64, 0.25_f64);
                let pi = std::f64::consts::PI;
                let mut v = vec![0f32; n * n * n];
                for (idx, out) in v.iter_mut().enumerate() {
                    let (x, y, z) = (
                        to_unit(idx % n),
                        to_unit((idx / n) % n),
                        to_unit(idx / (n * n)),
                    );
                    let r = (x * x + y * y).sqrt();
                    let rho = (2.0 * pi * fm * (pi * r / 2.0).cos()).cos();
                    let f = ((1.0 - (pi * z / 2.0).sin()) + alpha * (1.0 + rho))
                        / (2.0 * (1.0 + alpha));
                    {
                        *out = f as f32;
                    }
                }
                VoxelData::F32(Voxels::owned(v))
            }
            Phantom::Body => unreachable!("generated above"),
        };
        Volume::new([n; 3], [1.0; 3], data, name).expect("phantom layout is valid by construction")
    }
}
