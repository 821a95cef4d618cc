//! Smoothed-aggregation algebraic multigrid for the symmetric positive definite diffusion
//! system of diffusion-synthetic acceleration, `(diag(σt − σs) + G) y = r`.
//!
//! Algebraic: the aggregates come from the matrix's strong connections, not from a grid, so the
//! solver stays free of geometry. A V-cycle smooths by forward Gauss–Seidel before the coarse
//! correction and backward Gauss–Seidel after it (adjoints of each other), starts from zero and
//! ends in an exact dense solve, so a fixed number of cycles is a fixed symmetric positive
//! definite linear map: plain preconditioned CG stays valid around it.

use rayon::prelude::*;

use super::dense::Lu;
use crate::error::SolveError;
use crate::operator::Diffusion;

/// `j` is a strong neighbour of `i` when `a_ij² ≥ θ² a_ii a_jj` (Vaněk, Mandel & Brezina).
const STRENGTH: f64 = 0.08;
/// Levels at or below this size are solved by a dense LU factorisation (100 rather than a few
/// hundred: the dense factor and its triangular solves were a third of the setup).
const DENSE_MAX: usize = 100;
/// Coarsening stops when a level shrinks by less than this factor (aggregation has stalled).
const MIN_COARSENING: f64 = 1.5;
const MAX_LEVELS: usize = 20;
/// Power-iteration steps for the spectral radius of `D⁻¹ A` (prolongator smoothing).
const POWER_STEPS: usize = 15;
/// Gauss–Seidel sweeps before and after each coarse correction.
const SWEEPS: usize = 1;
/// Symmetric Gauss–Seidel sweeps on a coarsest level too large for the dense solve.
const COARSEST_SWEEPS: usize = 10;
/// Rows per rayon task; levels below twice this run serially: a 7-point product over 30 000
/// rows takes ~0.1 ms, less than waking a busy pool (measured: parallel loops over the sample
/// cloud's 24 335 active cells made each DSA correction 3× slower on a loaded machine).
const PAR_ROWS: usize = 32768;

/// A sparse matrix in compressed rows.
#[derive(Clone, Debug)]
struct Csr {
    rows: usize,
    cols: usize,
    ptr: Vec<usize>,
    col: Vec<u32>,
    val: Vec<f64>,
}

impl Csr {
    fn row_dot(&self, i: usize, x: &[f64]) -> f64 {
        let mut s = 0.0;
        for p in self.ptr[i]..self.ptr[i + 1] {
            s += self.val[p] * x[self.col[p] as usize];
        }
        s
    }

    /// `y = self · x`.
    fn mul(&self, x: &[f64], y: &mut [f64]) {
        if self.rows >= 2 * PAR_ROWS {
            y.par_iter_mut()
                .enumerate()
                .with_min_len(PAR_ROWS)
                .for_each(|(i, y)| *y = self.row_dot(i, x));
        } else {
            y.iter_mut()
                .enumerate()
                .for_each(|(i, y)| *y = self.row_dot(i, x));
        }
    }

    fn transpose(&self) -> Csr {
        let mut ptr = vec![0usize; self.cols + 1];
        for &c in &self.col {
            ptr[c as usize + 1] += 1;
        }
        for c in 0..self.cols {
            ptr[c + 1] += ptr[c];
        }
        let mut next = ptr.clone();
        let mut col = vec![0u32; self.col.len()];
        let mut val = vec![0.0; self.col.len()];
        for i in 0..self.rows {
            for p in self.ptr[i]..self.ptr[i + 1] {
                let c = self.col[p] as usize;
                col[next[c]] = i as u32;
                val[next[c]] = self.val[p];
                next[c] += 1;
            }
        }
        Csr {
            rows: self.cols,
            cols: self.rows,
            ptr,
            col,
            val,
        }
    }

