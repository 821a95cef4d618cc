//! The two-level method: a smoother plus a Galerkin coarse-grid correction on aggregates
//! (additive coarse-mesh rebalance).
//!
//! With `P` the piecewise-constant prolongation from aggregates and restriction `Pᵀ`
//! (summation), the coarse system `Pᵀ (I − K) P e = Pᵀ r` says that, on every aggregate, what
//! is added equals what is scattered in plus the missing source: the aggregate's energy
//! balance. It removes the smooth, slowly decaying error that Jacobi and Gauss–Seidel leave
//! when the albedo approaches 1.

use super::dense::Lu;
use crate::error::SolveError;
use crate::operator::TransportOperator;
use crate::options::Smoother;
use crate::solve::{Ctx, Stop};
use crate::vecops::for_each_mut;

/// Aggregates when the operator gives none and can list its entries: contiguous blocks of
/// unknowns, about this many unknowns each (capped by [`MAX_DEFAULT_AGGREGATES`]).
pub const DEFAULT_AGGREGATE_SIZE: usize = 512;
/// Cap on the default aggregate count (the coarse matrix is dense and factorised by LU).
pub const MAX_DEFAULT_AGGREGATES: usize = 512;
/// Default aggregate count when the coarse operator must be probed with one application of
/// `K` per aggregate (the operator has neither entries nor its own coarse operator).
pub const PROBED_DEFAULT_AGGREGATES: usize = 16;

/// Contiguous blocks `0..n` split into `count` nearly equal aggregates.
pub fn contiguous_aggregates(n: usize, count: usize) -> Vec<u32> {
    let count = count.clamp(1, n.max(1));
    (0..n).map(|i| (i * count / n.max(1)) as u32).collect()
}

fn has_entries(op: &dyn TransportOperator) -> bool {
    !op.is_empty()
        && op
            .rows()
            .is_some_and(|rows| rows.for_each_in_row(0, &mut |_, _| {}))
}

fn check_aggregates(aggs: &[u32], n: usize) -> Result<usize, SolveError> {
    let bad = |reason: String| SolveError::InvalidOperatorData {
        what: "coarse aggregates",
        reason,
    };
    if aggs.len() != n {
        return Err(bad(format!("length {} for {n} unknowns", aggs.len())));
    }
    let nc = aggs.iter().max().map_or(0, |&m| m as usize + 1);
    let mut used = vec![false; nc];
    aggs.iter().for_each(|&a| used[a as usize] = true);
    if let Some(c) = used.iter().position(|u| !u) {
        return Err(bad(format!("aggregate {c} of 0..{nc} has no unknowns")));
    }
    Ok(nc)
}

/// `Pᵀ W K P`, dense row-major (`W = I` when `weights` is `None`).
fn coarse_k(
    ctx: &mut Ctx<'_>,
    aggs: &[u32],
    nc: usize,
    weights: Option<&[f64]>,
) -> Result<Vec<f64>, SolveError> {
    let op = ctx.op;
    let n = aggs.len();
    let w = |i: usize| weights.map_or(1.0, |w| w[i]);
    if let Some(kc) = op.coarse_operator(aggs, nc, weights) {
        if kc.len() != nc * nc || kc.iter().any(|v| !v.is_finite()) {
            return Err(SolveError::InvalidOperatorData {
                what: "coarse operator",
                reason: format!("expected {} finite entries, got {}", nc * nc, kc.len()),
            });
        }
        return Ok(kc);
    }
    let mut kc = vec![0.0; nc * nc];
    if has_entries(op) {
        let rows = op.rows().expect("checked");
        for i in 0..n {
            let row = &mut kc[aggs[i] as usize * nc..][..nc];
            let wi = w(i);
            rows.for_each_in_row(i, &mut |j, v| row[aggs[j] as usize] += wi * v);
        }
        return Ok(kc);
    }
    if nc > 64 {
        tracing::warn!(
            nc,
            "probing the coarse operator with one application per aggregate"
        );
    }
    let mut x = vec![0.0; n];
    let mut y = vec![0.0; n];
    for c in 0..nc {
        for (xi, &a) in x.iter_mut().zip(aggs) {
            *xi = if a as usize == c { 1.0 } else { 0.0 };
        }
        ctx.apply(&x, &mut y);
        for (i, (yi, &a)) in y.iter().zip(aggs).enumerate() {
            kc[a as usize * nc + c] += w(i) * yi;
        }
    }
    Ok(kc)
}

