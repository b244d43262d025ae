use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::direct::{KIND_FRAGMENT, TAG_FRAGMENTS};
use super::*;
use crate::comm::LocalCommunicator;

const LONG: Duration = Duration::from_secs(30);

fn seeded_rng() -> StdRng {
    StdRng::seed_from_u64(0xc0_4905)
}

fn rect(x0: u32, y0: u32, x1: u32, y1: u32) -> PixelRect {
    PixelRect { x0, y0, x1, y1 }
}

/// A premultiplied pixel, transparent about half the time.
fn random_pixel(rng: &mut StdRng) -> [f32; 4] {
    if rng.gen_bool(0.5) {
        return [0.0; 4];
    }
    let a: f32 = rng.gen_range(0.0..=1.0);
    [
        rng.gen_range(0.0..=1.0) * a,
        rng.gen_range(0.0..=1.0) * a,
        rng.gen_range(0.0..=1.0) * a,
        a,
    ]
}

/// Fragments with unique keys, inside `bounds`, many sharing depth keys.
fn random_fragments(rng: &mut StdRng, count: u32, bounds: PixelRect) -> Vec<TileFragment> {
    (0..count)
        .map(|i| {
            let w = rng.gen_range(1..=bounds.width().min(24));
            let h = rng.gen_range(1..=bounds.height().min(24));
            let x0 = rng.gen_range(bounds.x0..=bounds.x1 - w);
            let y0 = rng.gen_range(bounds.y0..=bounds.y1 - h);
            let r = rect(x0, y0, x0 + w, y0 + h);
            TileFragment {
                brick: BrickId(i),
                depth_key: rng.gen_range(-4..4),
                rect: r,
                pixels: (0..r.area()).map(|_| random_pixel(rng)).collect(),
            }
        })
        .collect()
}

fn bits(image: &Image) -> Vec<[u32; 4]> {
    image.pixels().iter().map(|p| p.map(f32::to_bits)).collect()
}

#[test]
fn layout_cuts_bounds_into_exactly_n_disjoint_tiles() {
    let mut rng = seeded_rng();
    for _ in 0..200 {
        let (width, height) = (rng.gen_range(1..80), rng.gen_range(1..80));
        let (x0, y0) = (rng.gen_range(0..width), rng.gen_range(0..height));
        let bounds = rect(
            x0,
            y0,
            rng.gen_range(x0 + 1..=width),
            rng.gen_range(y0 + 1..=height),
        );
        let n = rng.gen_range(1..=40);
        let layout = TileLayout::new(width, height, bounds, n).unwrap();
        assert_eq!((layout.len(), layout.cols() * layout.rows()), (n, n));
        let mut cover = vec![0u32; (width * height) as usize];
        for t in 0..n {
            let id = TileId(u32::try_from(t).unwrap());
            let tile = layout.tile(id).unwrap();
            assert_eq!(layout.owner(id).index(), t);
            assert_eq!(layout.tile_of(layout.owner(id)), Some(id));
            for y in tile.y0..tile.y1 {
                for x in tile.x0..tile.x1 {
                    cover[(y * width + x) as usize] += 1;
                }
            }
        }
        for y in 0..height {
            for x in 0..width {
                let inside =
                    (bounds.x0..bounds.x1).contains(&x) && (bounds.y0..bounds.y1).contains(&y);
                assert_eq!(
                    cover[(y * width + x) as usize],
                    u32::from(inside),
                    "pixel {x},{y} of {bounds:?}/{n}"
                );
            }
        }
        // tiles_overlapping agrees with brute force.
        let q = rect(
            rng.gen_range(0..width),
            rng.gen_range(0..height),
            width,
            height,
        );
        let brute: Vec<TileId> = (0..n)
            .map(|t| TileId(u32::try_from(t).unwrap()))
            .filter(|&t| layout.tile(t).unwrap().intersect(&q).is_some())
            .collect();
        assert_eq!(layout.tiles_overlapping(&q), brute);
        assert_eq!(layout.tile(TileId(u32::try_from(n).unwrap())), None);
        assert_eq!(layout.tile_of(Rank(u32::try_from(n).unwrap())), None);
    }
}

