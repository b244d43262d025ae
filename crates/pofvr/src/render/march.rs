//! The march engine: every pixel's ray walks the one sample lattice front to back across
//! the whole volume, as the reference [`RayCaster::render`] does, but leaps over the runs
//! of samples that lie in empty space ([`Occupancy`]: 4³ cells and each empty cell's
//! chessboard distance to an occupied one), and stops once its own opacity reaches the
//! termination threshold.
//!
//! The leaps are exact, not geometric estimates. A sample's position along each axis,
//! `o + (k·step)·d` in f32, is monotone in the lattice index `k` (every float operation in
//! it is monotone), and so is its trilinear cell (the sampler's clamp and floor). An empty
//! cell at distance `D` from every occupied one is the centre of a cube of `2D − 1` empty
//! cells per axis; the walk estimates in float where the ray leaves that cube, and leaps
//! only once the last sample of the leap is found, by the sampler's own cell, inside the
//! cube: then every sample between is inside too, and classifies to zero opacity, which
//! composites to nothing. Everything else goes, in order and with the same accumulator,
//! through the same float operations as the reference, so the image equals it bit for bit.
//!
//! Where the CPU has AVX2, the frame goes in packets of eight rays (4 × 2 pixels), one
//! ray per lane, through `arch/x86_64/packet.rs` (sixteen, 4 × 4, through
//! `arch/x86_64/packet16.rs` where it has AVX-512): composited lane-wise, and leaping for
//! the packet as a whole by the rule above evaluated lane-wise; while the packet steps, a
//! lane in an empty cell reads no corners of its own. Elsewhere (SSE2, or the
//! scalar loop on request) each ray walks alone: marching a sample of zero opacity changes
//! nothing either, so the walk marches through occupied cells, and the empty cells next to
//! them, in chunks of samples through the sample loops ([`super::arch::march`]) without
//! looking at each cell.

use rayon::prelude::*;

use super::arch::{self, Gather};
use super::blocks::MarchBlocks;
use super::camera::Camera;
use super::frame_rays::FrameRays;
use super::image::Image;
use super::lattice::{sample_range, IndexRay};
use super::occupancy::Occupancy;
use super::ray_caster::{RayCaster, RayStats};
use super::sampler::TrilinearSampler;
use super::skip::Skip;
use crate::with_voxels;

/// Rows per parallel work item, as the reference.
const TILE_ROWS: usize = 8;
/// Columns of the pixel tiles a band is traversed in, as the reference.
const TILE_COLS: usize = 8;
/// The longest run of samples gathered for the sample loop before it is marched and the
/// ray's opacity checked: past that, walking on through occupied cells would be wasted on
/// a ray about to terminate.
const RUN_MAX: i32 = 64;
/// The samples the walk moves on by in an occupied cell, or in an empty one next to an
/// occupied one, before it looks at the occupancy again: the sample loop takes such
/// samples for less than a cell lookup per few samples would cost.
const CHUNK: i32 = 16;
/// The shortest run of empty samples worth a skip: a shorter one costs more in the split of
/// the sample loop than marching its samples of zero opacity does.
const MIN_SKIP: i32 = 2;

/// What a march frame took: the rays and samples, the samples jumped over, and the loop
/// that marched them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MarchStats {
    /// Rays that met the volume and samples taken.
    pub rays: RayStats,
    /// Lattice samples in empty cells the rays did not read before terminating: jumped
    /// over, or, in a packet that steps on because another ray is in an occupied cell,
    /// passed without reading their corners (they are of zero opacity either way).
    pub skipped_samples: u64,
    /// Steps of the packet loops: iterations in which at least one ray of a packet took a
    /// sample or leapt (0 where no packet loop runs). A frame's time is about its steps
    /// times the cost of one, which is how `docs/results.md` splits it.
    pub packet_steps: u64,
    /// The loop that ran: "avx512" (packets of sixteen rays), "avx2" (packets of eight),
    /// or, where no packet loop runs, the walk around the one-ray loop
    /// ([`RayCaster::simd`]): "walk-avx2", "sse2" or "scalar". Empty before a frame.
    pub simd: &'static str,
    /// Whether the packet loop read the voxels from the volume's blocked copy
    /// ([`MarchBlocks`]).
    pub blocks: bool,
}