    /// `self · b` (Gustavson's row-by-row product; blocks of rows in parallel, each with its
    /// own marker array).
    fn product(&self, b: &Csr) -> Csr {
        let blocks = self.rows.div_ceil(PAR_ROWS).max(1);
        let parts: Vec<(Vec<usize>, Vec<u32>, Vec<f64>)> = (0..blocks)
            .into_par_iter()
            .map(|block| {
                let rows = block * PAR_ROWS..((block + 1) * PAR_ROWS).min(self.rows);
                let mut marker = vec![usize::MAX; b.cols];
                let (mut lens, mut col, mut val) = (Vec::new(), Vec::new(), Vec::new());
                for i in rows {
                    let start = col.len();
                    for p in self.ptr[i]..self.ptr[i + 1] {
                        let (k, av) = (self.col[p] as usize, self.val[p]);
                        for q in b.ptr[k]..b.ptr[k + 1] {
                            let j = b.col[q] as usize;
                            let m = marker[j];
                            if m != usize::MAX && m >= start {
                                val[m] += av * b.val[q];
                            } else {
                                marker[j] = col.len();
                                col.push(j as u32);
                                val.push(av * b.val[q]);
                            }
                        }
                    }
                    lens.push(col.len() - start);
                }
                (lens, col, val)
            })
            .collect();
        let nnz = parts.iter().map(|p| p.1.len()).sum();
        let mut ptr = Vec::with_capacity(self.rows + 1);
        let (mut col, mut val) = (Vec::with_capacity(nnz), Vec::with_capacity(nnz));
        ptr.push(0);
        for (lens, c, v) in parts {
            for len in lens {
                ptr.push(ptr.last().copied().unwrap_or(0) + len);
            }
            col.extend_from_slice(&c);
            val.extend_from_slice(&v);
        }
        Csr {
            rows: self.rows,
            cols: b.cols,
            ptr,
            col,
            val,
        }
    }

    fn diagonal(&self) -> Vec<f64> {
        (0..self.rows)
            .map(|i| {
                (self.ptr[i]..self.ptr[i + 1])
                    .filter(|&p| self.col[p] as usize == i)
                    .map(|p| self.val[p])
                    .sum()
            })
            .collect()
    }

    /// The spectral radius of `D⁻¹ A` by power iteration (its eigenvalues are real and
    /// positive: it is similar to `D^{-1/2} A D^{-1/2}`), capped by Gershgorin's bound. The
    /// bound alone overestimates badly on coarse levels and would under-smooth the prolongator.
    fn jacobi_radius(&self, diag: &[f64]) -> f64 {
        let gershgorin = (0..self.rows)
            .map(|i| {
                let s: f64 = self.val[self.ptr[i]..self.ptr[i + 1]]
                    .iter()
                    .map(|v| v.abs())
                    .sum();
                s / diag[i]
            })
            .fold(0.0, f64::max);
        let n = self.rows;
        // A fixed, rough start vector (deterministic) with components along every mode.
        let mut x: Vec<f64> = (0..n)
            .map(|i| 1.0 + ((i * 7919) % 97) as f64 / 97.0)
            .collect();
        let mut ax = vec![0.0; n];
        let mut estimate = 0.0;
        for _ in 0..POWER_STEPS {
            self.mul(&x, &mut ax);
            ax.iter_mut().zip(diag).for_each(|(v, d)| *v /= d);
            // Rayleigh quotient in the D inner product.
            let num: f64 = (0..n).map(|i| diag[i] * x[i] * ax[i]).sum();
            let den: f64 = (0..n).map(|i| diag[i] * x[i] * x[i]).sum();
            estimate = num / den;
            let norm = ax.iter().map(|v| v * v).sum::<f64>().sqrt();
            if !(norm > 0.0) {
                break;
            }
            x.iter_mut().zip(&ax).for_each(|(x, v)| *x = v / norm);
        }
        // The Rayleigh quotient approaches from below: a 10 % margin.
        (1.1 * estimate).min(gershgorin).max(f64::MIN_POSITIVE)
    }
}

