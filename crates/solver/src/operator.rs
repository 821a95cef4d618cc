//! The operator interface between `formfactor` (which builds operators) and `solver`.

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
#[derive(Clone, Debug)]
pub struct Diffusion {
    pub sigma_t: Vec<f64>,
    pub sigma_s: Vec<f64>,
    pub row_ptr: Vec<usize>,
    pub col: Vec<u32>,
    pub val: Vec<f64>,
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
