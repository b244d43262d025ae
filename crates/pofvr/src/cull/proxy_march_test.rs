//! The two-level march against the cell-by-cell one it replaces.

use super::proxy_march::{Extinction, BLOCK};
use crate::render::IndexRay;

/// The cell-by-cell march (the proxy's before the blocks): where `ray`'s optical depth
/// through `ext` (cells of `edge` voxels, `n` per axis) reaches `depth`.
fn reference(ext: &[f32], n: [usize; 3], edge: usize, ray: &IndexRay, depth: f32) -> f32 {
    let hi = n.map(|c| (c * edge) as f32);
    let (mut t0, mut t1) = (0f32, f32::INFINITY);
    for ((&o, &d), &hi) in ray.o.iter().zip(&ray.d).zip(&hi) {
        if d == 0.0 {
            if o < 0.0 || o >= hi {
                return f32::INFINITY;
            }
            continue;
        }
        let (ta, tb) = (-o / d, (hi - o) / d);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    if t0 >= t1 {
        return f32::INFINITY;
    }
    let e = edge as f32;
    let mut cell: [i64; 3] = std::array::from_fn(|a| {
        let x = ((ray.o[a] + (t0 + (t1 - t0) * 1e-6) * ray.d[a]) / e).floor() as i64;
        x.clamp(0, n[a] as i64 - 1)
    });
    let step: [i64; 3] =
        std::array::from_fn(|a| ray.d[a].signum() as i64 * i64::from(ray.d[a] != 0.0));
    let next = |a: usize, c: i64| {
        if step[a] == 0 {
            return f32::INFINITY;
        }
        ((if step[a] > 0 { c + 1 } else { c }) as f32 * e - ray.o[a]) / ray.d[a]
    };
    let mut t_next: [f32; 3] = std::array::from_fn(|a| next(a, cell[a]));
    let (mut t, mut acc) = (t0, 0f32);
    loop {
        let i = (cell[2] as usize * n[1] + cell[1] as usize) * n[0] + cell[0] as usize;
        let a = (0..3)
            .min_by(|&x, &y| t_next[x].total_cmp(&t_next[y]))
            .unwrap();
        let out = t_next[a].min(t1);
        let add = ext[i] * (out - t).max(0.0);
        if acc + add >= depth && ext[i] > 0.0 {
            return t + (depth - acc) / ext[i];
        }
        acc += add;
        t = out;
        if t >= t1 {
            return f32::INFINITY;
        }
        cell[a] += step[a];
        if cell[a] < 0 || cell[a] >= n[a] as i64 {
            return f32::INFINITY;
        }
        t_next[a] = next(a, cell[a]);
    }
}

/// A deterministic pseudo-random number in [0, 1) from `k` (splitmix64).
fn unit(k: u64) -> f32 {
    let mut z = k.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 40) as f32 / (1u64 << 24) as f32
}

#[test]
fn the_two_level_march_ends_rays_where_the_cell_by_cell_march_does() {
    // Counts that are no multiple of the block, so edge blocks are cut short; a body of
    // tissue (some cells clear) inside air, so rays cross transparent blocks first.
    let n = [37usize, 23, 19];
    let c = [18.5f32, 11.5, 9.5];
    let ext: Vec<f32> = (0..n.iter().product::<usize>())
        .map(|i| {
            let p = [i % n[0], (i / n[0]) % n[1], i / (n[0] * n[1])];
            let r2: f32 = (0..3)
                .map(|a| ((p[a] as f32 + 0.5 - c[a]) / c[a]).powi(2))
                .sum();
            let u = unit(i as u64);
            if r2 > 0.6 || u < 0.3 {
                0.0
            } else {
                u * 0.2
            }
        })
        .collect();
    let two = Extinction::new(ext.clone(), n);
    assert!(
        n.map(|x| x.div_ceil(BLOCK)).iter().product::<usize>() > 8,
        "several blocks"
    );
    let (mut ended, mut compared) = (0, 0);
    for edge in [2usize, 4] {
        let size = n.map(|x| (x * edge) as f32);
        for k in 0..4000u64 {
            // From a point outside towards a point inside (some rays miss the body).
            let to: [f32; 3] = std::array::from_fn(|a| unit(k * 7 + a as u64) * size[a]);
            let dir: [f32; 3] = std::array::from_fn(|a| unit(k * 7 + 3 + a as u64) - 0.5);
            let len = dir.iter().map(|d| d * d).sum::<f32>().sqrt().max(1e-3);
            let mut d = dir.map(|x| x / len);
            if k % 10 == 0 {
                d[(k / 10 % 3) as usize] = 0.0; // rays in an axis plane
            }
            let o: [f32; 3] = std::array::from_fn(|a| to[a] - d[a] * 3.0 * size[0].max(size[1]));
            let ray = IndexRay { o, d, dir: d };
            let depth = 0.05 + unit(k * 7 + 6) * 3.0;
            let want = reference(&ext, n, edge, &ray, depth);
            let got = two.termination(edge, &ray, depth);
            compared += 1;
            if want.is_infinite() {
                assert!(got.is_infinite(), "edge {edge} ray {k}: {got}, want none");
                continue;
            }
            ended += 1;
            assert!(
                (got - want).abs() <= 1e-4 * want.abs().max(1.0),
                "edge {edge} ray {k}: {got}, want {want}"
            );
        }
    }
    // Both outcomes occur, so the comparison tests both.
    assert!(
        ended > compared / 10 && ended < compared,
        "{ended} of {compared}"
    );
}

#[test]
fn a_block_is_as_opaque_as_its_most_opaque_cell() {
    let n = [2 * BLOCK + 1, BLOCK, 1];
    let mut ext = vec![0f32; n.iter().product()];
    ext[BLOCK + 1] = 0.5; // in the second block along x
    let e = Extinction::new(ext, n);
    // Along x through the row of cells: the first block is skipped, the ray ends in
    // cell BLOCK + 1 (edge 2: from x = 2·BLOCK + 2), after depth 0.25 at 0.5 per unit.
    let ray = IndexRay {
        o: [-3.0, 0.5, 0.5],
        d: [1.0, 0.0, 0.0],
        dir: [1.0, 0.0, 0.0],
    };
    let t = e.termination(2, &ray, 0.25);
    let want = 3.0 + (2 * BLOCK + 2) as f32 + 0.5;
    assert!((t - want).abs() < 1e-4, "{t}, want {want}");
    // A row of air only: the ray never ends.
    let ray = IndexRay {
        o: [-3.0, 2.5, 0.5],
        ..ray
    };
    assert!(e.termination(2, &ray, 0.25).is_infinite());
}
