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
}

/// Explicit rows of an operator.
pub trait RowAccess: Sync {
    /// `(K x)_i`.
    fn row_dot(&self, row: usize, x: &[f64]) -> f64;
}