/// The coarse space: aggregates and the factorised Galerkin matrix `Pᵀ W (I − K) P`.
pub(crate) struct CoarseSpace<'a> {
    aggs: std::borrow::Cow<'a, [u32]>,
    lu: Option<Lu>,
    /// `Pᵀ W P`: the weight of each aggregate (its cell count when `W = I`).
    weight_sums: Vec<f64>,
    rc: Vec<f64>,
    tmp: Vec<f64>,
    means: Vec<f64>,
}

impl<'a> CoarseSpace<'a> {
    /// Aggregates from the operator or contiguous blocks; `weights` gives the W-weighted
    /// (symmetric) Galerkin matrix used inside conjugate gradients.
    pub(crate) fn new(ctx: &mut Ctx<'a>, weights: Option<&[f64]>) -> Result<Self, SolveError> {
        let op = ctx.op;
        let n = op.len();
        let aggs: std::borrow::Cow<'a, [u32]> = match op.coarse_aggregates() {
            Some(a) => std::borrow::Cow::Borrowed(a),
            None => {
                let count = if has_entries(op) {
                    (n / DEFAULT_AGGREGATE_SIZE).clamp(1, MAX_DEFAULT_AGGREGATES)
                } else {
                    PROBED_DEFAULT_AGGREGATES
                };
                std::borrow::Cow::Owned(contiguous_aggregates(n, count))
            }
        };
        let nc = check_aggregates(&aggs, n)?;
        let mut diag = vec![0.0; nc];
        for (i, &a) in aggs.iter().enumerate() {
            diag[a as usize] += weights.map_or(1.0, |w| w[i]);
        }
        let lu = if nc == 0 {
            None
        } else {
            let mut ac = coarse_k(ctx, &aggs, nc, weights)?;
            ac.iter_mut().for_each(|v| *v = -*v);
            // Aggregate weights set the scale against which cancellation is judged.
            let scale = diag.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            for (c, d) in diag.iter().enumerate() {
                ac[c * (nc + 1)] += d;
            }
            let lu = Lu::factor(ac, nc, scale);
            if lu.is_none() {
                tracing::warn!(
                    "coarse operator is singular (no leakage at albedo 1?): no coarse correction"
                );
            }
            lu
        };
        Ok(Self {
            aggs,
            lu,
            weight_sums: diag,
            rc: vec![0.0; nc],
            tmp: vec![0.0; nc],
            means: vec![0.0; nc],
        })
    }

    /// Whether the coarse matrix could be factorised (if not, corrections do nothing).
    pub(crate) fn is_active(&self) -> bool {
        self.lu.is_some()
    }

    /// `rc = Pᵀ W r` and, per aggregate, the W-weighted mean of `r` (so `Π r = P means`).
    fn restrict(&mut self, r: &[f64], weights: Option<&[f64]>) {
        self.rc.iter_mut().for_each(|v| *v = 0.0);
        for (i, (&a, &ri)) in self.aggs.iter().zip(r).enumerate() {
            self.rc[a as usize] += weights.map_or(ri, |w| w[i] * ri);
        }
        for ((m, &s), &d) in self.means.iter_mut().zip(&self.rc).zip(&self.weight_sums) {
            *m = if d > 0.0 { s / d } else { 0.0 };
        }
    }

    /// `x ← (I − Π) x`, with `Π = P (Pᵀ W P)⁻¹ Pᵀ W` the W-orthogonal projection onto
    /// piecewise-constant vectors: subtracts each aggregate's W-weighted mean.
    pub(crate) fn remove_means(&mut self, x: &mut [f64], weights: Option<&[f64]>) {
        self.restrict(x, weights);
        for (xi, &a) in x.iter_mut().zip(self.aggs.iter()) {
            *xi -= self.means[a as usize];
        }
    }

    /// `z = (I − Π) r + P A_c⁻¹ Pᵀ W r`: the balancing two-level preconditioner with the
    /// identity on the fine part. Unlike `I + P A_c⁻¹ Pᵀ W`, it replaces (rather than adds to)
    /// the piecewise-constant component of `r`, so coarse modes are not over-corrected.
    /// `fine`, if given, is used instead of `(I − Π) r` (already projected by the caller).
    pub(crate) fn balance(
        &mut self,
        r: &[f64],
        weights: Option<&[f64]>,
        fine: Option<&[f64]>,
        z: &mut [f64],
    ) {
        self.restrict(r, weights);
        match fine {
            Some(f) => z.copy_from_slice(f),
            None => {
                for ((zi, &ri), &a) in z.iter_mut().zip(r).zip(self.aggs.iter()) {
                    *zi = ri - self.means[a as usize];
                }
            }
        }
        let Some(lu) = &self.lu else {
            // No coarse solve: fall back to the plain residual on the coarse part.
            prolong_add(&self.aggs, &self.means, z);
            return;
        };
        lu.solve(&mut self.rc, &mut self.tmp);
        prolong_add(&self.aggs, &self.rc, z);
    }

    /// `g += P A_c⁻¹ Pᵀ W r`.
    pub(crate) fn correct(&mut self, r: &[f64], weights: Option<&[f64]>, g: &mut [f64]) {
        if self.lu.is_none() {
            return;
        }
        self.restrict(r, weights);
        let lu = self.lu.as_ref().expect("checked");
        lu.solve(&mut self.rc, &mut self.tmp);
        prolong_add(&self.aggs, &self.rc, g);
    }
}

