//! Whether the packet loops load by gathers: one `vpgatherdd` per word for all the lanes
//! of a step (a cell's corners, the classification's entries, the occupancy's:
//! [`super::gather16`] for sixteen lanes, `corners8_gathered`, `channel8` and `leaps8` for
//! eight), or each lane's word on its own, inserted into a vector.
//!
//! Which form is faster depends on the core and on the loop. On the Intel development VM
//! (AVX-512, no gather microcode mitigation) the sixteen-lane gathers made frames 10–25 %
//! faster (`docs/results.md`, stop 38) and the eight-lane ones 5–7 % (stop 41); on cores
//! whose gathers are microcoded or mitigated (older Intel, AMD before Zen 5) they are known
//! to lose. So the choice is measured once per process and per loop ([`pays`]): the loop
//! itself marches a synthetic volume both ways, and the gathers are taken only where they
//! are clearly faster. `POFVR_GATHER=on|off` overrides the measurement. Both forms read the
//! same words, so the image is the same either way.

use std::sync::OnceLock;
use std::time::{Duration, Instant};

use super::super::MarchParams;
use super::packet::{march8, Packet, PacketStats, PacketTables};
use super::packet16::march16;
use crate::render::lattice::IndexRay;
use crate::render::occupancy::{leap_table, CELL};
use crate::render::sampler::TrilinearSampler;
use crate::render::transfer_function::{ClassifierView, BIN_MAX, TF_BINS};

/// Whether the packet loop of sixteen lanes (`sixteen`) or of eight loads by gathers: as
/// `POFVR_GATHER` says (`on`, `off`), else as measured once per process and loop
/// ([`measure`]). False where that loop cannot run.
pub(crate) fn pays(sixteen: bool) -> bool {
    static PAYS: [OnceLock<bool>; 2] = [OnceLock::new(), OnceLock::new()];
    let runs = if sixteen {
        super::packet16::available()
    } else {
        super::avx2::available()
    };
    *PAYS[usize::from(sixteen)].get_or_init(|| match std::env::var("POFVR_GATHER").as_deref() {
        Ok(s) if s.eq_ignore_ascii_case("on") => runs,
        Ok(s) if s.eq_ignore_ascii_case("off") => false,
        _ => {
            runs && {
                let (lanes, gathers) = measure(sixteen);
                gathers.as_secs_f64() < GATHER_MARGIN * lanes.as_secs_f64()
            }
        }
    })
}
/// How much faster than the per-lane loads the gathers must be to be taken: a choice
/// that wins by less is within what this measurement can tell on a busy machine (its
/// timings spread by about 3 % from one process to the next).
const GATHER_MARGIN: f64 = 0.95;

/// Voxels per axis of the synthetic volume [`measure`] marches (256 KiB of i16: in L2,
/// as most of a frame's loads are, so that what is timed is the loop, not the memory).
const MEASURE_N: usize = 64;
/// Packets per timing, samples per ray, and timings per form.
const MEASURE_PACKETS: usize = 32;
const MEASURE_SAMPLES: i32 = 48;
const MEASURE_ROUNDS: usize = 7;
/// The synthetic volume's values up to which the classification is opaque (bins below
/// `TF_BINS / 2`, values 0–1023 over the table): about half of each ray.
const OPAQUE_BELOW: i16 = 512;

/// What [`measure`] marches: a synthetic volume and classification shaped like a frame's,
/// in miniature. Values run in diagonal bands, so about half of each ray is opaque, and
/// half of the cells are empty and leapt over; neighbouring rays see the same bands, so,
/// as in frames, many steps find every lane's sample transparent and fetch no colour.
/// (A first version, every cell occupied and every sample opaque, timed the gathers at
/// 0.86–0.92 of the per-lane loads on a core where frames took 0.63–1.03: too close to
/// the margin to decide the same way in every process, `docs/results.md`, stop 39.)
struct Synthetic {
    v: Vec<i16>,
    rgba: Vec<[f32; 4]>,
    leap: Vec<u8>,
    /// Packets of sixteen rays (4 × 4 pixels) and of eight (4 × 2) over the same rays.
    packets16: Vec<Packet<16>>,
    packets8: Vec<Packet<8>>,
}