/// Aggregates of strongly connected unknowns (the three passes of Vaněk, Mandel & Brezina).
/// Unknowns without strong neighbours stay unaggregated (`u32::MAX`): the diagonal dominates
/// their rows, so the smoother alone handles them. Returns the ids and their count.
#[allow(clippy::needless_range_loop)] // several per-unknown arrays indexed together
fn aggregate(a: &Csr, diag: &[f64]) -> (Vec<u32>, usize) {
    const FREE: u32 = u32::MAX;
    let n = a.rows;
    let strong = |i: usize, p: usize| {
        let j = a.col[p] as usize;
        j != i && a.val[p] * a.val[p] >= STRENGTH * STRENGTH * diag[i] * diag[j]
    };
    let mut agg = vec![FREE; n];
    let mut count = 0u32;
    // 1: an unknown whose strong neighbours are all free roots an aggregate of them all.
    for i in 0..n {
        if agg[i] != FREE {
            continue;
        }
        let row = a.ptr[i]..a.ptr[i + 1];
        let mut any = false;
        let mut all_free = true;
        for p in row.clone().filter(|&p| strong(i, p)) {
            any = true;
            all_free &= agg[a.col[p] as usize] == FREE;
        }
        if any && all_free {
            agg[i] = count;
            for p in row.filter(|&p| strong(i, p)) {
                agg[a.col[p] as usize] = count;
            }
            count += 1;
        }
    }
    // 2: the rest join the aggregate (from pass 1) they are most strongly connected to.
    let first = agg.clone();
    for i in 0..n {
        if agg[i] != FREE {
            continue;
        }
        let mut best = (0.0, FREE);
        for p in (a.ptr[i]..a.ptr[i + 1]).filter(|&p| strong(i, p)) {
            let g = first[a.col[p] as usize];
            if g != FREE && a.val[p].abs() > best.0 {
                best = (a.val[p].abs(), g);
            }
        }
        agg[i] = best.1;
    }
    // 3: what is still free but strongly connected forms new aggregates.
    for i in 0..n {
        if agg[i] != FREE {
            continue;
        }
        let row = a.ptr[i]..a.ptr[i + 1];
        if row.clone().any(|p| strong(i, p)) {
            agg[i] = count;
            for p in row.filter(|&p| strong(i, p)) {
                let j = a.col[p] as usize;
                if agg[j] == FREE {
                    agg[j] = count;
                }
            }
            count += 1;
        }
    }
    (agg, count as usize)
}

/// The smoothed prolongator `P = (I − ω D⁻¹ A) P_tent` (`P_tent` piecewise constant on the
/// aggregates), `ω = 4 / (3 λ)` with `λ` a bound on `ρ(D⁻¹ A)`.
#[allow(clippy::needless_range_loop)] // several per-unknown arrays indexed together
fn smoothed_prolongator(a: &Csr, diag: &[f64], agg: &[u32], n_coarse: usize, lambda: f64) -> Csr {
    let omega = 4.0 / (3.0 * lambda);
    let mut ptr = Vec::with_capacity(a.rows + 1);
    let (mut col, mut val): (Vec<u32>, Vec<f64>) = (Vec::new(), Vec::new());
    ptr.push(0);
    for i in 0..a.rows {
        let start = col.len();
        for p in a.ptr[i]..a.ptr[i + 1] {
            let j = a.col[p] as usize;
            let g = agg[j];
            if g == u32::MAX {
                continue;
            }
            let delta = if j == i { 1.0 } else { 0.0 };
            let v = delta - omega * a.val[p] / diag[i];
            // Rows touch only a few aggregates: a linear search beats a marker here.
            match col[start..].iter().position(|&c| c == g) {
                Some(k) => val[start + k] += v,
                None => {
                    col.push(g);
                    val.push(v);
                }
            }
        }
        ptr.push(col.len());
    }
    Csr {
        rows: a.rows,
        cols: n_coarse,
        ptr,
        col,
        val,
    }
}

struct Level {
    a: Csr,
    /// `1 / a_ii`.
    inv_diag: Vec<f64>,
    /// Prolongation to this level from the next coarser one, and its transpose (restriction).
    transfer: Option<(Csr, Csr)>,
    /// Dense factorisation when this is the coarsest level and small enough.
    dense: Option<Lu>,
    x: Vec<f64>,
    b: Vec<f64>,
    t: Vec<f64>,
}

impl Level {
    fn new(a: Csr) -> Self {
        let n = a.rows;
        Level {
            inv_diag: a.diagonal().iter().map(|d| 1.0 / d).collect(),
            a,
            transfer: None,
            dense: None,
            x: vec![0.0; n],
            b: vec![0.0; n],
            t: vec![0.0; n],
        }
    }

    /// `x += y` elementwise (`y` in `t`).
    fn add_correction(&mut self) {
        let (x, t) = (&mut self.x, &self.t);
        if x.len() >= 2 * PAR_ROWS {
            x.par_iter_mut()
                .zip(t)
                .with_min_len(PAR_ROWS)
                .for_each(|(x, t)| *x += t);
        } else {
            x.iter_mut().zip(t).for_each(|(x, t)| *x += t);
        }
    }

