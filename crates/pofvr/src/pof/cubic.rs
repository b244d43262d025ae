//! The paper's cubic POF: ten coefficients of a bivariate cubic in normalised (θ, φ),
//! least-squares fitted to the cell table, then shifted down until it is ≤ every cell.
//!
//! A lookup evaluates the cubic at the *centre of the cell* the direction falls in, not at
//! the direction itself: the shift is checked exactly on those centres (with the f32
//! coefficients and the very code of the lookup), so the result is never above the cell's
//! stored minimum, which is what makes the cell value conservative in the first place.

/// Number of coefficients.
pub(crate) const COEFFS: usize = 10;

fn centre(views: [u32; 2], (i, j): (usize, usize)) -> (f64, f64) {
    let x = (i as f64 + 0.5) / f64::from(views[0]) * 2.0 - 1.0;
    let y = (j as f64 + 0.5) / f64::from(views[1]) * 2.0 - 1.0;
    (x, y)
}

fn monomials(x: f64, y: f64) -> [f64; COEFFS] {
    [
        1.0,
        x,
        y,
        x * x,
        x * y,
        y * y,
        x * x * x,
        x * x * y,
        x * y * y,
        y * y * y,
    ]
}

/// The cubic at the centre of cell `(i, j)`, clamped to [0, 1).
pub(crate) fn eval_cell(co: &[f32; COEFFS], views: [u32; 2], cell: (usize, usize)) -> f32 {
    let (x, y) = centre(views, cell);
    let m = monomials(x, y);
    let v: f64 = co.iter().zip(m).map(|(c, m)| f64::from(*c) * m).sum();
    (v as f32).clamp(0.0, super::ALPHA_MAX)
}

/// Least-squares fit, then shifted down below every cell of `table`.
pub(crate) fn fit_below(table: &[f32], views: [u32; 2]) -> [f32; COEFFS] {
    let (n, m) = (views[0] as usize, views[1] as usize);
    // Normal equations AᵀA c = Aᵀb in f64.
    let mut ata = [[0f64; COEFFS]; COEFFS];
    let mut atb = [0f64; COEFFS];
    for i in 0..n {
        for j in 0..m {
            let (x, y) = centre(views, (i, j));
            let mono = monomials(x, y);
            let b = f64::from(table[i * m + j]);
            for r in 0..COEFFS {
                atb[r] += mono[r] * b;
                for c in 0..COEFFS {
                    ata[r][c] += mono[r] * mono[c];
                }
            }
        }
    }
    let sol = solve(ata, atb).unwrap_or_else(|| {
        // A degenerate grid (1×1, say): the constant min is the best conservative fit.
        let mut c = [0f64; COEFFS];
        c[0] = table
            .iter()
            .fold(f64::INFINITY, |a, b| a.min(f64::from(*b)));
        c
    });
    let mut co: [f32; COEFFS] = sol.map(|c| c as f32);
    // Shift down with the f32 coefficients and the lookup's own evaluation, until no cell
    // exceeds its table value.
    for _ in 0..64 {
        let mut worst = 0f64;
        for i in 0..n {
            for j in 0..m {
                let (x, y) = centre(views, (i, j));
                let v: f64 = co
                    .iter()
                    .zip(monomials(x, y))
                    .map(|(c, mo)| f64::from(*c) * mo)
                    .sum();
                let over = v - f64::from(table[i * m + j]);
                // A cell at 0 is met by the clamp whatever the cubic says below it.
                if over > worst && !(table[i * m + j] <= 0.0 && v <= 0.0) {
                    worst = over;
                }
            }
        }
        if worst <= 0.0 {
            break;
        }
        co[0] = (f64::from(co[0]) - worst - 1e-7 * (1.0 + f64::from(co[0]).abs())) as f32;
    }
    co
}

/// Gaussian elimination with partial pivoting; `None` when singular.
fn solve(mut a: [[f64; COEFFS]; COEFFS], mut b: [f64; COEFFS]) -> Option<[f64; COEFFS]> {
    for col in 0..COEFFS {
        let piv = (col..COEFFS).max_by(|x, y| a[*x][col].abs().total_cmp(&a[*y][col].abs()))?;
        if a[piv][col].abs() < 1e-12 {
            return None;
        }
        a.swap(col, piv);
        b.swap(col, piv);
        for r in col + 1..COEFFS {
            let f = a[r][col] / a[col][col];
            let pivot_row = a[col];
            for (x, y) in a[r][col..].iter_mut().zip(&pivot_row[col..]) {
                *x -= f * y;
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = [0f64; COEFFS];
    for r in (0..COEFFS).rev() {
        let s: f64 = (r + 1..COEFFS).map(|c| a[r][c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    Some(x)
}