#[test]
fn layout_prefers_square_tiles() {
    let grid = |w, h, n| {
        let l = TileLayout::new(w, h, rect(0, 0, w, h), n).unwrap();
        (l.cols(), l.rows())
    };
    assert_eq!(grid(100, 100, 4), (2, 2));
    assert_eq!(grid(200, 100, 2), (2, 1));
    assert_eq!(grid(100, 200, 2), (1, 2));
    assert_eq!(grid(300, 200, 6), (3, 2));
    // A tie between 4×8 and 8×4 goes to fewer columns, whose tile rows are longer.
    assert_eq!(grid(512, 512, 32), (4, 8));
    assert_eq!(grid(100, 100, 7), (1, 7));
    // Bounds too thin for a column per rank: stack the tiles instead of leaving some empty.
    assert_eq!(grid(3, 500, 4), (1, 4));
}

#[test]
fn layout_with_more_tiles_than_pixels_has_empty_tiles() {
    let layout = TileLayout::new(10, 10, rect(4, 4, 6, 6), 7).unwrap();
    let areas: usize = (0..7).map(|t| layout.tile(TileId(t)).unwrap().area()).sum();
    assert_eq!(areas, 4);
    assert!((0..7).any(|t| layout.tile(TileId(t)).unwrap().area() == 0));
}

#[test]
fn layout_rejects_bad_input() {
    assert!(matches!(
        TileLayout::new(10, 10, rect(0, 0, 10, 10), 0),
        Err(CompositeError::BadTileCount(0))
    ));
    let err = TileLayout::new(10, 10, rect(0, 0, 11, 10), 2).unwrap_err();
    assert!(matches!(err, CompositeError::BadBounds { .. }), "{err}");
    assert!(TileLayout::new(10, 10, rect(3, 3, 3, 9), 2).is_err());
}

#[test]
fn pack_unpack_round_trip() {
    let mut rng = seeded_rng();
    let frame = rect(0, 0, 64, 64);
    for _ in 0..500 {
        let f = &random_fragments(&mut rng, 1, frame)[0];
        let clip = rect(
            rng.gen_range(0..40),
            rng.gen_range(0..40),
            rng.gen_range(40..=64),
            rng.gen_range(40..=64),
        );
        let Some(r) = f.rect.intersect(&clip) else {
            assert!(matches!(
                pack(f, clip),
                Err(CompositeError::NoOverlap { .. })
            ));
            continue;
        };
        let back = unpack(&pack(f, clip).unwrap()).unwrap();
        assert_eq!(
            (back.brick, back.depth_key, back.rect),
            (f.brick, f.depth_key, r)
        );
        for y in r.y0..r.y1 {
            for x in r.x0..r.x1 {
                let want = f.pixels[((y - f.rect.y0) * f.rect.width() + x - f.rect.x0) as usize];
                let got = back.pixels[((y - r.y0) * r.width() + x - r.x0) as usize];
                assert_eq!(
                    got.map(f32::to_bits),
                    want.map(f32::to_bits),
                    "pixel {x},{y}"
                );
            }
        }
    }
}

#[test]
fn pack_skips_transparent_runs() {
    let r = rect(10, 10, 30, 20);
    let mut f = TileFragment {
        brick: BrickId(3),
        depth_key: -2,
        rect: r,
        pixels: vec![[0.0; 4]; r.area()],
    };
    let header = pack(&f, r).unwrap().len();
    assert_eq!(header, 36, "a blank fragment is its header only");
    f.pixels[25] = [0.1, 0.2, 0.3, 0.5];
    f.pixels[26] = [0.0, 0.0, 0.0, 0.25];
    f.pixels[199] = [0.5, 0.0, 0.0, 0.5];
    let sparse = SparseTile::new(&f, r).unwrap();
    assert_eq!(sparse.stored_pixels(), 3);
    assert_eq!(sparse.encode().len(), 36 + 2 * 12 + 3 * 16);
    assert_eq!(unpack(&sparse.encode()).unwrap(), f);
}

#[test]
fn unpack_rejects_bad_bytes_without_panicking() {
    let mut rng = seeded_rng();
    let f = &random_fragments(&mut rng, 1, rect(0, 0, 20, 20))[0];
    let good = pack(f, f.rect).unwrap();
    for cut in 0..good.len() {
        let err = unpack(&good[..cut]).unwrap_err();
        assert!(
            matches!(err, CompositeError::Malformed { .. }),
            "cut at {cut}: {err}"
        );
    }
    let mut long = good.clone();
    long.push(0);
    assert!(matches!(
        unpack(&long),
        Err(CompositeError::Malformed { .. })
    ));
    let mut huge = good.clone();
    huge[24..28].copy_from_slice(&u32::MAX.to_le_bytes());
    huge[28..32].copy_from_slice(&u32::MAX.to_le_bytes());
    assert!(matches!(
        unpack(&huge),
        Err(CompositeError::TooLarge { .. })
    ));
    for _ in 0..5000 {
        let mut bad = good.clone();
        for _ in 0..rng.gen_range(1..4) {
            let at = rng.gen_range(0..bad.len());
            bad[at] = rng.gen();
        }
        // Either error or a well-formed fragment; never a panic.
        if let Ok(back) = unpack(&bad) {
            back.check().unwrap();
        }
    }
}