impl Synthetic {
    fn new() -> Self {
        let n = MEASURE_N;
        let v: Vec<i16> = (0..n * n * n)
            .map(|i| ((i % n * 3 + i / n % n * 5 + i / (n * n) * 7) * 2 % 1024) as i16)
            .collect();
        // Values 0–1023 over the table: bins below the middle are opaque.
        let rgba: Vec<[f32; 4]> = (0..TF_BINS)
            .map(|b| {
                if b < TF_BINS / 2 {
                    [0.05, 0.04, 0.03, 0.05]
                } else {
                    [0.0; 4]
                }
            })
            .collect();
        let cells = (n - 1).div_ceil(CELL);
        // A cell is occupied where some corner of its trilinear cells is opaque.
        let occupied: Vec<bool> = (0..cells * cells * cells)
            .map(|c| {
                let at = [c % cells, c / cells % cells, c / (cells * cells)].map(|a| a * CELL);
                let span = |a: usize| at[a]..=(at[a] + CELL).min(n - 1);
                span(2).any(|z| {
                    span(1).any(|y| span(0).any(|x| v[(z * n + y) * n + x] <= OPAQUE_BELOW))
                })
            })
            .collect();
        let leap = leap_table(&occupied, [cells; 3]);
        let len = (0.3f32 * 0.3 + 0.4 * 0.4 + 0.85 * 0.85).sqrt();
        let d = [0.3 / len, 0.4 / len, 0.85 / len];
        // Rays through a 32 × 16 grid of pixels, 0.9 voxels apart.
        let ray = |x: usize, y: usize| IndexRay {
            o: [1.5 + x as f32 * 0.9, 1.5 + y as f32 * 0.9, 0.5],
            d,
            dir: d,
        };
        // Tiles of 4 × (N / 4) pixels, eight across.
        fn tile<const N: usize>(p: usize, ray: &impl Fn(usize, usize) -> IndexRay) -> Packet<N> {
            let h = N / 4;
            Packet {
                rays: std::array::from_fn(|j| ray(p % 8 * 4 + j % 4, p / 8 * h + j / 4)),
                k0: [0; N],
                k1: [MEASURE_SAMPLES; N],
                acc: [[0.0; 4]; N],
            }
        }
        let packets16 = (0..MEASURE_PACKETS).map(|p| tile(p, &ray)).collect();
        let packets8 = (0..2 * MEASURE_PACKETS).map(|p| tile(p, &ray)).collect();
        Synthetic {
            v,
            rgba,
            leap,
            packets16,
            packets8,
        }
    }

    /// Marches every packet of sixteen (`sixteen`) or of eight with gathers or without;
    /// the pixels as they end, and the stats summed.
    fn march(&self, sixteen: bool, gather: bool) -> (Vec<[f32; 4]>, PacketStats) {
        let n = MEASURE_N;
        let tri = TrilinearSampler::new(&self.v, [n; 3]);
        let cells = (n - 1).div_ceil(CELL) as i32;
        let tab = PacketTables {
            leap: &self.leap,
            cells: [cells; 3],
            sign: [0; 3],
        };
        let p = MarchParams {
            cls: ClassifierView {
                lo: 0.0,
                scale: BIN_MAX / 1024.0,
                rgba: &self.rgba,
            },
            step: 1.0,
            ert: 2.0,
            shade: None,
            avx2: true,
            avx512: sixteen,
            scalar: false,
            prefetch: false,
            gather,
        };
        let mut px = Vec::new();
        let mut sum = PacketStats::default();
        let mut add = |st: PacketStats| {
            sum.samples += st.samples;
            sum.skipped += st.skipped;
            sum.steps += st.steps;
        };
        if sixteen {
            for pk in &self.packets16 {
                let mut pk = pk.clone();
                // SAFETY: the callers checked that the loop runs on this CPU; the table is
                // this volume's, padded; every ray's samples stay inside the volume.
                add(std::hint::black_box(unsafe {
                    march16::<i16, false>(&p, &tri, &tab, &mut pk)
                }));
                px.extend_from_slice(&pk.acc);
            }
        } else {
            for pk in &self.packets8 {
                let mut pk = pk.clone();
                // SAFETY: as above; these rays are oblique (as `packet16::oblique` tells).
                add(std::hint::black_box(unsafe {
                    march8::<i16, false, true, false>(&p, &tri, &tab, &mut pk)
                }));
                px.extend_from_slice(&pk.acc);
            }
        }
        (px, sum)
    }
}