    /// One Gauss–Seidel sweep on `A x = b`, forward or backward. A forward sweep before the
    /// coarse correction and a backward one after it make the V-cycle symmetric.
    fn gauss_seidel(&mut self, forward: bool) {
        let a = &self.a;
        let (x, b, inv) = (&mut self.x, &self.b, &self.inv_diag);
        let mut relax = |i: usize| {
            let mut s = b[i];
            for p in a.ptr[i]..a.ptr[i + 1] {
                s -= a.val[p] * x[a.col[p] as usize];
            }
            x[i] += s * inv[i];
        };
        if forward {
            (0..a.rows).for_each(&mut relax);
        } else {
            (0..a.rows).rev().for_each(&mut relax);
        }
    }

    /// Pre-smoothing from zero: `SWEEPS` forward sweeps.
    fn presmooth(&mut self) {
        self.x.iter_mut().for_each(|v| *v = 0.0);
        for _ in 0..SWEEPS {
            self.gauss_seidel(true);
        }
    }

    /// Post-smoothing, the adjoint of [`presmooth`](Self::presmooth): `SWEEPS` backward sweeps.
    fn postsmooth(&mut self) {
        for _ in 0..SWEEPS {
            self.gauss_seidel(false);
        }
    }

    /// `t = b − A x`.
    fn residual(&mut self) {
        self.a.mul(&self.x, &mut self.t);
        let (t, b) = (&mut self.t, &self.b);
        if t.len() >= 2 * PAR_ROWS {
            t.par_iter_mut()
                .zip(b)
                .with_min_len(PAR_ROWS)
                .for_each(|(t, b)| *t = b - *t);
        } else {
            t.iter_mut().zip(b).for_each(|(t, b)| *t = b - *t);
        }
    }

    fn solve_coarsest(&mut self) {
        let Some(lu) = &self.dense else {
            // Symmetric Gauss–Seidel from zero: still a symmetric positive map.
            self.x.iter_mut().for_each(|v| *v = 0.0);
            for _ in 0..COARSEST_SWEEPS {
                self.gauss_seidel(true);
                self.gauss_seidel(false);
            }
            return;
        };
        self.x.copy_from_slice(&self.b);
        lu.solve(&mut self.x, &mut self.t);
    }
}

/// A smoothed-aggregation multigrid hierarchy for `(diag(σt − σs) + G) y = r` on the active
/// unknowns of a [`Diffusion`] (those with a non-empty row), with the work vectors of its
/// V-cycles preallocated.
pub struct DiffusionMultigrid {
    /// Active unknown → full index.
    active: Vec<u32>,
    levels: Vec<Level>,
    /// Compact work vectors: right-hand side, iterate, and those of the inner PCG.
    rhs: Vec<f64>,
    y: Vec<f64>,
    res: Vec<f64>,
    dir: Vec<f64>,
    a_dir: Vec<f64>,
}

