//! The angular grid of view directions a POF is tabulated over: `(θ, φ)` cells, and which
//! cells a direction, a border direction or a cone of directions falls in.

use glam::DVec3;

/// `(θ, φ)` of a unit direction: θ from +z in [0, π], φ from +x towards +y in [0, 2π).
#[must_use]
pub fn angles(dir: DVec3) -> (f64, f64) {
    let d = dir.normalize_or_zero();
    let theta = d.z.clamp(-1.0, 1.0).acos();
    let phi = d.y.atan2(d.x).rem_euclid(std::f64::consts::TAU);
    (theta, phi)
}

/// The unit direction of `(θ, φ)`.
#[must_use]
pub fn direction(theta: f64, phi: f64) -> DVec3 {
    let (st, ct) = theta.sin_cos();
    let (sp, cp) = phi.sin_cos();
    DVec3::new(st * cp, st * sp, ct)
}

pub(super) fn cell_of(views: [u32; 2], dir: DVec3) -> (usize, usize) {
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(dir);
    let i = ((theta / std::f64::consts::PI * n as f64) as usize).min(n - 1);
    let j = ((phi / std::f64::consts::TAU * m as f64) as usize).min(m - 1);
    (i, j)
}

/// Every view cell whose closure holds `dir`: one for most directions; two or four on
/// the lines between cells; a whole row at a pole. A direction within a hair (1e-9 of a
/// cell) of a line counts as on it: far below what the cells' margin covers.
pub(super) fn border_cells(views: [u32; 2], dir: DVec3) -> Vec<(usize, usize)> {
    const HAIR: f64 = 1e-9;
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(dir);
    let u = theta / std::f64::consts::PI * n as f64;
    if u <= HAIR || u >= n as f64 - HAIR {
        let i = if u <= HAIR { 0 } else { n - 1 };
        return (0..m).map(|j| (i, j)).collect();
    }
    let near = |x: f64, count: usize, wrap: bool| -> Vec<usize> {
        let k = x.round();
        let i = (x as usize).min(count - 1);
        if (x - k).abs() > HAIR {
            return vec![i];
        }
        let k = k as usize;
        if wrap {
            vec![(k + count - 1) % count, k % count]
        } else {
            vec![k - 1, k.min(count - 1)]
        }
    };
    let rows = near(u, n, false);
    let cols = near(phi / std::f64::consts::TAU * m as f64, m, true);
    let mut out: Vec<(usize, usize)> = rows
        .iter()
        .flat_map(|i| cols.iter().map(move |j| (*i, *j)))
        .collect();
    out.sort_unstable();
    out.dedup();
    out
}

/// Every view cell that directions within `half_angle` of `axis` can fall in.
pub(super) fn cone_cells(views: [u32; 2], axis: DVec3, half_angle: f64) -> Vec<(usize, usize)> {
    use std::f64::consts::{PI, TAU};
    let (n, m) = (views[0] as usize, views[1] as usize);
    let (theta, phi) = angles(axis);
    let beta = half_angle.max(0.0);
    if beta >= PI {
        return (0..n).flat_map(|i| (0..m).map(move |j| (i, j))).collect();
    }
    let (t0, t1) = ((theta - beta).max(0.0), (theta + beta).min(PI));
    let i0 = ((t0 / PI * n as f64) as usize).min(n - 1);
    let i1 = ((t1 / PI * n as f64) as usize).min(n - 1);
    // The cone's azimuth spread about its axis is asin(sin β / sin θ); a pole inside the
    // cone spreads it over every azimuth.
    let all_phi = theta - beta <= 0.0 || theta + beta >= PI || beta.sin() >= theta.sin();
    let cols: Vec<usize> = if all_phi {
        (0..m).collect()
    } else {
        let dphi = (beta.sin() / theta.sin()).asin();
        let w = TAU / m as f64;
        let j0 = ((phi - dphi) / w).floor() as i64;
        let j1 = ((phi + dphi) / w).floor() as i64;
        let span = (j1 - j0 + 1).min(m as i64);
        (0..span)
            .map(|k| (j0 + k).rem_euclid(m as i64) as usize)
            .collect()
    };
    (i0..=i1)
        .flat_map(|i| cols.iter().map(move |j| (i, *j)))
        .collect()
}
