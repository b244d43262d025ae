//! A CT-like torso in Hounsfield units, generated procedurally at any size.
//!
//! The anatomy is laid out in millimetres on a fixed patient frame, LPS like DICOM: +x the
//! patient's left, +y posterior, +z towards the head. The grid covers a 400 mm field of view
//! across x (and `Y / X` of that across y) and 700 mm from the pelvis to the neck along z,
//! whatever the voxel counts, so any size shows the whole torso and the spacing carries the
//! aspect (a 512×512×1728 grid has 0.78 mm pixels and 0.41 mm slices).
//!
//! Every structure is a distance field painted over the ones before it with a smoothstep
//! across its surface, about three voxels wide: no single-voxel steps for a sample distance
//! to alias into rings, and gradients that shading can light. Per slice only the structures
//! that reach that slice are evaluated, and the slices are generated in parallel; the
//! per-voxel noise is a hash of the voxel index, so the output does not depend on the
//! thread count.

use rayon::prelude::*;

use super::{Volume, VoxelData, Voxels};

/// Field of view across x, millimetres.
pub(super) const FOV_X_MM: f64 = 400.0;
/// Length covered along z, millimetres.
pub(super) const LENGTH_MM: f64 = 700.0;
/// The seed of the tissue noise and of the lung vessel trees.
const SEED: u64 = 0x5eed_b0d1;

/// Hounsfield units of the tissues.
pub(super) mod hu {
    pub(in super::super) const AIR: f64 = -1000.0;
    pub(in super::super) const SKIN: f64 = 40.0;
    pub(in super::super) const FAT: f64 = -100.0;
    pub(in super::super) const MUSCLE: f64 = 50.0;
    pub(in super::super) const VISCERA: f64 = 25.0;
    pub(in super::super) const MEDIASTINUM: f64 = -60.0;
    pub(in super::super) const LUNG: f64 = -860.0;
    pub(in super::super) const VESSEL: f64 = 40.0;
    pub(in super::super) const HEART: f64 = 45.0;
    pub(in super::super) const LIVER: f64 = 60.0;
    pub(in super::super) const SPLEEN: f64 = 48.0;
    pub(in super::super) const KIDNEY: f64 = 32.0;
    pub(in super::super) const DISC: f64 = 85.0;
    pub(in super::super) const CANAL: f64 = 20.0;
    pub(in super::super) const CANCELLOUS: f64 = 260.0;
    pub(in super::super) const CORTICAL: f64 = 1100.0;
}

/// Points (mm, patient frame) inside single tissues, for the tests.
#[cfg(test)]
pub(super) mod landmark {
    /// Inside the right lung, away from its hilum (where the big vessels run).
    pub(in super::super) const LUNG: [f64; 3] = [-105.0, 35.0, 540.0];
    /// The middle of the liver.
    pub(in super::super) const LIVER: [f64; 3] = [-75.0, -10.0, 350.0];
    /// The middle of the heart.
    pub(in super::super) const HEART: [f64; 3] = [25.0, -25.0, 430.0];
    /// The middle of a lumbar vertebral body (the period is 26 mm, bodies at the middle of
    /// each period).
    pub(in super::super) const VERTEBRA: [f64; 3] = [0.0, 42.0, 247.0];
    /// The anterior abdominal fat, halfway through its thickness.
    pub(in super::super) const FAT: [f64; 3] = [0.0, -85.0, 250.0];
    /// A corner of the field, outside the body.
    pub(in super::super) const AIR: [f64; 3] = [-195.0, -190.0, 10.0];
}

