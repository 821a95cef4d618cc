//! Test systems: seeded random zonal-like (reciprocal) and general diagonally dominant
//! operators, a large 1-D chain, an apply-only wrapper, and a direct dense solve.
#![allow(dead_code)]

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use solver::{DenseOperator, RowAccess, TransportOperator};

/// Zonal-like `K = a · diag(s) · S` with `S` symmetric non-negative, scaled so every column
/// sum of `diag(s) S` is at most `colsum`; symmetrizer `w_i = 1 / (a s_i)` (reciprocity).
pub fn reciprocal(n: usize, seed: u64, albedo: f64, colsum: f64) -> DenseOperator {
    let mut rng = Pcg64::seed_from_u64(seed);
    let s: Vec<f64> = (0..n).map(|_| rng.random_range(0.3..1.0)).collect();
    let mut sym = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            // Mostly local coupling, like form factors falling off with distance.
            let d = (i as f64 - j as f64).abs();
            let v = rng.random_range(0.2..1.0) / (1.0 + d * d);
            sym[i * n + j] = v;
            sym[j * n + i] = v;
        }
    }
    let max_col = (0..n)
        .map(|j| (0..n).map(|i| s[i] * sym[i * n + j]).sum::<f64>())
        .fold(0.0, f64::max);
    let c = colsum / max_col;
    let k = DenseOperator::from_fn(n, |i, j| albedo * s[i] * c * sym[i * n + j]);
    k.with_symmetrizer(s.iter().map(|si| 1.0 / (albedo * si)).collect())
}

/// General (non-symmetric, mixed-sign) `K` with `Σ_j |K_ij| = row_sum < 1`: `I − K` strictly
/// diagonally dominant.
pub fn dominant(n: usize, seed: u64, row_sum: f64) -> DenseOperator {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut e: Vec<f64> = (0..n * n).map(|_| rng.random_range(-1.0..1.0)).collect();
    for i in 0..n {
        let t: f64 = e[i * n..(i + 1) * n].iter().map(|v| v.abs()).sum();
        e[i * n..(i + 1) * n]
            .iter_mut()
            .for_each(|v| *v *= row_sum / t);
    }
    DenseOperator::new(n, e).unwrap()
}

pub fn random_source(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = Pcg64::seed_from_u64(seed ^ 0x5eed);
    (0..n).map(|_| rng.random_range(0.0..1.0)).collect()
}

/// `(I − K)⁻¹ E` by Gaussian elimination with partial pivoting.
pub fn direct_solve(k: &DenseOperator, e: &[f64]) -> Vec<f64> {
    let n = k.len();
    let mut a: Vec<f64> = (0..n * n)
        .map(|idx| f64::from(u8::from(idx / n == idx % n)) - k.entry(idx / n, idx % n))
        .collect();
    let mut b = e.to_vec();
    for col in 0..n {
        let p = (col..n)
            .max_by(|&x, &y| a[x * n + col].abs().total_cmp(&a[y * n + col].abs()))
            .unwrap();
        for c in 0..n {
            a.swap(col * n + c, p * n + c);
        }
        b.swap(col, p);
        for r in col + 1..n {
            let f = a[r * n + col] / a[col * n + col];
            for c in col..n {
                a[r * n + c] -= f * a[col * n + c];
            }
            b[r] -= f * b[col];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|c| a[r * n + c] * x[c]).sum();
        x[r] = (b[r] - s) / a[r * n + r];
    }
    x
}

pub fn rel_diff(a: &[f64], b: &[f64]) -> f64 {
    let d: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let m: f64 = b.iter().map(|y| y * y).sum();
    (d / m).sqrt()
}

/// 1-D chain of thick cells: `K_ij = a s_i / 3` for `|i − j| ≤ 1` (reflecting nothing at the
/// ends, so light leaks only there). Reciprocal with `w_i = 1 / (a s_i)`.
pub struct Chain {
    pub s: Vec<f64>,
    pub albedo: f64,
    weights: Vec<f64>,
    aggregates: Option<Vec<u32>>,
}

impl Chain {
    /// Interception `s_i` uniform in `[s_min, 1)`.
    pub fn new(n: usize, seed: u64, albedo: f64, s_min: f64) -> Self {
        let mut rng = Pcg64::seed_from_u64(seed);
        let s: Vec<f64> = (0..n).map(|_| rng.random_range(s_min..1.0)).collect();
        let weights = s.iter().map(|si| 1.0 / (albedo * si)).collect();
        Self {
            s,
            albedo,
            weights,
            aggregates: None,
        }
    }

    pub fn with_blocks(mut self, size: usize) -> Self {
        self.aggregates = Some((0..self.s.len()).map(|i| (i / size) as u32).collect());
        self
    }

    fn row(&self, i: usize, x: &[f64]) -> f64 {
        let n = x.len();
        let lo = i.saturating_sub(1);
        let hi = (i + 1).min(n - 1);
        let sum: f64 = x[lo..=hi].iter().sum();
        self.albedo * self.s[i] / 3.0 * sum
    }
}

impl TransportOperator for Chain {
    fn len(&self) -> usize {
        self.s.len()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        for (i, yi) in y.iter_mut().enumerate() {
            *yi = self.row(i, x);
        }
    }
    fn rows(&self) -> Option<&dyn RowAccess> {
        Some(self)
    }
    fn symmetrizer(&self) -> Option<&[f64]> {
        Some(&self.weights)
    }
    fn coarse_aggregates(&self) -> Option<&[u32]> {
        self.aggregates.as_deref()
    }
}

impl RowAccess for Chain {
    fn row_dot(&self, row: usize, x: &[f64]) -> f64 {
        self.row(row, x)
    }
    fn for_each_in_row(&self, row: usize, visit: &mut dyn FnMut(usize, f64)) -> bool {
        let n = self.s.len();
        let v = self.albedo * self.s[row] / 3.0;
        for j in row.saturating_sub(1)..=(row + 1).min(n - 1) {
            visit(j, v);
        }
        true
    }
}

/// Hides everything but `apply` (like a hierarchical operator without rows).
pub struct ApplyOnly<'a>(pub &'a dyn TransportOperator);

impl TransportOperator for ApplyOnly<'_> {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.0.apply(x, y)
    }
}
