//! The chunk-aligned deal: one owner per chunk, contiguous runs along the chunk curve,
//! balanced by weight, and every brick dealt once.

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::chunks::chunk_shape_for;
use super::*;

/// The chunk (coordinates) brick `id` of a grid of `counts` starts in.
fn chunk_of(id: BrickId, counts: [usize; 3], brick: usize, chunk: [usize; 3]) -> [usize; 3] {
    let i = id.index();
    let c = [
        i % counts[0],
        (i / counts[0]) % counts[1],
        i / (counts[0] * counts[1]),
    ];
    std::array::from_fn(|a| c[a] * brick / chunk[a])
}

#[test]
fn a_chunks_bricks_have_one_owner_in_contiguous_runs_balanced_by_weight() {
    let mut rng = StdRng::seed_from_u64(0xc4c5);
    for _ in 0..200 {
        let counts = [0; 3].map(|_: u8| rng.gen_range(1..=14));
        let brick = rng.gen_range(2..=16);
        // Aligned chunks (a multiple of the brick) and unaligned ones.
        let chunk = [0; 3].map(|_: u8| {
            if rng.gen_bool(0.5) {
                brick * rng.gen_range(1..=4)
            } else {
                rng.gen_range(3..=50)
            }
        });
        let ranks = rng.gen_range(1..=9);
        let curve = if rng.gen_bool(0.5) {
            Curve::Hilbert
        } else {
            Curve::Z
        };
        let p = rng.gen_range(0.0..1.0);
        let n: usize = counts.iter().product();
        let weight: Vec<u64> = (0..n).map(|_| u64::from(rng.gen_bool(p))).collect();
        let a = BrickAssignment::by_chunks(counts, brick, chunk, curve, ranks, &|id| {
            weight[id.index()]
        })
        .unwrap();
        let what = format!("{counts:?} bricks of {brick}, chunks {chunk:?}, {ranks} ranks");
        assert_eq!(a.deal(), Deal::Chunks);
        assert_eq!((a.len(), a.ranks(), a.replicas()), (n, ranks, 1));
        // Every brick once, each rank's list in the curve's order over the bricks.
        let order = SfcOrder::new(counts, curve).unwrap();
        let mut seen = vec![false; n];
        for r in 0..ranks {
            let rank = Rank(r as u32);
            let pos: Vec<usize> = a
                .of(rank)
                .iter()
                .map(|b| order.bricks().iter().position(|x| x == b).unwrap())
                .collect();
            assert!(pos.windows(2).all(|w| w[0] < w[1]), "{what}");
            for b in a.of(rank) {
                assert!(!std::mem::replace(&mut seen[b.index()], true), "{what}");
                assert_eq!(a.owner(*b), Some(rank), "{what}");
            }
        }
        assert!(seen.iter().all(|s| *s), "{what}: a brick was not dealt");
        // One owner per chunk, and owners never decrease along the chunk curve.
        let mut by_chunk = std::collections::HashMap::new();
        let mut chunk_w = std::collections::HashMap::new();
        for (i, w) in weight.iter().enumerate() {
            let id = BrickId(i as u32);
            let k = chunk_of(id, counts, brick, chunk);
            let o = a.owner(id).unwrap();
            assert_eq!(
                *by_chunk.entry(k).or_insert(o),
                o,
                "{what}: chunk {k:?} split"
            );
            *chunk_w.entry(k).or_insert(0u64) += w;
        }
        let chunk_counts: [usize; 3] =
            std::array::from_fn(|a| (counts[a] - 1) * brick / chunk[a] + 1);
        let chunks = SfcOrder::new(chunk_counts, curve).unwrap();
        let coords = |i: usize| {
            [
                i % chunk_counts[0],
                (i / chunk_counts[0]) % chunk_counts[1],
                i / (chunk_counts[0] * chunk_counts[1]),
            ]
        };
        // (A chunk smaller than a brick may have no brick starting in it.)
        let owners: Vec<Rank> = chunks
            .bricks()
            .iter()
            .filter_map(|k| by_chunk.get(&coords(k.index())).copied())
            .collect();
        assert!(
            owners.windows(2).all(|w| w[0] <= w[1]),
            "{what}: {owners:?}"
        );
        // Each run's weight is within one chunk's weight of the even share.
        let total: u64 = weight.iter().sum();
        let heaviest = chunk_w.values().copied().max().unwrap_or(0);
        for r in 0..ranks {
            let w: u64 = a.of(Rank(r as u32)).iter().map(|b| weight[b.index()]).sum();
            let share = total as f64 / ranks as f64;
            assert!(
                (w as f64 - share).abs() <= heaviest as f64,
                "{what}: rank {r} weighs {w}, share {share:.1}, heaviest chunk {heaviest}"
            );
        }
    }
}