#[test]
fn over_is_associative() {
    let mut rng = seeded_rng();
    for _ in 0..10_000 {
        let [a, b, c] = [0; 3].map(|_| random_pixel(&mut rng));
        let (left, right) = (over(over(a, b), c), over(a, over(b, c)));
        for k in 0..4 {
            assert!(
                (left[k] - right[k]).abs() <= 1e-6,
                "{a:?} {b:?} {c:?}: {left:?} vs {right:?}"
            );
        }
    }
}

#[test]
fn composite_local_blends_front_to_back() {
    let r = rect(0, 0, 1, 1);
    let frag = |brick, depth_key, p| TileFragment {
        brick: BrickId(brick),
        depth_key,
        rect: r,
        pixels: vec![p],
    };
    let red = [0.5, 0.0, 0.0, 0.5];
    let blue = [0.0, 0.0, 1.0, 1.0];
    // Blue has the larger key, so it is behind red whatever the input order.
    let img = composite_local(&[frag(0, 7, blue), frag(1, 3, red)], 1, 1).unwrap();
    assert_eq!(img.pixel(0, 0), [0.5, 0.0, 0.5, 1.0]);
    // Equal depth keys: the smaller brick id is in front.
    let img = composite_local(&[frag(9, 3, blue), frag(2, 3, red)], 1, 1).unwrap();
    assert_eq!(img.pixel(0, 0), [0.5, 0.0, 0.5, 1.0]);
    // Pixels outside the frame are dropped, not a panic.
    let off = TileFragment {
        brick: BrickId(0),
        depth_key: 0,
        rect: rect(0, 0, 3, 3),
        pixels: vec![red; 9],
    };
    assert_eq!(composite_local(&[off], 2, 1).unwrap().pixels(), &[red, red]);
}

#[test]
fn composite_local_rejects_bad_fragments() {
    let r = rect(0, 0, 2, 2);
    let short = TileFragment {
        brick: BrickId(1),
        depth_key: 0,
        rect: r,
        pixels: vec![[0.0; 4]; 3],
    };
    let err = composite_local(&[short], 4, 4).unwrap_err();
    assert!(
        matches!(
            err,
            CompositeError::PixelCount {
                got: 3,
                expected: 4,
                ..
            }
        ),
        "{err}"
    );
    let f = TileFragment {
        brick: BrickId(1),
        depth_key: 5,
        rect: r,
        pixels: vec![[0.0; 4]; 4],
    };
    let err = composite_local(&[f.clone(), f], 4, 4).unwrap_err();
    assert!(
        matches!(
            err,
            CompositeError::DuplicateKey {
                brick: BrickId(1),
                depth_key: 5
            }
        ),
        "{err}"
    );
}

fn direct_send(
    n: usize,
    layout: &TileLayout,
    fragments: &[TileFragment],
) -> Vec<Result<Option<Image>, CompositeError>> {
    LocalCommunicator::run(n, |comm| {
        let mine: Vec<TileFragment> = fragments
            .iter()
            .skip(comm.rank().index())
            .step_by(n)
            .cloned()
            .collect();
        DirectSend::new(LONG).composite(comm, layout, mine)
    })
}

#[test]
fn direct_send_matches_composite_local_at_1_2_3_4_7_32_ranks() {
    let mut rng = seeded_rng();
    let (width, height) = (67, 45);
    let bounds = rect(5, 3, 61, 44);
    let fragments = random_fragments(&mut rng, 60, bounds);
    let reference = composite_local(&fragments, width, height).unwrap();
    assert!(reference.mean_alpha() > 0.05, "the scene is not blank");
    for n in [1, 2, 3, 4, 7, 32] {
        let layout = TileLayout::new(width, height, bounds, n).unwrap();
        let out = direct_send(n, &layout, &fragments);
        for (r, result) in out.into_iter().enumerate() {
            let image = result.unwrap_or_else(|e| panic!("{n} ranks, rank {r}: {e}"));
            if r == 0 {
                assert_eq!(bits(&image.unwrap()), bits(&reference), "{n} ranks");
            } else {
                assert!(image.is_none());
            }
        }
    }
}