/// Smoothstep cover: 1 well inside (`d ≤ -h`), 0 well outside (`d ≥ h`).
#[inline(always)]
fn cover(d: f64, h: f64) -> f64 {
    let t = (0.5 - d / (2.0 * h)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

#[inline(always)]
fn paint(v: &mut f64, value: f64, c: f64) {
    *v += (value - *v) * c;
}

/// An ellipsoid rotated about z.
#[derive(Clone, Copy)]
struct Ellipsoid {
    c: [f64; 3],
    r: [f64; 3],
    cos: f64,
    sin: f64,
}

impl Ellipsoid {
    fn new(c: [f64; 3], r: [f64; 3], rot_deg: f64) -> Self {
        let (sin, cos) = rot_deg.to_radians().sin_cos();
        Ellipsoid { c, r, cos, sin }
    }

    fn grown(self, by: f64) -> Self {
        Ellipsoid {
            r: self.r.map(|r| r + by),
            ..self
        }
    }

    fn z_range(&self, pad: f64) -> (f64, f64) {
        (self.c[2] - self.r[2] - pad, self.c[2] + self.r[2] + pad)
    }

    /// Signed distance, first-order estimate `f / |∇f|` (exact on spheres, close near the
    /// surface, monotone everywhere).
    #[inline(always)]
    fn dist(&self, p: [f64; 3]) -> f64 {
        let (dx, dy, dz) = (p[0] - self.c[0], p[1] - self.c[1], p[2] - self.c[2]);
        let l = [
            self.cos * dx + self.sin * dy,
            -self.sin * dx + self.cos * dy,
            dz,
        ];
        let u = [l[0] / self.r[0], l[1] / self.r[1], l[2] / self.r[2]];
        let root = (u[0] * u[0] + u[1] * u[1] + u[2] * u[2]).sqrt();
        if root < 1e-9 {
            return -self.r[0].min(self.r[1]).min(self.r[2]);
        }
        let g = [u[0] / self.r[0], u[1] / self.r[1], u[2] / self.r[2]];
        let grad = (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() / root;
        (root - 1.0) / grad
    }
}

/// A tapered capsule (a vessel, a clavicle).
#[derive(Clone, Copy)]
struct Capsule {
    a: [f64; 3],
    b: [f64; 3],
    ra: f64,
    rb: f64,
}

impl Capsule {
    fn z_range(&self, pad: f64) -> (f64, f64) {
        let r = self.ra.max(self.rb) + pad;
        (self.a[2].min(self.b[2]) - r, self.a[2].max(self.b[2]) + r)
    }

    #[inline(always)]
    fn dist(&self, p: [f64; 3]) -> f64 {
        let ab = [
            self.b[0] - self.a[0],
            self.b[1] - self.a[1],
            self.b[2] - self.a[2],
        ];
        let ap = [p[0] - self.a[0], p[1] - self.a[1], p[2] - self.a[2]];
        let len2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
        let t = ((ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / len2.max(1e-12)).clamp(0.0, 1.0);
        let q = [ap[0] - ab[0] * t, ap[1] - ab[1] * t, ap[2] - ab[2] * t];
        (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt() - (self.ra + (self.rb - self.ra) * t)
    }
}

/// A bone: a solid painted cancellous inside and cortical within `shell` of its surface.
#[derive(Clone, Copy)]
enum Bone {
    Ellipsoid(Ellipsoid),
    Capsule(Capsule),
}

impl Bone {
    fn z_range(&self, pad: f64) -> (f64, f64) {
        match self {
            Bone::Ellipsoid(e) => e.z_range(pad),
            Bone::Capsule(c) => c.z_range(pad),
        }
    }
    #[inline(always)]
    fn dist(&self, p: [f64; 3]) -> f64 {
        match self {
            Bone::Ellipsoid(e) => e.dist(p),
            Bone::Capsule(c) => c.dist(p),
        }
    }
}

/// SplitMix64: the hash behind the noise and the vessel trees.
#[inline(always)]
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A deterministic stream of uniforms in [0, 1).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = mix(self.0);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// Linear interpolation through `(z, value)` keys with a smoothstep between them, clamped
/// at the ends: the torso's outline changes smoothly along its length.
fn profile(keys: &[(f64, f64)], z: f64) -> f64 {
    if z <= keys[0].0 {
        return keys[0].1;
    }
    for w in keys.windows(2) {
        let ((z0, v0), (z1, v1)) = (w[0], w[1]);
        if z <= z1 {
            let t = (z - z0) / (z1 - z0);
            let s = t * t * (3.0 - 2.0 * t);
            return v0 + (v1 - v0) * s;
        }
    }
    keys[keys.len() - 1].1
}

// The torso's outline: half-width, half-depth and the centre's y, by height.
const HALF_WIDTH: [(f64, f64); 8] = [
    (0.0, 168.0),
    (120.0, 172.0),
    (230.0, 146.0),
    (330.0, 150.0),
    (480.0, 166.0),
    (600.0, 200.0),
    (648.0, 190.0),
    (690.0, 62.0),
];
const HALF_DEPTH: [(f64, f64); 7] = [
    (0.0, 108.0),
    (120.0, 112.0),
    (230.0, 102.0),
    (360.0, 108.0),
    (520.0, 114.0),
    (640.0, 96.0),
    (690.0, 60.0),
];
const CENTRE_Y: [(f64, f64); 4] = [(0.0, 5.0), (300.0, -2.0), (560.0, 0.0), (690.0, 18.0)];

/// Vertebra period and the z where the column ends.
const VERTEBRA_PERIOD: f64 = 26.0;
const RIB_COUNT: usize = 12;

/// The anatomy, fixed in millimetres; built once per volume.
struct Body {
    h: f64,
    lungs: [Ellipsoid; 2],
    heart: Ellipsoid,
    pericardium: Ellipsoid,
    liver: Ellipsoid,
    spleen: Ellipsoid,
    kidneys: [Ellipsoid; 2],
    kidney_fat: [Ellipsoid; 2],
    aorta: [Capsule; 3],
    airways: [Capsule; 3],
    vessels: [Vec<Capsule>; 2],
    bones: Vec<Bone>,
}

/// What of the anatomy reaches one slice.
struct Slice<'a> {
    z: f64,
    a: f64,
    b: f64,
    cy: f64,
    /// Lung vessel segments reaching this slice, per lung.
    vessels: [Vec<&'a Capsule>; 2],
    organs: Vec<(Ellipsoid, f64)>,
    aorta: Vec<&'a Capsule>,
    airways: Vec<&'a Capsule>,
    bones: Vec<&'a Bone>,
    lungs: bool,
    ribs: bool,
    spine: bool,
}

impl Body {
    fn new(h: f64) -> Self {
        let lungs = [
            Ellipsoid::new([-80.0, 12.0, 505.0], [64.0, 82.0, 140.0], 0.0),
            Ellipsoid::new([80.0, 12.0, 510.0], [60.0, 80.0, 135.0], 0.0),
        ];
        let heart = Ellipsoid::new([25.0, -25.0, 430.0], [62.0, 48.0, 56.0], 30.0);
        let kidneys = [
            Ellipsoid::new([-68.0, 40.0, 290.0], [24.0, 19.0, 52.0], -20.0),
            Ellipsoid::new([68.0, 40.0, 300.0], [24.0, 19.0, 52.0], 20.0),
        ];
        let mut rng = Rng(SEED);
        let vessels = [0, 1].map(|side| {
            let s = if side == 0 { -1.0 } else { 1.0 };
            let hilum = [s * 38.0, 15.0, 470.0];
            let mut out = Vec::new();
            // Three lobar trunks (up, out, down), each branching four times.
            for target in [
                [s * 70.0, 10.0, 600.0],
                [s * 110.0, -20.0, 480.0],
                [s * 85.0, 45.0, 400.0],
            ] {
                let dir = norm(sub(target, hilum));
                branch(&mut out, &mut rng, hilum, dir, 55.0, 6.5, 4);
            }
            out
        });
        let aorta = [
            Capsule {
                a: [18.0, 2.0, 230.0],
                b: [16.0, 14.0, 545.0],
                ra: 12.0,
                rb: 12.0,
            },
            Capsule {
                a: [16.0, 14.0, 545.0],
                b: [4.0, -20.0, 585.0],
                ra: 13.0,
                rb: 14.0,
            },
            Capsule {
                a: [4.0, -20.0, 585.0],
                b: [8.0, -30.0, 470.0],
                ra: 14.0,
                rb: 15.0,
            },
        ];
        let mut bones = Vec::new();
        for s in [-1.0, 1.0] {
            // Iliac wings, opening forwards; the femoral heads below them.
            bones.push(Bone::Ellipsoid(Ellipsoid::new(
                [s * 100.0, 18.0, 105.0],
                [11.0, 58.0, 70.0],
                -s * 35.0,
            )));
            bones.push(Bone::Ellipsoid(Ellipsoid::new(
                [s * 88.0, -2.0, 22.0],
                [25.0, 25.0, 25.0],
                0.0,
            )));
            // Scapulae, flat against the upper back.
            bones.push(Bone::Ellipsoid(Ellipsoid::new(
                [s * 100.0, 82.0, 565.0],
                [55.0, 8.0, 72.0],
                -s * 25.0,
            )));
            // Humeral heads at the shoulders.
            bones.push(Bone::Ellipsoid(Ellipsoid::new(
                [s * 172.0, 4.0, 612.0],
                [26.0, 26.0, 28.0],
                0.0,
            )));
            // Clavicles from the top of the sternum to the shoulders.
            bones.push(Bone::Capsule(Capsule {
                a: [s * 20.0, -88.0, 628.0],
                b: [s * 150.0, -12.0, 645.0],
                ra: 8.0,
                rb: 9.0,
            }));
        }
        // Sacrum: a wedge continuing the column into the pelvis.
        bones.push(Bone::Ellipsoid(Ellipsoid::new(
            [0.0, 62.0, 95.0],
            [42.0, 22.0, 60.0],
            0.0,
        )));
        // Sternum.
        bones.push(Bone::Capsule(Capsule {
            a: [0.0, -80.0, 620.0],
            b: [0.0, -92.0, 468.0],
            ra: 9.0,
            rb: 7.0,
        }));
        Body {
            h,
            lungs,
            heart,
            pericardium: heart.grown(7.0),
            liver: Ellipsoid::new([-60.0, -8.0, 358.0], [98.0, 82.0, 68.0], 15.0),
            spleen: Ellipsoid::new([95.0, 42.0, 385.0], [30.0, 40.0, 45.0], 30.0),
            kidneys,
            kidney_fat: kidneys.map(|k| k.grown(8.0)),
            aorta,
            airways: [
                // Trachea down the neck, then the two main bronchi to the hila.
                Capsule {
                    a: [0.0, -20.0, 700.0],
                    b: [0.0, -2.0, 540.0],
                    ra: 9.0,
                    rb: 9.0,
                },
                Capsule {
                    a: [0.0, -2.0, 540.0],
                    b: [-38.0, 15.0, 478.0],
                    ra: 7.0,
                    rb: 5.5,
                },
                Capsule {
                    a: [0.0, -2.0, 540.0],
                    b: [38.0, 15.0, 478.0],
                    ra: 7.0,
                    rb: 5.5,
                },
            ],
            vessels,
            bones,
        }
    }

    fn slice(&self, z: f64) -> Slice<'_> {
        let pad = 2.0 * self.h;
        let reaches = |(lo, hi): (f64, f64)| z >= lo && z <= hi;
        let organs = [
            (self.liver, hu::LIVER),
            (self.spleen, hu::SPLEEN),
            (self.kidney_fat[0], hu::FAT),
            (self.kidney_fat[1], hu::FAT),
            (self.kidneys[0], hu::KIDNEY),
            (self.kidneys[1], hu::KIDNEY),
            (self.pericardium, hu::FAT),
            (self.heart, hu::HEART),
        ]
        .into_iter()
        .filter(|(e, _)| reaches(e.z_range(pad)))
        .collect();
        Slice {
            z,
            a: profile(&HALF_WIDTH, z),
            b: profile(&HALF_DEPTH, z),
            cy: profile(&CENTRE_Y, z),
            vessels: [0, 1].map(|s| {
                self.vessels[s]
                    .iter()
                    .filter(|c| reaches(c.z_range(pad)))
                    .collect()
            }),
            organs,
            airways: self
                .airways
                .iter()
                .filter(|c| reaches(c.z_range(pad)))
                .collect(),
            aorta: self
                .aorta
                .iter()
                .filter(|c| reaches(c.z_range(pad)))
                .collect(),
            bones: self
                .bones
                .iter()
                .filter(|b| reaches(b.z_range(pad)))
                .collect(),
            lungs: self.lungs.iter().any(|l| reaches(l.z_range(pad))),
            ribs: (330.0..=640.0).contains(&z),
            spine: z <= 655.0,
        }
    }

    /// The HU value at `p` (mm) before noise.
    #[inline]
    fn value(&self, s: &Slice<'_>, x: f64, y: f64) -> f64 {
        let h = self.h;
        let z = s.z;
        let p = [x, y, z];
        // Torso outline: an ellipse per slice; the distance estimate as for the ellipsoids.
        let (ux, uy) = (x / s.a, (y - s.cy) / s.b);
        let rho = (ux * ux + uy * uy).sqrt();
        let grad = if rho > 1e-9 {
            ((ux / s.a).powi(2) + (uy / s.b).powi(2)).sqrt() / rho
        } else {
            1.0 / s.a.max(s.b)
        };
        let d_out = (rho - 1.0) / grad;
        if d_out > h {
            return hu::AIR;
        }
        // cos of the angle from the back (+y) around the outline: fat is thick in front.
        let back = if rho > 1e-9 { uy / rho } else { 0.0 };
        let front = (-back).max(0.0);
        let belly = cover(z - 330.0, 60.0) * cover(90.0 - z, 60.0);
        let fat = 10.0 + 6.0 * (1.0 - back.abs()) + front * (6.0 + 14.0 * belly);
        let skin = 2.5;
        // Paraspinal muscles: the wall is thick at the back.
        let muscle = 11.0 + 26.0 * back.max(0.0).powi(3);
        let mut v = hu::AIR;
        paint(&mut v, hu::SKIN, cover(d_out, h));
        paint(&mut v, hu::FAT, cover(d_out + skin, h));
        paint(&mut v, hu::MUSCLE, cover(d_out + skin + fat, h));
        let d_cavity = d_out + skin + fat + muscle;
        let c_cavity = cover(d_cavity, h);
        if c_cavity <= 0.0 {
            return v + self.bones_and_spine(s, p, v, d_out, back, skin + fat + muscle);
        }
        // The cavity: mediastinal fat above the diaphragm, viscera below, with a
        // low-frequency texture so that the soft tissue is not flat.
        let chest = cover(400.0 - z, 30.0);
        let texture = 12.0 * ((x * 0.11).sin() * (y * 0.09).sin() * (z * 0.07 + x * 0.03).sin());
        let cavity = hu::VISCERA + (hu::MEDIASTINUM - hu::VISCERA) * chest + texture;
        paint(&mut v, cavity, c_cavity);
        for (e, value) in &s.organs {
            let d = e.dist(p).max(d_cavity);
            paint(&mut v, *value, cover(d, h));
        }
        for c in &s.aorta {
            paint(&mut v, hu::VESSEL, cover(c.dist(p), h));
        }
        for c in &s.airways {
            paint(&mut v, hu::AIR + 50.0, cover(c.dist(p), h));
        }
        if s.lungs {
            let heart = self.pericardium.dist(p);
            for (side, lung) in self.lungs.iter().enumerate() {
                // Domed diaphragm under each lung, higher on the right (over the liver).
                let lx = (x - lung.c[0]) / lung.r[0];
                let dome = if side == 0 { 405.0 } else { 390.0 } + 40.0 * lx * lx;
                let d = lung.dist(p).max(dome - z).max(-heart).max(d_cavity + 4.0);
                let c_lung = cover(d, h);
                if c_lung <= 0.0 {
                    continue;
                }
                let parenchyma = hu::LUNG + 25.0 * (texture / 12.0);
                paint(&mut v, parenchyma, c_lung);
                let d_vessel = s.vessels[side]
                    .iter()
                    .map(|c| c.dist(p))
                    .fold(f64::INFINITY, f64::min);
                paint(&mut v, hu::VESSEL, cover(d_vessel, h) * c_lung);
            }
        }
        v + self.bones_and_spine(s, p, v, d_out, back, skin + fat + muscle)
    }

    /// The change that the bones (ribs, column and the others) make to `v`.
    #[inline]
    fn bones_and_spine(
        &self,
        s: &Slice<'_>,
        p: [f64; 3],
        v0: f64,
        d_out: f64,
        back: f64,
        wall: f64,
    ) -> f64 {
        let h = self.h;
        let mut v = v0;
        let shell = 2.0;
        let bone = |v: &mut f64, d: f64| {
            let c = cover(d, h);
            if c > 0.0 {
                let marrow = cover(d + shell, h);
                let value = hu::CORTICAL + (hu::CANCELLOUS - hu::CORTICAL) * marrow;
                paint(v, value, c);
            }
        };
        for b in &s.bones {
            bone(&mut v, b.dist(p));
        }
        let [x, y, z] = p;
        let spine_y = s.cy + s.b - 68.0;
        if s.spine && (y - spine_y).abs() < 75.0 && x.abs() < 60.0 {
            // One vertebra per period: a disc, the body, the arch round the canal with its
            // spinous and transverse processes.
            let k = (z / VERTEBRA_PERIOD).floor();
            let zl = z - (k + 0.5) * VERTEBRA_PERIOD;
            let scale = if z > 520.0 { 0.78 } else { 1.0 };
            let (ra, rb) = (24.0 * scale, 17.0 * scale);
            let (ex, ey) = (x / ra, (y - spine_y) / rb);
            let er = (ex * ex + ey * ey).sqrt();
            let d_disc2 = (er - 1.0) * ra.min(rb);
            paint(&mut v, hu::DISC, cover(d_disc2, h));
            let d_body = box_round(d_disc2, zl.abs() - 10.5);
            bone(&mut v, d_body);
            let canal_y = spine_y + rb + 10.0;
            let r_canal = ((x * x) + (y - canal_y).powi(2)).sqrt();
            let arch_z = (zl + 2.0).abs() - 7.0;
            let d_ring = box_round((r_canal - 17.0 * scale).max(9.0 * scale - r_canal), arch_z);
            let spinous = Capsule {
                a: [0.0, canal_y + 12.0, 0.0],
                b: [0.0, canal_y + 26.0 * scale, 0.0],
                ra: 5.0,
                rb: 4.0,
            };
            let sx = if x < 0.0 { -1.0 } else { 1.0 };
            let transverse = Capsule {
                a: [sx * 10.0, canal_y - 2.0, 0.0],
                b: [sx * 40.0 * scale, canal_y + 4.0, 0.0],
                ra: 5.5,
                rb: 4.5,
            };
            let d_arch = d_ring
                .min(box_round(spinous.dist([x, y, 0.0]), arch_z))
                .min(box_round(transverse.dist([x, y, 0.0]), arch_z));
            if r_canal < 9.0 * scale + h {
                paint(
                    &mut v,
                    hu::CANAL,
                    cover(box_round(r_canal - 9.0 * scale, 0.0), h),
                );
            }
            bone(&mut v, d_arch);
        }
        if s.ribs {
            // Twelve ribs following the chest wall just under the muscle, each falling
            // towards the front; the lower ones end further back (floating ribs).
            let depth = d_out + wall - 3.0;
            if depth.abs() < 14.0 {
                let phi = back.clamp(-1.0, 1.0).acos();
                let drop = 70.0 * (1.0 - back) * 0.5;
                let top = 618.0;
                let gap = 24.0;
                let u = (top - drop - z) / gap;
                let i = u.round();
                if (0.0..RIB_COUNT as f64).contains(&i) {
                    let reach = if i >= 10.0 { 1.6 } else { 2.7 - 0.04 * i };
                    let dz = (u - i) * gap;
                    let (er, ez) = (depth / 4.0, dz / 7.0);
                    let d = ((er * er + ez * ez).sqrt() - 1.0) * 4.0;
                    // Both ends as distances (1 rad of the wall ≈ 120 mm), so they blend too.
                    let ends = ((phi - reach) * 120.0).max((0.4 - phi) * 120.0);
                    bone(&mut v, d.max(ends));
                }
            }
        }
        v - v0
    }
}

/// Distance to the intersection of a 2-D shape (`d_xy`) and a slab (`d_z`), rounded
/// outside the edge like a capped cylinder.
#[inline(always)]
fn box_round(d_xy: f64, d_z: f64) -> f64 {
    let outside = (d_xy.max(0.0).powi(2) + d_z.max(0.0).powi(2)).sqrt();
    outside + d_xy.max(d_z).min(0.0)
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: [f64; 3]) -> [f64; 3] {
    let l = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt().max(1e-12);
    a.map(|x| x / l)
}

/// Adds a vessel and, `depth` more times, two thinner children bent away from it.
fn branch(
    out: &mut Vec<Capsule>,
    rng: &mut Rng,
    from: [f64; 3],
    dir: [f64; 3],
    len: f64,
    r: f64,
    depth: u32,
) {
    let to = [
        from[0] + dir[0] * len,
        from[1] + dir[1] * len,
        from[2] + dir[2] * len,
    ];
    let rb = r * 0.72;
    out.push(Capsule {
        a: from,
        b: to,
        ra: r,
        rb,
    });
    if depth == 0 {
        return;
    }
    for _ in 0..2 {
        let jitter = [
            rng.range(-0.8, 0.8),
            rng.range(-0.8, 0.8),
            rng.range(-0.8, 0.8),
        ];
        let child = norm([dir[0] + jitter[0], dir[1] + jitter[1], dir[2] + jitter[2]]);
        let child_len = len * rng.range(0.6, 0.8);
        branch(out, rng, to, child, child_len, rb, depth - 1);
    }
}

/// The voxel spacing (mm) of a body phantom of `dims` voxels.
pub(super) fn spacing(dims: [usize; 3]) -> [f64; 3] {
    let p = FOV_X_MM / dims[0] as f64;
    [p, p, LENGTH_MM / dims[2] as f64]
}

/// The patient-frame point (mm) of voxel `(i, j, k)`.
pub(super) fn position(dims: [usize; 3], ijk: [usize; 3]) -> [f64; 3] {
    let s = spacing(dims);
    [
        (ijk[0] as f64 - (dims[0] as f64 - 1.0) * 0.5) * s[0],
        (ijk[1] as f64 - (dims[1] as f64 - 1.0) * 0.5) * s[1],
        (ijk[2] as f64 + 0.5) * s[2],
    ]
}

/// Generates the body phantom on a `dims` grid (each at least 2).
pub(super) fn generate(dims: [usize; 3]) -> Volume {
    let dims = dims.map(|d| d.max(2));
    let s = spacing(dims);
    // Surfaces blend over about three voxels of the coarsest axis.
    let body = Body::new(1.5 * s[0].max(s[2]));
    let plane = dims[0] * dims[1];
    let mut data = vec![0i16; plane * dims[2]];
    data.par_chunks_mut(plane).enumerate().for_each(|(k, out)| {
        let z = position(dims, [0, 0, k])[2];
        let slice = body.slice(z);
        for j in 0..dims[1] {
            let y = position(dims, [0, j, 0])[1];
            for i in 0..dims[0] {
                let x = position(dims, [i, 0, 0])[0];
                let idx = (k * plane + j * dims[0] + i) as u64;
                let n = mix(SEED ^ idx);
                // Triangular noise, σ ≈ 8 HU, as on a real scan.
                let noise = (((n & 0xffff) + ((n >> 16) & 0xffff)) as f64 / 65535.0 - 1.0) * 19.6;
                let v = body.value(&slice, x, y) + noise;
                out[j * dims[0] + i] = v.round().clamp(-1024.0, 3071.0) as i16;
            }
        }
    });
    let name = format!("body phantom {}×{}×{}", dims[0], dims[1], dims[2]);
    Volume::new(
        dims,
        s.map(|x| x as f32),
        VoxelData::I16(Voxels::owned(data)),
        name,
    )
    .expect("phantom layout is valid by construction")
}