impl DiffusionMultigrid {
    /// Builds the hierarchy. Errors if an active row's diagonal `σt − σs + G_ii` is not
    /// positive and finite (the rest of the data is consistent by [`Diffusion`]'s invariants).
    pub fn new(d: &Diffusion) -> Result<Self, SolveError> {
        let t0 = std::time::Instant::now();
        let n = d.len();
        let (sigma_t, sigma_s) = (d.sigma_t(), d.sigma_s());
        let (row_ptr, d_col, d_val) = (d.row_ptr(), d.col(), d.val());
        let active: Vec<u32> = (0..n as u32)
            .filter(|&i| row_ptr[i as usize + 1] > row_ptr[i as usize])
            .collect();
        let mut compact = vec![u32::MAX; n];
        for (k, &i) in active.iter().enumerate() {
            compact[i as usize] = k as u32;
        }
        // The compact matrix diag(σt − σs) + G, diagonal first in each row.
        let m = active.len();
        let mut ptr = Vec::with_capacity(m + 1);
        let (mut col, mut val) = (Vec::new(), Vec::new());
        ptr.push(0);
        for (k, &i) in active.iter().enumerate() {
            let i = i as usize;
            let mut diag = sigma_t[i] - sigma_s[i];
            col.push(k as u32);
            val.push(0.0);
            for p in row_ptr[i]..row_ptr[i + 1] {
                let j = d_col[p] as usize;
                if j == i {
                    diag += d_val[p];
                } else if compact[j] != u32::MAX {
                    col.push(compact[j]);
                    val.push(d_val[p]);
                }
            }
            if !(diag > 0.0 && diag.is_finite()) {
                return Err(SolveError::InvalidOperatorData {
                    what: "diffusion approximation",
                    reason: format!("row {i} has diagonal {diag}"),
                });
            }
            let start = ptr[k];
            val[start] = diag;
            ptr.push(col.len());
        }
        let mut a = Csr {
            rows: m,
            cols: m,
            ptr,
            col,
            val,
        };
        let mut levels = Vec::new();
        loop {
            let n_level = a.rows;
            if n_level <= DENSE_MAX || levels.len() + 1 >= MAX_LEVELS {
                break;
            }
            let diag = a.diagonal();
            let lambda = a.jacobi_radius(&diag);
            let (agg, n_coarse) = aggregate(&a, &diag);
            if n_coarse == 0 || (n_coarse as f64) * MIN_COARSENING > n_level as f64 {
                break;
            }
            let p = smoothed_prolongator(&a, &diag, &agg, n_coarse, lambda);
            let r = p.transpose();
            let coarse = r.product(&a.product(&p));
            let mut level = Level::new(a);
            level.transfer = Some((p, r));
            levels.push(level);
            a = coarse;
        }
        let mut coarsest = Level::new(a);
        if coarsest.a.rows <= DENSE_MAX {
            let n = coarsest.a.rows;
            let mut dense = vec![0.0; n * n];
            for i in 0..n {
                for p in coarsest.a.ptr[i]..coarsest.a.ptr[i + 1] {
                    dense[i * n + coarsest.a.col[p] as usize] += coarsest.a.val[p];
                }
            }
            // The Galerkin matrix of an SPD matrix is SPD: if LU finds it singular to rounding
            // (e.g. no absorption and no leakage), the Gauss–Seidel sweeps, still a symmetric
            // positive map, take its place. Pivots are judged against the largest diagonal
            // entry, which bounds every entry of an SPD matrix.
            let scale = (0..n).fold(0.0f64, |m, i| m.max(dense[i * n + i].abs()));
            coarsest.dense = Lu::factor(dense, n, scale);
        }
        levels.push(coarsest);
        tracing::debug!(
            levels = levels.len(),
            sizes = ?levels.iter().map(|l| l.a.rows).collect::<Vec<_>>(),
            entries = ?levels.iter().map(|l| l.a.col.len()).collect::<Vec<_>>(),
            seconds = t0.elapsed().as_secs_f64(),
            "diffusion multigrid"
        );
        Ok(DiffusionMultigrid {
            active,
            levels,
            rhs: vec![0.0; m],
            y: vec![0.0; m],
            res: vec![0.0; m],
            dir: vec![0.0; m],
            a_dir: vec![0.0; m],
        })
    }

    /// Unknowns per level, finest first.
    pub fn level_sizes(&self) -> Vec<usize> {
        self.levels.iter().map(|l| l.a.rows).collect()
    }

    /// One V-cycle on the finest level's `b`, from zero, into its `x`.
    fn vcycle(&mut self) {
        let last = self.levels.len() - 1;
        for l in 0..last {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let level = &mut fine[l];
            level.presmooth();
            level.residual();
            let (_, restrict) = level.transfer.as_ref().expect("not the coarsest level");
            restrict.mul(&level.t, &mut coarse[0].b);
        }
        self.levels[last].solve_coarsest();
        for l in (0..last).rev() {
            let (fine, coarse) = self.levels.split_at_mut(l + 1);
            let level = &mut fine[l];
            let (prolong, _) = level.transfer.as_ref().expect("not the coarsest level");
            prolong.mul(&coarse[0].x, &mut level.t);
            level.add_correction();
            level.postsmooth();
        }
    }

