//! How much a POF table can cull: its lookups at the centre of every view cell, over the
//! bricks that are non-empty for the weights.

use crate::brick::BrickGrid;
use crate::pof::{direction, PofMode, PofTable};
use crate::render::{SampledTf, TransferFunction};

/// The table's lookups over every non-empty brick and view cell.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct CellOpacities {
    /// Lookups taken (non-empty bricks × view cells).
    pub lookups: u64,
    /// Their mean.
    pub mean: f64,
    /// The share of them at 0.5 or above.
    pub share_at_least_half: f64,
}

/// The conservative lookups of `table` for `tf`'s weights at the centre of each of its view
/// cells, for every brick of `grid` that is non-empty for those weights.
#[must_use]
pub fn cell_opacities(table: &PofTable, grid: &BrickGrid, tf: &TransferFunction) -> CellOpacities {
    let sampled = SampledTf::new(tf, grid.value_range());
    let [rows, cols] = table.meta().views.map(|v| v as usize);
    let (mut sum, mut half, mut count) = (0f64, 0u64, 0u64);
    for id in grid
        .ids()
        .filter(|id| !sampled.is_empty(grid.range(*id), &tf.weights))
    {
        for i in 0..rows {
            for j in 0..cols {
                let d = direction(
                    (i as f64 + 0.5) / rows as f64 * std::f64::consts::PI,
                    (j as f64 + 0.5) / cols as f64 * std::f64::consts::TAU,
                );
                let o = table.opacity(id, d, &tf.weights, PofMode::Conservative);
                sum += f64::from(o);
                half += u64::from(o >= 0.5);
                count += 1;
            }
        }
    }
    CellOpacities {
        lookups: count,
        mean: sum / count.max(1) as f64,
        share_at_least_half: half as f64 / count.max(1) as f64,
    }
}

#[cfg(test)]
mod test {
    use super::*;
    use crate::pof::PofSettings;
    use crate::render::families;
    use crate::volume::phantom::Phantom;

    #[test]
    fn every_non_empty_brick_and_cell_is_looked_up_once() {
        let vol = Phantom::SheppLogan.generate(32);
        let grid = BrickGrid::from_volume(&vol, 16).unwrap();
        let mut tf = families::for_phantom(Phantom::SheppLogan);
        let sampled = SampledTf::new(&tf, grid.value_range());
        let settings = PofSettings {
            views: [3, 5],
            ..PofSettings::default()
        };
        let table = PofTable::build(&vol, &grid, &tf, &sampled, &settings, &|_, _| {}).unwrap();
        let non_empty = grid
            .ids()
            .filter(|id| !sampled.is_empty(grid.range(*id), &tf.weights))
            .count() as u64;
        let c = cell_opacities(&table, &grid, &tf);
        assert_eq!(c.lookups, non_empty * 15);
        assert!((0.0..=1.0).contains(&c.mean), "{c:?}");
        assert!((0.0..=1.0).contains(&c.share_at_least_half), "{c:?}");
        // The mean of lookups that are each at least 0.5 on that share bounds it below.
        assert!(c.mean >= 0.5 * c.share_at_least_half, "{c:?}");

        // Weights that empty every brick leave nothing to look up.
        tf.weights.iter_mut().for_each(|w| *w = 0.0);
        assert_eq!(cell_opacities(&table, &grid, &tf), CellOpacities::default());
    }
}