#[test]
fn direct_send_is_repeatable_on_one_communicator() {
    // Ranks other than 0 finish a frame as soon as their tile is sent, so they start the
    // next frame while owners still read this one: the streams must not mix.
    let mut rng = seeded_rng();
    let bounds = rect(0, 0, 40, 30);
    let frames: Vec<Vec<TileFragment>> = (0..12)
        .map(|i| random_fragments(&mut rng, 10 + i, bounds))
        .collect();
    let layout = TileLayout::new(40, 30, bounds, 3).unwrap();
    let out = LocalCommunicator::run(3, |comm| {
        frames
            .iter()
            .map(|f| {
                let mine = f
                    .iter()
                    .skip(comm.rank().index())
                    .step_by(3)
                    .cloned()
                    .collect();
                DirectSend::new(LONG)
                    .composite(comm, &layout, mine)
                    .unwrap()
            })
            .collect::<Vec<_>>()
    });
    for (i, f) in frames.iter().enumerate() {
        let reference = composite_local(f, 40, 30).unwrap();
        assert_eq!(
            bits(out[0][i].as_ref().unwrap()),
            bits(&reference),
            "frame {i}"
        );
    }
}

#[test]
fn blank_tiles() {
    let layout = TileLayout::new(16, 8, rect(2, 2, 14, 8), 4).unwrap();
    let out = direct_send(4, &layout, &[]);
    let image = out.into_iter().next().unwrap().unwrap().unwrap();
    assert_eq!(image, Image::new(16, 8));
}

#[test]
fn direct_send_rejects_a_layout_of_the_wrong_size() {
    let layout = TileLayout::new(16, 8, rect(0, 0, 16, 8), 3).unwrap();
    let start = Instant::now();
    let out = direct_send(2, &layout, &[]);
    assert!(start.elapsed() < Duration::from_secs(10));
    for r in out {
        assert!(
            matches!(
                r,
                Err(CompositeError::LayoutRanks {
                    tiles: 3,
                    ranks: 2,
                    ..
                })
            ),
            "{r:?}"
        );
    }
}

/// Forwards to a real communicator but loses the first fragment message it sends.
struct LosesOneFragment<'a> {
    inner: &'a LocalCommunicator,
    lost: AtomicBool,
    lost_to: Mutex<Option<Rank>>,
}

impl Communicator for LosesOneFragment<'_> {
    fn rank(&self) -> Rank {
        self.inner.rank()
    }
    fn size(&self) -> usize {
        self.inner.size()
    }
    fn send(&self, to: Rank, tag: u32, bytes: Vec<u8>) -> Result<(), CommError> {
        if tag == TAG_FRAGMENTS
            && bytes.first() == Some(&KIND_FRAGMENT)
            && !self.lost.swap(true, Ordering::SeqCst)
        {
            *self.lost_to.lock().unwrap() = Some(to);
            return Ok(());
        }
        self.inner.send(to, tag, bytes)
    }
    fn recv(
        &self,
        from: Option<Rank>,
        tag: u32,
        timeout: Duration,
    ) -> Result<(Rank, Vec<u8>), CommError> {
        self.inner.recv(from, tag, timeout)
    }
    fn abort(&self, reason: &str) {
        self.inner.abort(reason);
    }
    fn bytes_sent(&self) -> u64 {
        self.inner.bytes_sent()
    }
}

#[test]
fn lost_fragment_is_reported_by_the_tile_owner() {
    let mut rng = seeded_rng();
    let bounds = rect(0, 0, 48, 48);
    let fragments = random_fragments(&mut rng, 40, bounds);
    let layout = TileLayout::new(48, 48, bounds, 4).unwrap();
    let timeout = Duration::from_millis(300);
    let start = Instant::now();
    let out = LocalCommunicator::run(4, |comm| {
        let mine: Vec<TileFragment> = fragments
            .iter()
            .skip(comm.rank().index())
            .step_by(4)
            .cloned()
            .collect();
        let compositor = DirectSend::new(timeout);
        if comm.rank() == Rank(1) {
            let lossy = LosesOneFragment {
                inner: comm,
                lost: AtomicBool::new(false),
                lost_to: Mutex::new(None),
            };
            let result = compositor.composite(&lossy, &layout, mine);
            (result, lossy.lost_to.into_inner().unwrap())
        } else {
            (compositor.composite(comm, &layout, mine), None)
        }
    });
    assert!(
        start.elapsed() < timeout + Duration::from_secs(5),
        "took {:?}",
        start.elapsed()
    );
    let owner = out[1]
        .1
        .expect("rank 1 sent at least one fragment to another owner");
    let (result, _) = &out[owner.index()];
    match result {
        Err(
            e @ CompositeError::FragmentCount {
                tile,
                rank,
                from: Rank(1),
                expected,
                got,
            },
        ) => {
            assert_eq!((tile.index(), *rank), (owner.index(), owner));
            assert_eq!(*got + 1, *expected);
            let msg = e.to_string();
            assert!(
                msg.contains(&format!("rank {owner}"))
                    && msg.contains(&format!("tile {}", owner.0)),
                "{msg}"
            );
        }
        other => panic!("owner {owner}: {other:?}"),
    }
    // Rank 0 cannot assemble the frame; other ranks may have finished their part before the
    // owner noticed.
    assert!(
        out[0].0.is_err(),
        "rank 0 returned a frame although a fragment was lost"
    );
}