/// The least time, over [`MEASURE_ROUNDS`] interleaved timings each, that the packet loop
/// of sixteen lanes (`sixteen`) or of eight takes to march the packets of [`Synthetic`]
/// (oblique rays, none terminating), loading lane by lane and by gathers (a few
/// milliseconds in all). Timing the loads alone would not do: they cost about the same on
/// their own, and what the gathers save in the loop is the inserts and extracts that
/// compete with its other shuffles, and the colour of steps whose samples are all
/// transparent. Only where that loop runs.
fn measure(sixteen: bool) -> (Duration, Duration) {
    let syn = Synthetic::new();
    let mut best = [Duration::MAX; 2];
    for _ in 0..MEASURE_ROUNDS {
        for (g, b) in best.iter_mut().enumerate() {
            let start = Instant::now();
            std::hint::black_box(syn.march(sixteen, g == 1));
            *b = (*b).min(start.elapsed());
        }
    }
    (best[0], best[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The loops that run on this CPU, as `sixteen` flags, printing `skipped:` for the others.
    fn loops() -> Vec<bool> {
        [true, false]
            .into_iter()
            .filter(|&sixteen| {
                let runs = if sixteen {
                    super::super::packet16::available()
                } else {
                    super::super::avx2::available()
                };
                if !runs {
                    println!(
                        "skipped: this CPU does not run the packet loop (sixteen lanes: {sixteen})"
                    );
                }
                runs
            })
            .collect()
    }

    #[test]
    fn the_measurement_marches_as_frames_do() {
        for sixteen in loops() {
            let syn = Synthetic::new();
            let (lanes, st) = syn.march(sixteen, false);
            let (gathers, st_g) = syn.march(sixteen, true);
            // Both forms give the same pixels and take the same steps.
            assert_eq!(lanes, gathers, "sixteen {sixteen}");
            assert_eq!(
                (st.samples, st.skipped, st.steps),
                (st_g.samples, st_g.skipped, st_g.steps)
            );
            // Every ray of the 32 × 16 pixels, whichever the packets.
            assert_eq!(lanes.len(), 512);
            // Empty cells are leapt over: a fair share of the samples is skipped.
            let all = (st.samples + st.skipped) as f64;
            let skipped = st.skipped as f64 / all;
            assert!((0.2..0.8).contains(&skipped), "skipped {skipped}");
            // Of the samples taken, some are transparent: each opaque one composites an
            // opacity of 0.05, so a ray's opacity is 1 − 0.95^opaque.
            let opaque: f64 = lanes
                .iter()
                .map(|px| f64::from(1.0 - px[3]).ln() / 0.95f64.ln())
                .sum();
            let opaque = opaque / st.samples as f64;
            assert!((0.3..0.9).contains(&opaque), "opaque {opaque}");
        }
    }

    #[test]
    fn both_loops_march_the_same_rays_to_the_same_pixels() {
        let l = loops();
        if l.len() < 2 {
            println!("skipped: this CPU does not run both packet loops");
            return;
        }
        // The packets of sixteen and of eight cover the same pixels in another order:
        // each pixel's colour, bit for bit, from either loop.
        let syn = Synthetic::new();
        let (a, _) = syn.march(true, false);
        let (b, _) = syn.march(false, false);
        let key = |v: Vec<[f32; 4]>| {
            let mut k: Vec<[u32; 4]> = v.iter().map(|p| p.map(f32::to_bits)).collect();
            k.sort_unstable();
            k
        };
        assert_eq!(key(a), key(b));
    }

    #[test]
    fn the_measurement_times_both_forms() {
        for sixteen in loops() {
            let (lanes, gathers) = measure(sixteen);
            println!("sixteen {sixteen}: lanes {lanes:?} gathers {gathers:?}");
            for t in [lanes, gathers] {
                assert!(t > Duration::ZERO && t < Duration::from_secs(1), "{t:?}");
            }
        }
    }
}