#[test]
fn without_weight_the_runs_hold_equal_numbers_of_chunks() {
    // 8×8×8 bricks of 16 in 64³ chunks: 2×2×2 chunks of 64 bricks each.
    for ranks in [1, 2, 4, 8] {
        let a = BrickAssignment::by_chunks([8, 8, 8], 16, [64; 3], Curve::Hilbert, ranks, &|_| 0)
            .unwrap();
        for r in 0..ranks {
            assert_eq!(a.of(Rank(r as u32)).len(), 512 / ranks, "{ranks} ranks");
        }
    }
    // More ranks than chunks: some runs are empty, none is split.
    let a = BrickAssignment::by_chunks([8, 8, 8], 16, [64; 3], Curve::Hilbert, 11, &|_| 1).unwrap();
    let sizes: Vec<usize> = (0..11).map(|r| a.of(Rank(r)).len()).collect();
    assert!(sizes.iter().all(|s| *s == 0 || *s == 64), "{sizes:?}");
    assert_eq!(sizes.iter().sum::<usize>(), 512);
    assert!(matches!(
        BrickAssignment::by_chunks([2, 2, 2], 16, [64; 3], Curve::Z, 0, &|_| 1),
        Err(DistributeError::BadRanks(0))
    ));
    // Unusable counts and sizes are errors or degenerate deals, never a panic.
    assert!(matches!(
        BrickAssignment::by_chunks([0, 2, 2], 16, [64; 3], Curve::Z, 2, &|_| 1),
        Err(DistributeError::BadCounts { .. })
    ));
    let huge = BrickAssignment::by_chunks([3, 2, 2], usize::MAX, [0; 3], Curve::Z, 2, &|_| 1);
    assert!(matches!(huge, Err(DistributeError::BadCounts { .. })));
    let flat = BrickAssignment::by_chunks([3, 2, 2], 8, [0; 3], Curve::Z, 2, &|_| 1).unwrap();
    assert_eq!(flat.len(), 12);
}

#[test]
fn deal_names_parse_and_a_volume_without_chunks_is_dealt_along_the_curve() {
    for d in [Deal::Auto, Deal::Curve, Deal::Chunks] {
        assert_eq!(d.to_string().parse::<Deal>().unwrap(), d);
    }
    assert_eq!("CHUNKS".parse::<Deal>().unwrap(), Deal::Chunks);
    let e = "bricks".parse::<Deal>().unwrap_err().to_string();
    assert!(e.contains("bricks") && e.contains("chunks"), "{e}");
    let v = crate::volume::phantom::Phantom::SheppLogan.generate(24);
    assert_eq!(chunk_shape_for(&v, 8, Deal::Auto).unwrap(), None);
    assert_eq!(chunk_shape_for(&v, 8, Deal::Curve).unwrap(), None);
    let e = chunk_shape_for(&v, 8, Deal::Chunks)
        .unwrap_err()
        .to_string();
    assert!(e.contains(v.source()) && e.contains("chunk"), "{e}");
}