#[test]
fn a_rank_with_a_bad_fragment_does_not_leave_peers_waiting() {
    let layout = TileLayout::new(16, 16, rect(0, 0, 16, 16), 3).unwrap();
    let start = Instant::now();
    let out = LocalCommunicator::run(3, |comm| {
        let mine = if comm.rank() == Rank(2) {
            vec![TileFragment {
                brick: BrickId(0),
                depth_key: 0,
                rect: rect(0, 0, 4, 4),
                pixels: vec![[0.0; 4]; 5],
            }]
        } else {
            Vec::new()
        };
        DirectSend::new(LONG).composite(comm, &layout, mine)
    });
    assert!(
        start.elapsed() < Duration::from_secs(10),
        "peers waited for the timeout"
    );
    assert!(
        matches!(out[2], Err(CompositeError::PixelCount { .. })),
        "{:?}",
        out[2]
    );
    for r in &out[..2] {
        assert!(
            matches!(
                r,
                Err(CompositeError::Comm(CommError::Aborted { by: Rank(2), .. }))
            ),
            "{r:?}"
        );
    }
}

/// Forwards to a real communicator but loses every fragment count it sends.
struct LosesCounts<'a>(&'a LocalCommunicator);

impl Communicator for LosesCounts<'_> {
    fn rank(&self) -> Rank {
        self.0.rank()
    }
    fn size(&self) -> usize {
        self.0.size()
    }
    fn send(&self, to: Rank, tag: u32, bytes: Vec<u8>) -> Result<(), CommError> {
        if tag == TAG_FRAGMENTS && bytes.first() == Some(&super::direct::KIND_COUNT) {
            return Ok(());
        }
        self.0.send(to, tag, bytes)
    }
    fn recv(
        &self,
        from: Option<Rank>,
        tag: u32,
        timeout: Duration,
    ) -> Result<(Rank, Vec<u8>), CommError> {
        self.0.recv(from, tag, timeout)
    }
    fn abort(&self, reason: &str) {
        self.0.abort(reason);
    }
    fn bytes_sent(&self) -> u64 {
        self.0.bytes_sent()
    }
}

#[test]
fn missing_fragment_count_is_reported_within_the_timeout() {
    let layout = TileLayout::new(32, 32, rect(0, 0, 32, 32), 3).unwrap();
    let timeout = Duration::from_millis(200);
    let start = Instant::now();
    let out = LocalCommunicator::run(3, |comm| {
        let compositor = DirectSend::new(timeout);
        if comm.rank() == Rank(2) {
            compositor.composite(&LosesCounts(comm), &layout, Vec::new())
        } else {
            compositor.composite(comm, &layout, Vec::new())
        }
    });
    assert!(
        start.elapsed() < timeout + Duration::from_secs(5),
        "took {:?}",
        start.elapsed()
    );
    // Owners 0 and 1 both wait for rank 2's count; whichever times out first reports it
    // and aborts the other.
    let mut reported = 0;
    for (r, result) in out[..2].iter().enumerate() {
        match result {
            Err(
                e @ CompositeError::CountMissing {
                    tile,
                    rank,
                    from: Rank(2),
                },
            ) => {
                assert_eq!((tile.index(), rank.index()), (r, r));
                assert!(e.to_string().contains("from rank 2"), "{e}");
                reported += 1;
            }
            Err(CompositeError::Comm(CommError::Aborted { .. })) => {}
            other => panic!("rank {r}: {other:?}"),
        }
    }
    assert!(reported >= 1, "{out:?}");
}
