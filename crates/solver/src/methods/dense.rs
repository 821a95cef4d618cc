//! The dense direct solve of the coarse levels: the two-level methods' Galerkin matrix
//! (`coarse.rs`; not symmetric when the coarse correction is unweighted) and the coarsest
//! level of the diffusion multigrid (`multigrid.rs`; symmetric positive definite). One LU with
//! partial pivoting serves both: the matrices have at most a few hundred rows, so Cholesky's
//! halved factorisation cost would not pay for a second solver.

/// Dense LU with partial pivoting, in place; `None` if numerically singular.
pub(crate) struct Lu {
    n: usize,
    a: Vec<f64>,
    perm: Vec<usize>,
}

impl Lu {
    /// Factorises the row-major `n × n` matrix `a`. `scale`: the size of the matrix's terms
    /// before cancellation (pivots below `1e-10 · scale` count as singular).
    pub(crate) fn factor(mut a: Vec<f64>, n: usize, scale: f64) -> Option<Self> {
        let mut perm: Vec<usize> = (0..n).collect();
        for k in 0..n {
            let p = (k..n)
                .max_by(|&i, &j| a[i * n + k].abs().total_cmp(&a[j * n + k].abs()))
                .expect("non-empty");
            if !(a[p * n + k].abs() > 1e-10 * scale) {
                return None;
            }
            if p != k {
                for c in 0..n {
                    a.swap(k * n + c, p * n + c);
                }
                perm.swap(k, p);
            }
            let pivot = a[k * n + k];
            for i in k + 1..n {
                let f = a[i * n + k] / pivot;
                a[i * n + k] = f;
                if f != 0.0 {
                    for c in k + 1..n {
                        a[i * n + c] -= f * a[k * n + c];
                    }
                }
            }
        }
        Some(Self { n, a, perm })
    }

    #[allow(clippy::needless_range_loop)] // triangular loops read clearer with indices
    /// Solves in place: `b` is overwritten by the solution (uses `tmp` as scratch).
    pub(crate) fn solve(&self, b: &mut [f64], tmp: &mut [f64]) {
        let n = self.n;
        for i in 0..n {
            tmp[i] = b[self.perm[i]];
        }
        for i in 0..n {
            let mut s = tmp[i];
            for c in 0..i {
                s -= self.a[i * n + c] * tmp[c];
            }
            tmp[i] = s;
        }
        for i in (0..n).rev() {
            let mut s = tmp[i];
            for c in i + 1..n {
                s -= self.a[i * n + c] * tmp[c];
            }
            tmp[i] = s / self.a[i * n + i];
        }
        b.copy_from_slice(tmp);
    }
}