    /// `y ≈ (diag(σt − σs) + G)⁻¹ r` by conjugate gradients preconditioned by one V-cycle,
    /// from zero, until the residual is at most `rel_tol` times `‖r‖` or after `max_iter`
    /// iterations (full-length vectors; `y` is 0 on inactive unknowns). Returns the iterations.
    /// With a loose tolerance this is not a fixed linear map of `r`: use it inside flexible CG.
    pub fn solve_pcg(&mut self, r: &[f64], y: &mut [f64], rel_tol: f64, max_iter: usize) -> usize {
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
        for (k, &i) in self.active.iter().enumerate() {
            self.res[k] = r[i as usize];
        }
        self.y.iter_mut().for_each(|v| *v = 0.0);
        let r0 = dot(&self.res, &self.res).sqrt();
        let mut iterations = 0;
        if r0 > 0.0 {
            let mut rz = self.precondition_into_top();
            self.dir.copy_from_slice(&self.levels[0].x);
            while iterations < max_iter {
                self.levels[0].a.mul(&self.dir, &mut self.a_dir);
                let curvature = dot(&self.dir, &self.a_dir);
                if !(curvature > 0.0) {
                    break;
                }
                let alpha = rz / curvature;
                for k in 0..self.y.len() {
                    self.y[k] += alpha * self.dir[k];
                    self.res[k] -= alpha * self.a_dir[k];
                }
                iterations += 1;
                if dot(&self.res, &self.res).sqrt() <= rel_tol * r0 {
                    break;
                }
                let rz_new = self.precondition_into_top();
                let beta = rz_new / rz;
                rz = rz_new;
                let z = &self.levels[0].x;
                self.dir
                    .iter_mut()
                    .zip(z)
                    .for_each(|(d, z)| *d = z + beta * *d);
            }
        }
        y.iter_mut().for_each(|v| *v = 0.0);
        for (k, &i) in self.active.iter().enumerate() {
            y[i as usize] = self.y[k];
        }
        iterations
    }

    /// One V-cycle on the current inner residual into the finest level's `x`; returns
    /// `⟨res, x⟩`.
    fn precondition_into_top(&mut self) -> f64 {
        self.levels[0].b.copy_from_slice(&self.res);
        self.vcycle();
        self.res
            .iter()
            .zip(&self.levels[0].x)
            .map(|(r, z)| r * z)
            .sum()
    }

