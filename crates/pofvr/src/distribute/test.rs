use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::*;

fn seeded_rng() -> StdRng {
    StdRng::seed_from_u64(0x5fc0_4d15)
}

fn random_counts(rng: &mut StdRng) -> [usize; 3] {
    [
        rng.gen_range(1..=23),
        rng.gen_range(1..=23),
        rng.gen_range(1..=23),
    ]
}

#[test]
fn morton_round_trips() {
    let mut rng = seeded_rng();
    for _ in 0..10_000 {
        let c = [
            rng.gen_range(0..1 << 21),
            rng.gen_range(0..1 << 21),
            rng.gen_range(0..1 << 21),
        ];
        let key = morton::encode(c).unwrap();
        assert_eq!(morton::decode(key), c);
        let key: u64 = rng.gen_range(0..1 << 63);
        assert_eq!(morton::encode(morton::decode(key)), Some(key));
    }
}

#[test]
fn morton_interleaves_x_fastest() {
    assert_eq!(morton::encode([1, 0, 0]), Some(1));
    assert_eq!(morton::encode([0, 1, 0]), Some(2));
    assert_eq!(morton::encode([0, 0, 1]), Some(4));
    assert_eq!(morton::encode([3, 0, 0]), Some(0b1001));
    assert_eq!(morton::encode([1 << 21, 0, 0]), None);
}

#[test]
fn hilbert_round_trips() {
    let mut rng = seeded_rng();
    for _ in 0..10_000 {
        let bits = rng.gen_range(0..=hilbert::MAX_BITS);
        let side = 1u64 << bits;
        let c = [0; 3].map(|_: u32| rng.gen_range(0..side) as u32);
        let h = hilbert::index(c, bits).unwrap();
        assert!(h < 1 << (3 * bits), "{c:?} bits {bits}: {h}");
        assert_eq!(hilbert::coords(h, bits), Some(c), "bits {bits}");
        let h = rng.gen_range(0..1u64 << (3 * bits));
        assert_eq!(
            hilbert::index(hilbert::coords(h, bits).unwrap(), bits),
            Some(h)
        );
    }
}

#[test]
fn hilbert_rejects_out_of_cube_input() {
    assert_eq!(hilbert::index([4, 0, 0], 2), None);
    assert_eq!(hilbert::index([0; 3], 22), None);
    assert_eq!(hilbert::coords(64, 2), None);
    assert_eq!(
        hilbert::coords(63, 2).map(|c| c.iter().all(|&v| v < 4)),
        Some(true)
    );
}

#[test]
fn hilbert_steps_are_face_adjacent_in_power_of_two_cubes() {
    for bits in 1..=5 {
        let mut prev = hilbert::coords(0, bits).unwrap();
        assert_eq!(prev, [0; 3], "the curve starts at the origin");
        for h in 1..1u64 << (3 * bits) {
            let c = hilbert::coords(h, bits).unwrap();
            let step: u32 = (0..3).map(|a| c[a].abs_diff(prev[a])).sum();
            assert_eq!(step, 1, "bits {bits}: {prev:?} -> {c:?} at {h}");
            prev = c;
        }
    }
}

#[test]
fn hilbert_order_of_a_power_of_two_cube_is_face_adjacent() {
    let order = SfcOrder::new([8, 8, 8], Curve::Hilbert).unwrap();
    let coords = |b: BrickId| {
        let i = b.index();
        [i % 8, (i / 8) % 8, i / 64]
    };
    for w in order.bricks().windows(2) {
        let (a, b) = (coords(w[0]), coords(w[1]));
        let step: usize = (0..3).map(|k| a[k].abs_diff(b[k])).sum();
        assert_eq!(step, 1, "{a:?} -> {b:?}");
    }
}

fn assert_permutation(order: &SfcOrder) {
    let n = order.counts().iter().product::<usize>();
    assert_eq!(order.len(), n);
    let mut seen = vec![false; n];
    for b in order.bricks() {
        assert!(
            !std::mem::replace(&mut seen[b.index()], true),
            "{b:?} twice in {:?}",
            order.counts()
        );
    }
}

#[test]
fn orders_are_bijections_for_non_power_of_two_shapes() {
    let mut rng = seeded_rng();
    for _ in 0..200 {
        let counts = random_counts(&mut rng);
        for curve in [Curve::Hilbert, Curve::Z] {
            assert_permutation(&SfcOrder::new(counts, curve).unwrap());
        }
    }
    for counts in [
        [1, 1, 1],
        [1, 1, 300],
        [300, 1, 1],
        [5, 1, 9],
        [32, 32, 108],
    ] {
        for curve in [Curve::Hilbert, Curve::Z] {
            assert_permutation(&SfcOrder::new(counts, curve).unwrap());
        }
    }
}

