//! The operator interface between `formfactor` (which builds operators) and `solver`.

use crate::SolveError;

/// The scattering operator `K` of `g = E + K g`; for the zonal method `K = diag(a) · F`.
///
/// Implementations must be deterministic and thread-safe (`apply` may use rayon inside).
pub trait TransportOperator: Sync {
    /// Number of unknowns.
    fn len(&self) -> usize;

    fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// `y = K x`. `x` and `y` have length [`len`](Self::len); `y` is overwritten.
    fn apply(&self, x: &[f64], y: &mut [f64]);

    /// Row access for Gauss–Seidel and SOR, when the operator has explicit rows.
    fn rows(&self) -> Option<&dyn RowAccess> {
        None
    }

    /// One in-place Gauss–Seidel sweep `g ← (1−ω) g + ω (E + K g)` in the operator's own
    /// natural order (for operators without explicit rows, such as transport sweeps).
    /// Returns `false` if the operator does not support it; the default uses [`rows`](Self::rows).
    fn sweep_in_place(&self, g: &mut [f64], source: &[f64], omega: f64) -> bool {
        let Some(rows) = self.rows() else {
            return false;
        };
        for i in 0..g.len() {
            let kg = rows.row_dot(i, g);
            g[i] = (1.0 - omega) * g[i] + omega * (source[i] + kg);
        }
        true
    }

    /// Positive weights `w` (length [`len`](Self::len)) such that `diag(w) · K` is symmetric,
    /// when the operator has one. The zonal operator `K = diag(a) F` has `w_i = 1 / (a_i σt_i)`
    /// by reciprocity (`F_ij / σt_i = F_ji / σt_j`). Enables conjugate gradients.
    fn symmetrizer(&self) -> Option<&[f64]> {
        None
    }

    /// Aggregates for a coarse-grid correction: `aggregates[i]` is the coarse unknown that fine
    /// unknown `i` belongs to (ids `0..n_coarse`, every id used). Operators with geometry should
    /// give spatially compact groups (e.g. 8×8×8 blocks of cells, or octree clusters); without
    /// them the solver falls back to contiguous blocks of unknowns.
    fn coarse_aggregates(&self) -> Option<&[u32]> {
        None
    }

    /// The Galerkin coarse operator `Pᵀ W K P` for the given aggregates (piecewise-constant
    /// prolongation `P`, `W = diag(row_weights)` or the identity), dense and row-major,
    /// `n_coarse × n_coarse`: entry `(c, d)` is the sum of `w_i K_ij` over `i ∈ c`, `j ∈ d`.
    /// Conjugate-gradient preconditioners pass the [`symmetrizer`](Self::symmetrizer) as
    /// `row_weights`, so the coarse matrix is symmetric. Operators that can form it cheaply
    /// (e.g. a hierarchy that already holds cluster-to-cluster links) override this; by default
    /// the solver builds it from [`RowAccess::for_each_in_row`] or, failing that, from one
    /// `apply` per aggregate.
    fn coarse_operator(
        &self,
        aggregates: &[u32],
        n_coarse: usize,
        row_weights: Option<&[f64]>,
    ) -> Option<Vec<f64>> {
        let _ = (aggregates, n_coarse, row_weights);
        None
    }

    /// The operator's diffusion approximation (needs geometry), for `dsa-cg`.
    fn diffusion(&self) -> Option<Diffusion> {
        None
    }
}