    /// `y ≈ (diag(σt − σs) + G)⁻¹ r` by `cycles` V-cycles from zero (full-length vectors;
    /// `y` is 0 on inactive unknowns). A fixed linear, symmetric positive definite map of `r`.
    pub fn solve(&mut self, r: &[f64], y: &mut [f64], cycles: usize) {
        for (k, &i) in self.active.iter().enumerate() {
            self.rhs[k] = r[i as usize];
        }
        self.y.iter_mut().for_each(|v| *v = 0.0);
        for cycle in 0..cycles {
            let top = &mut self.levels[0];
            if cycle == 0 {
                top.b.copy_from_slice(&self.rhs);
            } else {
                top.a.mul(&self.y, &mut top.t);
                let (b, t, rhs) = (&mut top.b, &top.t, &self.rhs);
                b.iter_mut()
                    .enumerate()
                    .for_each(|(i, b)| *b = rhs[i] - t[i]);
            }
            self.vcycle();
            let (y, x) = (&mut self.y, &self.levels[0].x);
            y.iter_mut().zip(x).for_each(|(y, x)| *y += x);
        }
        y.iter_mut().for_each(|v| *v = 0.0);
        for (k, &i) in self.active.iter().enumerate() {
            y[i as usize] = self.y[k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Cell-centred 7-point diffusion on an `n³` grid (coefficient `coef(i)` per cell,
    /// harmonic-mean faces, vacuum-like boundary term) with absorption `sigma_a`.
    fn grid_diffusion(n: usize, coef: impl Fn(usize) -> f64, sigma_a: f64) -> Diffusion {
        let len = n * n * n;
        let stride = [1, n, n * n];
        let (mut row_ptr, mut col, mut val) = (vec![0], Vec::new(), Vec::new());
        for i in 0..len {
            let x = [i % n, (i / n) % n, i / (n * n)];
            let mut diag = 0.0;
            for ax in 0..3 {
                for up in [false, true] {
                    let nb = if up {
                        (x[ax] + 1 < n).then(|| i + stride[ax])
                    } else {
                        (x[ax] > 0).then(|| i - stride[ax])
                    };
                    let di = coef(i);
                    match nb {
                        Some(j) => {
                            let dj = coef(j);
                            let c = 2.0 * di * dj / (di + dj);
                            diag += c;
                            col.push(j as u32);
                            val.push(-c);
                        }
                        None => diag += di / (0.5 + 2.0 * di),
                    }
                }
            }
            col.push(i as u32);
            val.push(diag);
            row_ptr.push(col.len());
        }
        Diffusion::new(vec![1.0; len], vec![1.0 - sigma_a; len], row_ptr, col, val).unwrap()
    }

    fn reduction(d: &Diffusion, cycles: usize) -> f64 {
        let n = d.len();
        let mut mg = DiffusionMultigrid::new(d).unwrap();
        let r: Vec<f64> = (0..n)
            .map(|i| ((i * 7919) % 101) as f64 / 101.0 - 0.3)
            .collect();
        let mut y = vec![0.0; n];
        mg.solve(&r, &mut y, cycles);
        let mut res = 0.0;
        let mut r0 = 0.0;
        for i in 0..n {
            let mut ay = (d.sigma_t()[i] - d.sigma_s()[i]) * y[i];
            for p in d.row_ptr()[i]..d.row_ptr()[i + 1] {
                ay += d.val()[p] * y[d.col()[p] as usize];
            }
            res += (r[i] - ay) * (r[i] - ay);
            r0 += r[i] * r[i];
        }
        (res / r0).sqrt().powf(1.0 / cycles as f64)
    }

    #[test]
    fn a_system_within_the_dense_size_is_solved_exactly_by_one_cycle() {
        // 4³ = 64 unknowns ≤ DENSE_MAX: one level, so a V-cycle is the dense LU solve alone
        // (smoothing alone would leave a residual of order 0.1; 1000:1 coefficient jumps).
        let d = grid_diffusion(4, |i| if i % 3 == 0 { 1e3 / 3.0 } else { 1.0 / 3.0 }, 1e-3);
        assert_eq!(DiffusionMultigrid::new(&d).unwrap().level_sizes(), vec![64]);
        let relative_residual = reduction(&d, 1);
        assert!(relative_residual < 1e-12, "{relative_residual}");
    }

    #[test]
    fn a_v_cycle_reduces_the_diffusion_residual_by_a_bounded_factor() {
        // Homogeneous (D = 1/3) and with 1000:1 coefficient jumps in a checkerboard of
        // 3-cell blocks; absorption 1e-3, so only the vacuum faces keep A well conditioned.
        let jumpy = |i: usize| {
            let x = [i % 24, (i / 24) % 24, i / 576];
            if (x[0] / 3 + x[1] / 3 + x[2] / 3).is_multiple_of(2) {
                1.0 / 3.0
            } else {
                1e3 / 3.0
            }
        };
        for (name, d) in [
            ("homogeneous 12³", grid_diffusion(12, |_| 1.0 / 3.0, 1e-3)),
            ("homogeneous 24³", grid_diffusion(24, |_| 1.0 / 3.0, 1e-3)),
            ("jumps 24³", grid_diffusion(24, jumpy, 1e-3)),
        ] {
            let levels = DiffusionMultigrid::new(&d).unwrap().level_sizes();
            assert!(levels.len() >= 2, "{name}: {levels:?}");
            let one = reduction(&d, 1);
            let three = reduction(&d, 3);
            eprintln!("{name}: levels {levels:?}, one cycle {one:.3}, three {three:.3}");
            // A wrong prolongator, restriction or coarse matrix leaves factors near 1.
            assert!(
                one < 0.6,
                "{name}: one V-cycle reduced the residual only by {one}"
            );
            assert!(three < 0.7, "{name}: three V-cycles, {three} per cycle");
            // Preconditioned CG on top: 1e-8 in a handful of cycles.
            let n = d.len();
            let mut mg = DiffusionMultigrid::new(&d).unwrap();
            let r: Vec<f64> = (0..n).map(|i| ((i * 31) % 17) as f64 - 8.0).collect();
            let mut y = vec![0.0; n];
            let iterations = mg.solve_pcg(&r, &mut y, 1e-8, 100);
            eprintln!("{name}: PCG to 1e-8 in {iterations}");
            assert!(iterations <= 25, "{name}: {iterations}");
        }
    }
}