#[test]
fn orders_follow_the_curve_keys_on_the_enclosing_cube() {
    let counts = [3, 5, 2];
    let id = |c: [u32; 3]| BrickId(c[0] + 3 * (c[1] + 5 * c[2]));
    let inside = |c: [u32; 3]| c[0] < 3 && c[1] < 5 && c[2] < 2;
    let z: Vec<BrickId> = (0..512)
        .map(morton::decode)
        .filter(|&c| inside(c))
        .map(id)
        .collect();
    assert_eq!(
        SfcOrder::new(counts, Curve::Z).unwrap().bricks(),
        z.as_slice()
    );
    let h: Vec<BrickId> = (0..512)
        .map(|h| hilbert::coords(h, 3).unwrap())
        .filter(|&c| inside(c))
        .map(id)
        .collect();
    assert_eq!(
        SfcOrder::new(counts, Curve::Hilbert).unwrap().bricks(),
        h.as_slice()
    );
}

#[test]
fn bad_counts_and_ranks_are_errors() {
    assert!(matches!(
        SfcOrder::new([0, 4, 4], Curve::Z),
        Err(DistributeError::BadCounts { .. })
    ));
    assert!(matches!(
        SfcOrder::new([1 << 22, 1, 1], Curve::Hilbert),
        Err(DistributeError::BadCounts { .. })
    ));
    assert!(matches!(
        SfcOrder::new([1 << 21, 1 << 21, 2], Curve::Hilbert),
        Err(DistributeError::BadCounts { .. })
    ));
    assert!(matches!(
        BrickAssignment::new([2, 2, 2], Curve::Z, 0),
        Err(DistributeError::BadRanks(0))
    ));
}

#[test]
fn curve_names_parse() {
    assert_eq!("hilbert".parse::<Curve>().unwrap(), Curve::Hilbert);
    assert_eq!("Z".parse::<Curve>().unwrap(), Curve::Z);
    let err = "peano".parse::<Curve>().unwrap_err().to_string();
    assert!(err.contains("peano") && err.contains("hilbert"), "{err}");
    assert_eq!(
        Curve::Hilbert.to_string().parse::<Curve>().unwrap(),
        Curve::Hilbert
    );
}

#[test]
fn assignment_partitions_bricks_evenly() {
    let mut rng = seeded_rng();
    for _ in 0..100 {
        let counts = random_counts(&mut rng);
        let ranks = rng.gen_range(1..=40);
        for curve in [Curve::Hilbert, Curve::Z] {
            let a = BrickAssignment::new(counts, curve, ranks).unwrap();
            let order = SfcOrder::new(counts, curve).unwrap();
            assert_eq!(a.ranks(), ranks);
            let n = order.len();
            let mut owner_seen = vec![None; n];
            let sizes: Vec<usize> = (0..ranks)
                .map(|r| {
                    let rank = Rank(r as u32);
                    for &b in a.of(rank) {
                        assert_eq!(
                            owner_seen[b.index()].replace(rank),
                            None,
                            "{b:?} dealt twice"
                        );
                        assert_eq!(a.owner(b), Some(rank));
                    }
                    a.of(rank).len()
                })
                .collect();
            assert!(
                owner_seen.iter().all(Option::is_some),
                "a brick was not dealt"
            );
            let (mn, mx) = (sizes.iter().min().unwrap(), sizes.iter().max().unwrap());
            assert!(mx - mn <= 1, "{counts:?} over {ranks}: sizes {sizes:?}");
            // Round-robin along the curve: each rank's list keeps the curve order.
            assert_eq!(a.of(Rank(0)).first(), order.bricks().first());
        }
    }
}

#[test]
fn assignment_answers_unknown_ids_and_ranks_without_panicking() {
    let a = BrickAssignment::new([2, 3, 1], Curve::Hilbert, 4).unwrap();
    assert_eq!(a.owner(BrickId(6)), None);
    assert!(a.of(Rank(4)).is_empty());
    assert_eq!(a.len(), 6);
}

#[test]
fn a_compact_region_is_spread_evenly_over_ranks() {
    // The paper's argument for SFC distribution: the visible bricks of a view form compact
    // regions, and dealing along a curve gives each rank about the same share of them.
    let counts = [24, 20, 28];
    let inside = |c: [usize; 3]| {
        let d: f64 = (0..3).map(|a| (c[a] as f64 - 10.0).powi(2)).sum();
        d < 64.0
    };
    for curve in [Curve::Hilbert, Curve::Z] {
        for ranks in [2, 8, 32] {
            let a = BrickAssignment::new(counts, curve, ranks).unwrap();
            let per_rank: Vec<usize> = (0..ranks)
                .map(|r| {
                    a.of(Rank(u32::try_from(r).unwrap()))
                        .iter()
                        .filter(|b| {
                            let i = b.index();
                            inside([i % 24, (i / 24) % 20, i / 480])
                        })
                        .count()
                })
                .collect();
            let total: usize = per_rank.iter().sum();
            let max = *per_rank.iter().max().unwrap() as f64;
            let balance = max / (total as f64 / ranks as f64);
            // Hilbert keeps the busiest rank within 15 % of the mean; Z jumps more, so cuts a
            // region into more runs.
            let limit = if curve == Curve::Hilbert { 1.15 } else { 1.25 };
            assert!(
                balance <= limit,
                "{curve} at {ranks} ranks: {per_rank:?} (max/mean {balance:.3})"
            );
        }
    }
}