/// A diffusion approximation of the transport problem, for diffusion-synthetic acceleration:
/// per unknown `σt` and `σs` (both 0 for unknowns outside the medium) and the symmetric
/// leakage matrix `G ≈ −∇·(1/(3σt))∇` with vacuum (Marshak) boundaries, in CSR form over all
/// unknowns (rows of unknowns outside the medium are empty).
///
/// # Invariants
/// Checked by [`Diffusion::new`], the only way to build one (the fields are private):
/// - `σt` and `σs` have one value per unknown, `row_ptr` one more; `row_ptr` starts at 0,
///   never decreases and ends at the entry count, which `col` and `val` share; every column
///   names an unknown;
/// - `σt` and `σs` are finite with `0 ≤ σs ≤ σt` (the absorption `σt − σs` is ≥ 0);
/// - the entries of `G` are finite, off-diagonal ones ≤ 0 (face conductances are ≥ 0).
///
/// `G` is meant to be symmetric; that is the builder's to ensure (not checked: mirrored
/// conductances may differ by rounding).
#[derive(Clone, Debug)]
pub struct Diffusion {
    sigma_t: Vec<f64>,
    sigma_s: Vec<f64>,
    row_ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl Diffusion {
    /// Checks the [invariants](Diffusion#invariants) and builds the approximation.
    pub fn new(
        sigma_t: Vec<f64>,
        sigma_s: Vec<f64>,
        row_ptr: Vec<usize>,
        col: Vec<u32>,
        val: Vec<f64>,
    ) -> Result<Self, SolveError> {
        let n = sigma_t.len();
        let bad = |reason: String| SolveError::InvalidOperatorData {
            what: "diffusion approximation",
            reason,
        };
        if sigma_s.len() != n || row_ptr.len() != n + 1 {
            return Err(bad(format!(
                "{n} σt, {} σs and {} row pointers (expected one σs per σt and one more row \
                 pointer)",
                sigma_s.len(),
                row_ptr.len()
            )));
        }
        if row_ptr[0] != 0
            || row_ptr.windows(2).any(|w| w[1] < w[0])
            || row_ptr[n] != col.len()
            || col.len() != val.len()
        {
            return Err(bad("row pointers do not match the entries".into()));
        }
        if let Some(i) = (0..n).find(|&i| {
            let (t, s) = (sigma_t[i], sigma_s[i]);
            !(t.is_finite() && s.is_finite() && 0.0 <= s && s <= t)
        }) {
            return Err(bad(format!(
                "unknown {i} has σt = {} and σs = {} (need finite 0 ≤ σs ≤ σt)",
                sigma_t[i], sigma_s[i]
            )));
        }
        for i in 0..n {
            for p in row_ptr[i]..row_ptr[i + 1] {
                let (j, v) = (col[p] as usize, val[p]);
                if j >= n {
                    return Err(bad(format!("row {i} has column {j} out of range")));
                }
                if !v.is_finite() || (j != i && v > 0.0) {
                    return Err(bad(format!(
                        "row {i} has entry {v} in column {j} (need finite, ≤ 0 off the diagonal)"
                    )));
                }
            }
        }
        Ok(Diffusion {
            sigma_t,
            sigma_s,
            row_ptr,
            col,
            val,
        })
    }

    /// Number of unknowns.
    pub fn len(&self) -> usize {
        self.sigma_t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.sigma_t.is_empty()
    }

    /// `σt` per unknown.
    pub fn sigma_t(&self) -> &[f64] {
        &self.sigma_t
    }

    /// `σs` per unknown.
    pub fn sigma_s(&self) -> &[f64] {
        &self.sigma_s
    }

    /// CSR row pointers of `G` (`row_ptr()[i]..row_ptr()[i + 1]` index row `i`'s entries).
    pub fn row_ptr(&self) -> &[usize] {
        &self.row_ptr
    }

    /// CSR column of each entry of `G`.
    pub fn col(&self) -> &[u32] {
        &self.col
    }

    /// CSR value of each entry of `G`.
    pub fn val(&self) -> &[f64] {
        &self.val
    }

    /// The parts `(σt, σs, row_ptr, col, val)`, for building a changed approximation through
    /// [`Diffusion::new`].
    #[allow(clippy::type_complexity)] // the five arrays of `new`, in its order
    pub fn into_parts(self) -> (Vec<f64>, Vec<f64>, Vec<usize>, Vec<u32>, Vec<f64>) {
        (self.sigma_t, self.sigma_s, self.row_ptr, self.col, self.val)
    }
}

/// Explicit rows of an operator.
pub trait RowAccess: Sync {
    /// `(K x)_i`.
    fn row_dot(&self, row: usize, x: &[f64]) -> f64;

    /// Calls `visit(j, K_ij)` for every stored entry of row `i` and returns `true`, or returns
    /// `false` without calling it if the entries are not available (the default).
    fn for_each_in_row(&self, row: usize, visit: &mut dyn FnMut(usize, f64)) -> bool {
        let _ = (row, visit);
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type Parts = (Vec<f64>, Vec<f64>, Vec<usize>, Vec<u32>, Vec<f64>);
    type Change = fn(&mut Parts);

    /// Two unknowns joined by a conductance of 1, each with a vacuum face of 0.5.
    fn parts() -> Parts {
        (
            vec![1.0, 2.0],
            vec![0.5, 2.0],
            vec![0, 2, 4],
            vec![0, 1, 1, 0],
            vec![1.5, -1.0, 1.5, -1.0],
        )
    }

    fn build(change: impl FnOnce(&mut Parts)) -> Result<Diffusion, SolveError> {
        let mut p = parts();
        change(&mut p);
        Diffusion::new(p.0, p.1, p.2, p.3, p.4)
    }

    #[test]
    fn a_consistent_diffusion_is_built_and_reads_back() {
        let d = build(|_| {}).unwrap();
        assert_eq!(d.len(), 2);
        assert_eq!(d.sigma_s(), &[0.5, 2.0]);
        assert_eq!(d.row_ptr(), &[0, 2, 4]);
        assert_eq!(d.into_parts(), parts());
    }

    #[test]
    fn inconsistent_or_unphysical_data_is_refused() {
        let cases: [(&str, Change); 11] = [
            ("σs length", |p| p.1.push(0.0)),
            ("row pointers", |p| p.2[2] = 3),
            ("first pointer", |p| p.2[0] = 1),
            ("decreasing pointers", |p| p.2[1] = 5),
            ("values", |p| {
                p.4.pop();
            }),
            ("column", |p| p.3[1] = 2),
            ("negative σt", |p| p.0[0] = -1.0),
            ("σs > σt", |p| p.1[0] = 1.5),
            ("NaN σs", |p| p.1[1] = f64::NAN),
            ("infinite entry", |p| p.4[0] = f64::INFINITY),
            ("positive coupling", |p| p.4[1] = 1.0),
        ];
        for (name, change) in cases {
            let err = build(change).expect_err(name);
            assert!(
                matches!(err, SolveError::InvalidOperatorData { .. }),
                "{name}: {err}"
            );
        }
    }
}