impl std::ops::AddAssign for MarchStats {
    fn add_assign(&mut self, o: Self) {
        self.rays += o.rays;
        self.skipped_samples += o.skipped_samples;
        self.packet_steps += o.packet_steps;
        if self.simd.is_empty() {
            self.simd = o.simd;
        }
        self.blocks |= o.blocks;
    }
}

impl RayCaster<'_> {
    /// Renders the whole volume as [`RayCaster::render`] does, bit for bit, skipping the
    /// samples in the cells `occ` says are empty (see the [module](self)). `occ` must be
    /// built for this volume and this caster's classification.
    #[must_use]
    pub fn render_march(&self, camera: &Camera, occ: &Occupancy) -> (Image, MarchStats) {
        self.render_march_with(camera, occ, None)
    }

    /// [`Self::render_march`], the eight-ray packet loop reading the voxels from `blocks`,
    /// this volume's blocked copy ([`MarchBlocks`]), where given: the same image, from
    /// other addresses (faster on volumes far larger than the caches).
    ///
    /// # Panics
    /// Where `blocks` was not built from this caster's volume (its block counts differ).
    #[must_use]
    pub fn render_march_with(
        &self,
        camera: &Camera,
        occ: &Occupancy,
        blocks: Option<&MarchBlocks>,
    ) -> (Image, MarchStats) {
        let w = camera.width as usize;
        let mut image = Image::new(camera.width, camera.height);
        let frame = camera.frame();
        let vbox = self.volume_box();
        let settings = self.settings();
        let rays = FrameRays::new(
            camera,
            &frame,
            self.volume().spacing(),
            self.volume().unit(),
            settings.jitter.map(|seed| (seed, settings.step)),
        );
        let mut stats = with_voxels!(self.volume().data(), v => {
            let tri = TrilinearSampler::new(v, self.volume().dims());
            let copy = blocks.map(|b| {
                assert_eq!(
                    b.blocks(),
                    super::blocks::blocks_of(self.volume().dims()),
                    "the blocked copy of another volume"
                );
                b.voxels().expect("a blocked copy of this volume's voxel type")
            });
            let blocked = copy.map(|c| TrilinearSampler::blocked(c, &tri));
            if let Some(st) = self.render_packets(&tri, blocked.as_ref(), &rays, occ, w, image.pixels_mut()) {
                MarchStats { simd: self.packet_simd(), ..st }
            } else {
            image
                .pixels_mut()
                .par_chunks_mut(w * TILE_ROWS)
                .enumerate()
                .map(|(band, rows)| {
                    let mut st = MarchStats::default();
                    let mut skip = Skip::new(occ, &tri, settings.step);
                    for x0 in (0..w).step_by(TILE_COLS) {
                        for r in 0..rows.len() / w {
                            for x in x0..(x0 + TILE_COLS).min(w) {
                                let y = (band * TILE_ROWS + r) as u32;
                                let ray = rays.ray(x as u32, y);
                                debug_assert_eq!(ray, self.pixel_ray(camera, &frame, x as u32, y));
                                if let Some(span) = ray.span(&vbox) {
                                    st.rays.rays += 1;
                                    let range = sample_range(span, settings.step);
                                    skip.aim(&ray);
                                    self.walk(&tri, &mut skip, &ray, range, &mut rows[r * w + x], &mut st);
                                }
                            }
                        }
                    }
                    st.skipped_samples = skip.skipped;
                    st
                })
                .reduce(MarchStats::default, |mut a, b| {
                    a += b;
                    a
                })
            }
        });
        if stats.simd.is_empty() {
            stats.simd = match self.simd() {
                "avx2" => "walk-avx2",
                other => other,
            };
        }
        (image, stats)
    }

    /// The frame in packets through the packet loops, in parallel over bands of rows:
    /// sixteen rays, 4 × 4 pixels each, on AVX-512 ([`arch::march_packet16`]) where it
    /// runs, else eight, 4 × 2 pixels each, on AVX2 ([`arch::march_packet`]); `None`,
    /// having done nothing, where neither runs.
    #[cfg(target_arch = "x86_64")]
    fn render_packets<T: Gather>(
        &self,
        tri: &TrilinearSampler<'_, T>,
        blocked: Option<&TrilinearSampler<'_, T>>,
        rays: &FrameRays,
        occ: &Occupancy,
        w: usize,
        pixels: &mut [[f32; 4]],
    ) -> Option<MarchStats> {
        use arch::x86_64::packet::LANES;
        use arch::x86_64::packet16::LANES as LANES16;
        let p = self.params();
        if !arch::packets(&p, tri) {
            return None;
        }
        if p.avx512 {
            self.packet_frame::<LANES16, 4>(rays, occ, w, pixels, &|tab, pk| {
                arch::march_packet16(&p, tri, tab, pk)
            })
        } else {
            let st = self.packet_frame::<LANES, 4>(rays, occ, w, pixels, &|tab, pk| {
                arch::march_packet(&p, tri, blocked, tab, pk)
            });
            st.map(|st| MarchStats {
                blocks: blocked.is_some_and(|b| arch::x86_64::avx2::fits(b)),
                ..st
            })
        }
    }

    /// [`Self::render_packets`] in packets of `N` rays, `PW` pixels wide, each marched by
    /// `march` (`None` where its loop does not run).
    #[cfg(target_arch = "x86_64")]
    #[allow(clippy::type_complexity)]
    fn packet_frame<const N: usize, const PW: usize>(
        &self,
        rays: &FrameRays,
        occ: &Occupancy,
        w: usize,
        pixels: &mut [[f32; 4]],
        march: &(dyn Fn(
            &arch::x86_64::packet::PacketTables<'_>,
            &mut arch::x86_64::packet::Packet<N>,
        ) -> Option<arch::x86_64::packet::PacketStats>
              + Sync),
    ) -> Option<MarchStats> {
        use arch::x86_64::packet::{Packet, PacketTables};
        let ph = N / PW;
        debug_assert_eq!(TILE_ROWS % ph, 0);
        let step = self.settings().step;
        let vbox = self.volume_box();
        let p = self.params();
        let cells = occ.dims().map(|n| n as i32);
        let tab = PacketTables {
            leap: occ.leaps(),
            cells,
            sign: [0; 3],
        };
        // The octant of the frame's middle ray (the direction of every ray in an
        // orthographic frame): packets whose every ray heads that way (or runs along an
        // axis) leap by the table toward it, whose boxes reach only ahead of the ray.
        let mid = rays.ray(w as u32 / 2, (pixels.len() / w) as u32 / 2);
        let sign = mid.d.map(|d| if d < 0.0 { -1i8 } else { 1 });
        let ahead = (N == arch::x86_64::packet::LANES).then(|| PacketTables {
            leap: occ.leaps_toward(sign),
            cells,
            sign,
        });
        let heads = |r: &IndexRay| (0..3).all(|a| r.d[a] == 0.0 || (r.d[a] < 0.0) == (sign[a] < 0));
        let none = IndexRay {
            o: [0.0; 3],
            d: [0.0; 3],
            dir: [0.0; 3],
        };
        pixels
            .par_chunks_mut(w * TILE_ROWS)
            .enumerate()
            .map(|(band, rows)| {
                let mut st = MarchStats::default();
                let h = rows.len() / w;
                let mut pk = Packet::<N> {
                    rays: [none; N],
                    k0: [0; N],
                    k1: [0; N],
                    acc: [[0.0; 4]; N],
                };
                for x0 in (0..w).step_by(PW) {
                    for r0 in (0..h).step_by(ph) {
                        let mut valid = 0u32;
                        for j in 0..N {
                            let (x, r) = (x0 + j % PW, r0 + j / PW);
                            if x < w && r < h {
                                pk.rays[j] = rays.ray(x as u32, (band * TILE_ROWS + r) as u32);
                                valid |= 1 << j;
                            }
                        }
                        let hit = arch::x86_64::packet_ranges(&p, &mut pk, valid, &vbox, step);
                        st.rays.rays += u64::from(hit.count_ones());
                        for j in 0..N {
                            if hit >> j & 1 != 0 {
                                let (x, r) = (x0 + j % PW, r0 + j / PW);
                                pk.acc[j] = rows[r * w + x];
                            }
                        }
                        let t = match &ahead {
                            Some(a) if (0..N).all(|j| hit >> j & 1 == 0 || heads(&pk.rays[j])) => a,
                            _ => &tab,
                        };
                        let ps = march(t, &mut pk)?;
                        st.rays.samples += ps.samples;
                        st.skipped_samples += ps.skipped;
                        st.packet_steps += ps.steps;
                        for j in 0..N {
                            let (x, r) = (x0 + j % PW, r0 + j / PW);
                            if pk.k0[j] < pk.k1[j] {
                                rows[r * w + x] = pk.acc[j];
                            }
                        }
                    }
                }
                Some(st)
            })
            .reduce(
                || Some(MarchStats::default()),
                |a, b| {
                    let mut a = a?;
                    a += b?;
                    Some(a)
                },
            )
    }

    /// [`Self::render_packets`] where there is no packet loop.
    #[cfg(not(target_arch = "x86_64"))]
    fn render_packets<T: Gather>(
        &self,
        _: &TrilinearSampler<'_, T>,
        _: Option<&TrilinearSampler<'_, T>>,
        _: &FrameRays,
        _: &Occupancy,
        _: usize,
        _: &mut [[f32; 4]],
    ) -> Option<MarchStats> {
        None
    }

    /// Walks samples `k0..k1` of `ray` through the cells of `skip` into `acc`, where the
    /// packet loop does not run (SSE2 or the scalar loop): the walk goes from sample to
    /// sample: at sample `k`, its cell (the sampler's own) and that cell's
    /// [`Occupancy::leaps`] give a cube of empty cells around it, and
    /// [`Skip::leap_end`] the first sample past it; everything else is marched, in order,
    /// in as few calls of the sample loop as the leaps allow.
    fn walk<T: Gather>(
        &self,
        tri: &TrilinearSampler<'_, T>,
        skip: &mut Skip<'_>,
        ray: &IndexRay,
        (k0, k1): (i32, i32),
        acc: &mut [f32; 4],
        st: &mut MarchStats,
    ) {
        let ert = self.settings().ert;
        let march = |from: i32, to: i32, acc: &mut [f32; 4], st: &mut MarchStats| {
            st.rays.samples += self.march(tri, ray, (from, to), acc);
            acc[3] >= ert
        };
        // The first sample neither marched nor skipped: samples `pend..k` are marched
        // before any skip past them.
        let mut pend = k0;
        let mut k = k0;
        while k < k1 {
            let c = skip.cell(k);
            let leap = skip.leap_of(c);
            let kb;
            if Skip::leaps(leap) {
                kb = skip.leap_end(k, c, leap, k1);
                if kb - k >= MIN_SKIP {
                    if k > pend && march(pend, k, acc, st) {
                        return;
                    }
                    skip.skipped += (kb - k) as u64;
                    pend = kb;
                }
            } else {
                kb = (k + CHUNK).min(k1);
                if kb - pend >= RUN_MAX {
                    // A long occupied stretch is marched before walking on: the ray may
                    // terminate in it.
                    if march(pend, kb, acc, st) {
                        return;
                    }
                    pend = kb;
                }
            }
            k = kb;
        }
        if pend < k1 {
            march(pend, k1, acc, st);
        }
    }
}