/// `x += P coarse`: each unknown gets its aggregate's value.
fn prolong_add(aggs: &[u32], coarse: &[f64], x: &mut [f64]) {
    for (xi, &a) in x.iter_mut().zip(aggs) {
        *xi += coarse[a as usize];
    }
}

/// One cycle per iteration: residual (one application) → coarse correction → one smoother
/// step (a Jacobi step costs another application; Gauss–Seidel/SOR one sweep).
pub(crate) fn two_level(
    ctx: &mut Ctx<'_>,
    g: &mut [f64],
    inner: Smoother,
    name: String,
) -> Result<Stop, SolveError> {
    let op = ctx.op;
    let n = g.len();
    let mut coarse = CoarseSpace::new(ctx, None)?;
    let omega = match inner {
        Smoother::Jacobi => None,
        Smoother::GaussSeidel => Some(1.0),
        Smoother::Sor { omega } => Some(omega),
    };
    // The residual, then (for a Jacobi step) K g.
    let mut work = vec![0.0; n];
    let mut k = 0;
    loop {
        let rel = ctx.residual(g, &mut work);
        if let Some(reason) = ctx.mon.observe(k, rel) {
            return Ok(Stop {
                reason,
                true_residual: Some(rel),
            });
        }
        coarse.correct(&work, None, g);
        match omega {
            None => {
                ctx.apply(g, &mut work);
                let source = ctx.source;
                let kg: &[f64] = &work;
                for_each_mut(g, |i, _| source[i] + kg[i]);
            }
            Some(omega) => {
                if !op.sweep_in_place(g, ctx.source, omega) {
                    return Err(SolveError::Unsupported {
                        method: name,
                        needs: "row access or an in-place sweep for its smoother",
                    });
                }
                ctx.sweeps += 1;
            }
        }
        k += 1;
    }
}
