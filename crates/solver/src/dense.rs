//! A dense matrix operator: small test systems, and a reference for other operators.

use rayon::prelude::*;

use crate::operator::{RowAccess, TransportOperator};

/// `K` stored densely, row-major, with optional symmetrizer weights and coarse aggregates.
#[derive(Clone, Debug, PartialEq)]
pub struct DenseOperator {
    n: usize,
    entries: Vec<f64>,
    symmetrizer: Option<Vec<f64>>,
    aggregates: Option<Vec<u32>>,
}

/// A dense matrix that does not fit its stated size.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("dense operator of size {n} needs {expected} entries, got {got}")]
pub struct DenseSizeError {
    pub n: usize,
    pub expected: usize,
    pub got: usize,
}

impl DenseOperator {
    /// `entries` row-major, `n × n`.
    pub fn new(n: usize, entries: Vec<f64>) -> Result<Self, DenseSizeError> {
        if entries.len() != n * n {
            return Err(DenseSizeError {
                n,
                expected: n * n,
                got: entries.len(),
            });
        }
        Ok(Self {
            n,
            entries,
            symmetrizer: None,
            aggregates: None,
        })
    }

    pub fn from_fn(n: usize, f: impl Fn(usize, usize) -> f64) -> Self {
        let entries = (0..n * n).map(|k| f(k / n, k % n)).collect();
        Self::new(n, entries).expect("size matches by construction")
    }

    /// Declares weights `w` with `diag(w) K` symmetric (not checked here; see
    /// [`symmetry_defect`](Self::symmetry_defect)).
    pub fn with_symmetrizer(mut self, w: Vec<f64>) -> Self {
        self.symmetrizer = Some(w);
        self
    }

    pub fn with_aggregates(mut self, aggregates: Vec<u32>) -> Self {
        self.aggregates = Some(aggregates);
        self
    }

    pub fn entry(&self, i: usize, j: usize) -> f64 {
        self.entries[i * self.n + j]
    }

    /// `max |w_i K_ij − w_j K_ji|` for the declared symmetrizer (`None` without one).
    pub fn symmetry_defect(&self) -> Option<f64> {
        let w = self.symmetrizer.as_ref()?;
        let n = self.n;
        let mut worst = 0.0f64;
        for i in 0..n {
            for j in 0..i {
                worst = worst.max((w[i] * self.entry(i, j) - w[j] * self.entry(j, i)).abs());
            }
        }
        Some(worst)
    }

    /// Largest column sum `max_j Σ_i K_ij` (energy bound for non-negative `K`).
    pub fn max_column_sum(&self) -> f64 {
        (0..self.n)
            .map(|j| (0..self.n).map(|i| self.entry(i, j)).sum::<f64>())
            .fold(0.0, f64::max)
    }
}

impl TransportOperator for DenseOperator {
    fn len(&self) -> usize {
        self.n
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        let n = self.n;
        y.par_iter_mut()
            .with_min_len(64)
            .enumerate()
            .for_each(|(i, yi)| *yi = dot(&self.entries[i * n..(i + 1) * n], x));
    }

    fn rows(&self) -> Option<&dyn RowAccess> {
        Some(self)
    }

    fn symmetrizer(&self) -> Option<&[f64]> {
        self.symmetrizer.as_deref()
    }

    fn coarse_aggregates(&self) -> Option<&[u32]> {
        self.aggregates.as_deref()
    }
}

impl RowAccess for DenseOperator {
    fn row_dot(&self, row: usize, x: &[f64]) -> f64 {
        dot(&self.entries[row * self.n..(row + 1) * self.n], x)
    }

    fn for_each_in_row(&self, row: usize, visit: &mut dyn FnMut(usize, f64)) -> bool {
        for (j, &v) in self.entries[row * self.n..(row + 1) * self.n]
            .iter()
            .enumerate()
        {
            if v != 0.0 {
                visit(j, v);
            }
        }
        true
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}