#[test]
fn each_class_of_bricks_is_dealt_evenly_apart_from_the_others() {
    let mut rng = seeded_rng();
    for _ in 0..100 {
        let counts = random_counts(&mut rng);
        let ranks = rng.gen_range(1..=40);
        let order = SfcOrder::new(counts, Curve::Hilbert).unwrap();
        // A random occupied set, with runs along the curve as real data have.
        let p = rng.gen_range(0.0..1.0);
        let classes = rng.gen_range(2..6);
        let class: Vec<usize> = (0..order.len())
            .map(|_| {
                if rng.gen_bool(p) {
                    rng.gen_range(1..classes)
                } else {
                    0
                }
            })
            .collect();
        let a =
            BrickAssignment::from_order_classes(&order, ranks, &|id| class[id.index()]).unwrap();
        let mut seen = vec![false; order.len()];
        let mut per_rank = vec![vec![0usize; classes]; ranks];
        for (r, counts) in per_rank.iter_mut().enumerate() {
            let rank = Rank(r as u32);
            let mine = a.of(rank);
            // Each rank's list keeps the curve order.
            let pos: Vec<usize> = mine
                .iter()
                .map(|b| order.bricks().iter().position(|x| x == b).unwrap())
                .collect();
            assert!(pos.windows(2).all(|w| w[0] < w[1]));
            for b in mine {
                assert!(
                    !std::mem::replace(&mut seen[b.index()], true),
                    "{b:?} dealt twice"
                );
                assert_eq!(a.owner(*b), Some(rank));
                counts[class[b.index()]] += 1;
            }
        }
        assert!(seen.iter().all(|s| *s), "a brick was not dealt");
        for c in 0..classes {
            let n: Vec<usize> = per_rank.iter().map(|r| r[c]).collect();
            let (mn, mx) = (n.iter().min().unwrap(), n.iter().max().unwrap());
            assert!(mx - mn <= 1, "class {c} over {ranks} ranks: {n:?}");
        }
    }
    // One class: the plain deal.
    let order = SfcOrder::new([5, 6, 7], Curve::Z).unwrap();
    assert_eq!(
        BrickAssignment::from_order_classes(&order, 7, &|_| 1).unwrap(),
        BrickAssignment::from_order(&order, 7).unwrap()
    );
    assert!(BrickAssignment::from_order_classes(&order, 0, &|_| 0).is_err());
}

#[test]
fn replicas_give_each_brick_distinct_owners_and_renderers_balance_a_skewed_load() {
    let counts = [9, 7, 5];
    let order = SfcOrder::new(counts, Curve::Hilbert).unwrap();
    let ranks = 6;
    let one = BrickAssignment::from_order(&order, ranks).unwrap();
    let two = one.clone().with_replicas(2).unwrap();
    assert!(one.clone().with_replicas(0).is_err());
    assert!(one.clone().with_replicas(7).is_err());
    let mut held = vec![0usize; ranks];
    for &b in order.bricks() {
        let owners: Vec<Rank> = two.owners_of(b).collect();
        assert_eq!(owners.len(), 2);
        assert_eq!(
            owners[0],
            one.owner(b).unwrap(),
            "the dealt rank comes first"
        );
        assert_ne!(owners[0], owners[1]);
        for r in owners {
            held[r.index()] += 1;
        }
    }
    for (r, h) in held.iter().enumerate() {
        let rank = Rank(r as u32);
        assert_eq!(two.held_by(rank).len(), *h);
        assert_eq!(one.held_by(rank), {
            let mut v = one.of(rank).to_vec();
            v.sort();
            v
        });
    }
    assert_eq!(held.iter().sum::<usize>(), 2 * order.len());
    // Visible: the bricks dealt to ranks 0 and 1 only, as when a view shows one corner.
    let visible: Vec<BrickId> = order
        .bricks()
        .iter()
        .copied()
        .filter(|b| one.owner(*b).unwrap().index() < 2)
        .collect();
    let cost = |b: BrickId| u64::from(b.0 % 5 + 1);
    let load = |who: &[Rank]| {
        let mut l = vec![0u64; ranks];
        for (b, r) in visible.iter().zip(who) {
            l[r.index()] += cost(*b);
        }
        l
    };
    let single = load(&one.renderers(&visible, &cost));
    let chosen = two.renderers(&visible, &cost);
    for (b, r) in visible.iter().zip(&chosen) {
        assert!(two.owners_of(*b).any(|o| o == *r), "{b:?} given to {r:?}");
    }
    assert_eq!(chosen, two.renderers(&visible, &cost), "deterministic");
    let double = load(&chosen);
    let max = |l: &[u64]| *l.iter().max().unwrap();
    assert_eq!(single.iter().sum::<u64>(), double.iter().sum::<u64>());
    // Two ranks carried everything; now four share it.
    assert!(
        max(&double) * 10 <= max(&single) * 6,
        "{single:?} -> {double:?}"
    );
}
