//! Krylov methods on `A = I − K`: restarted GMRES, BiCGSTAB, and conjugate gradients in the
//! operator's symmetrizing inner product.

use crate::methods::coarse::CoarseSpace;
use crate::methods::multigrid::DiffusionMultigrid;
use crate::report::StopReason;
use crate::solve::{Ctx, Stop};
use crate::vecops::for_each_mut;

/// `y = (I − K) x`.
fn apply_a(ctx: &mut Ctx<'_>, x: &[f64], y: &mut [f64]) {
    ctx.apply(x, y);
    for_each_mut(y, |i, kx| x[i] - kx);
}

/// `r = E − A x`; returns the relative residual.
fn residual(ctx: &mut Ctx<'_>, x: &[f64], r: &mut [f64]) -> f64 {
    apply_a(ctx, x, r);
    let source = ctx.source;
    let r2 = ctx.red.update(r, |off, chunk| {
        let mut s = 0.0;
        for (i, v) in chunk.iter_mut().enumerate() {
            *v = source[off + i] - *v;
            s += *v * *v;
        }
        s
    });
    r2.sqrt() / ctx.scale
}

/// `y += a x`.
/// At each (re)start, from the true residual `rel`: the first call records it with the
/// monitor; later ones stop on convergence or on the monitor's limits.
fn restart_check(ctx: &mut Ctx<'_>, rel: f64, first: &mut bool) -> Option<Stop> {
    let reason = if std::mem::take(first) {
        ctx.mon.observe(0, rel)
    } else if rel <= ctx.mon.tolerance {
        Some(StopReason::Converged)
    } else {
        ctx.mon.limits()
    };
    reason.map(|reason| Stop {
        reason,
        true_residual: Some(rel),
    })
}

fn axpy(y: &mut [f64], a: f64, x: &[f64]) {
    for_each_mut(y, |i, v| v + a * x[i]);
}

/// GMRES(m), modified Gram–Schmidt, Givens rotations. One application per iteration; the
/// least-squares residual is the estimate, confirmed by a true residual at each restart.
pub(crate) fn gmres(ctx: &mut Ctx<'_>, x: &mut [f64], m: usize) -> Stop {
    let n = x.len();
    // GMRES converges within n steps: a longer cycle only costs memory.
    let m = m.min(n.max(1));
    let mut basis: Vec<Vec<f64>> = (0..=m).map(|_| vec![0.0; n]).collect();
    let mut w = vec![0.0; n];
    // Hessenberg column-major: h[j] has m+1 entries.
    let mut h = vec![vec![0.0; m + 1]; m];
    let mut cs = vec![0.0; m];
    let mut sn = vec![0.0; m];
    let mut rhs = vec![0.0; m + 1];
    let mut y = vec![0.0; m];
    let mut k = 0;
    let mut first = true;
    loop {
        let rel = residual(ctx, x, &mut basis[0]);
        if first {
            first = false;
            if let Some(reason) = ctx.mon.observe(0, rel) {
                return Stop {
                    reason,
                    true_residual: Some(rel),
                };
            }
        } else if rel <= ctx.mon.tolerance {
            return Stop {
                reason: StopReason::Converged,
                true_residual: Some(rel),
            };
        } else if let Some(reason) = ctx.mon.limits() {
            return Stop {
                reason,
                true_residual: Some(rel),
            };
        }
        let beta = rel * ctx.scale;
        if beta == 0.0 {
            return Stop {
                reason: StopReason::Converged,
                true_residual: Some(0.0),
            };
        }
        for_each_mut(&mut basis[0], |_, v| v / beta);
        rhs.iter_mut().for_each(|v| *v = 0.0);
        rhs[0] = beta;
        let mut used = 0;
        let mut stop = None;
        for j in 0..m {
            apply_a(ctx, &basis[j], &mut w);
            for i in 0..=j {
                let hij = ctx.red.dot(&w, &basis[i]);
                h[j][i] = hij;
                axpy(&mut w, -hij, &basis[i]);
            }
            let hnext = ctx.red.norm(&w);
            h[j][j + 1] = hnext;
            for i in 0..j {
                let (a, b) = (h[j][i], h[j][i + 1]);
                h[j][i] = cs[i] * a + sn[i] * b;
                h[j][i + 1] = -sn[i] * a + cs[i] * b;
            }
            let (a, b) = (h[j][j], h[j][j + 1]);
            let d = a.hypot(b);
            let (c, s) = if d == 0.0 { (1.0, 0.0) } else { (a / d, b / d) };
            cs[j] = c;
            sn[j] = s;
            h[j][j] = d;
            h[j][j + 1] = 0.0;
            rhs[j + 1] = -s * rhs[j];
            rhs[j] *= c;
            used = j + 1;
            k += 1;
            let estimate = rhs[j + 1].abs() / ctx.scale;
            // Happy breakdown: the Krylov space is invariant, the solution is in it.
            let invariant = hnext <= 1e-14 * beta;
            if let Some(reason) = ctx.mon.observe(k, estimate) {
                stop = Some(reason);
                break;
            }
            if invariant {
                break;
            }
            let bj1 = &mut basis[j + 1];
            bj1.copy_from_slice(&w);
            for_each_mut(bj1, |_, v| v / hnext);
        }
        // Back substitution for y, then x += V y.
        for i in (0..used).rev() {
            let mut s = rhs[i];
            for l in i + 1..used {
                s -= h[l][i] * y[l];
            }
            y[i] = if h[i][i] != 0.0 { s / h[i][i] } else { 0.0 };
        }
        for i in 0..used {
            axpy(x, y[i], &basis[i]);
        }
        match stop {
            Some(StopReason::Converged) | None => {}
            Some(reason) => {
                return Stop {
                    reason,
                    true_residual: None,
                }
            }
        }
        if used == 0 {
            return Stop {
                reason: StopReason::Stagnated,
                true_residual: None,
            };
        }
    }
}

/// BiCGSTAB (van der Vorst). Two applications per iteration; restarts from the true
/// residual on breakdown or when the recurrence claims convergence the true residual denies.
pub(crate) fn bicgstab(ctx: &mut Ctx<'_>, x: &mut [f64]) -> Stop {
    let n = x.len();
    let mut r = vec![0.0; n];
    let mut r_hat = vec![0.0; n];
    let mut p = vec![0.0; n];
    let mut v = vec![0.0; n];
    let mut s = vec![0.0; n];
    let mut t = vec![0.0; n];
    let mut k = 0;
    let mut restarts_without_progress = 0;
    let mut first = true;
    'restart: loop {
        let rel = residual(ctx, x, &mut r);
        if let Some(stop) = restart_check(ctx, rel, &mut first) {
            return stop;
        }
        if restarts_without_progress > 3 {
            return Stop {
                reason: StopReason::Stagnated,
                true_residual: Some(rel),
            };
        }
        r_hat.copy_from_slice(&r);
        p.iter_mut().for_each(|x| *x = 0.0);
        v.iter_mut().for_each(|x| *x = 0.0);
        let (mut rho, mut alpha, mut omega) = (1.0, 1.0, 1.0);
        let k_at_restart = k;
        loop {
            let rho_new = ctx.red.dot(&r_hat, &r);
            let rr = ctx.red.dot(&r, &r);
            if rho_new.abs() <= 1e-30 * rr.max(f64::MIN_POSITIVE) || omega == 0.0 {
                restarts_without_progress += usize::from(k == k_at_restart) + 1;
                continue 'restart;
            }
            let beta = (rho_new / rho) * (alpha / omega);
            rho = rho_new;
            for_each_mut(&mut p, |i, pi| r[i] + beta * (pi - omega * v[i]));
            apply_a(ctx, &p, &mut v);
            let rv = ctx.red.dot(&r_hat, &v);
            if rv == 0.0 || !rv.is_finite() {
                restarts_without_progress += 1;
                continue 'restart;
            }
            alpha = rho / rv;
            s.copy_from_slice(&r);
            axpy(&mut s, -alpha, &v);
            apply_a(ctx, &s, &mut t);
            let tt = ctx.red.dot(&t, &t);
            omega = if tt > 0.0 {
                ctx.red.dot(&t, &s) / tt
            } else {
                0.0
            };
            axpy(x, alpha, &p);
            axpy(x, omega, &s);
            r.copy_from_slice(&s);
            axpy(&mut r, -omega, &t);
            k += 1;
            restarts_without_progress = 0;
            let estimate = ctx.red.norm(&r) / ctx.scale;
            match ctx.mon.observe(k, estimate) {
                None => {}
                Some(StopReason::Converged) => continue 'restart,
                Some(reason) => {
                    return Stop {
                        reason,
                        true_residual: None,
                    }
                }
            }
        }
    }
}

/// The preconditioner of [`cg`], self-adjoint and positive in the `W` inner product.
pub(crate) enum Preconditioner<'a> {
    /// Plain conjugate gradients.
    Identity,
    /// `z = r + P A_c⁻¹ Pᵀ W r` (additive coarse correction).
    Coarse(CoarseSpace<'a>),
    /// Diffusion-synthetic acceleration (see [`Dsa`]).
    Dsa(Box<Dsa>),
    /// `z = (I − Π) S_m (I − Π) r + P A_c⁻¹ Pᵀ W r` with `S_m = Σ_{j≤m} K^j` (`m` extra
    /// applications of `K`): the balancing two-level preconditioner (see
    /// [`Method::TwoLevelCg`](crate::Method::TwoLevelCg)).
    TwoLevel {
        coarse: CoarseSpace<'a>,
        smoothing: usize,
        fine: Vec<f64>,
        power: Vec<f64>,
        scratch: Vec<f64>,
    },
}

/// Diffusion-synthetic acceleration: `z = r + σs ⊙ y` with `(diag(σt − σs) + G) y = r`
/// solved only loosely (relative residual [`DSA_INNER_TOLERANCE`]) by multigrid-preconditioned
/// CG: DSA has to remove the slow, smooth error modes, not to solve diffusion exactly. A loose
/// inner solve is not a fixed linear map, so [`cg`] runs as flexible CG with it.
pub(crate) struct Dsa {
    multigrid: DiffusionMultigrid,
    sigma_s: Vec<f64>,
    y: Vec<f64>,
    pub inner_iterations: usize,
}

/// Relative residual of the inner diffusion solve, and its iteration cap. On the sample cloud
/// (σ×1 and σ×4, albedo 0.5 to 1) 0.1 to 0.3 keep the outer count of an exact inner solve
/// (6 at albedo 0.999) in 3 to 5 multigrid-CG steps; a fixed 1 to 3 V-cycles cost 1 to 3
/// outer iterations more.
pub(crate) const DSA_INNER_TOLERANCE: f64 = 0.1;
const DSA_INNER_MAX: usize = 100;

impl Dsa {
    pub(crate) fn new(d: crate::operator::Diffusion) -> Result<Self, crate::SolveError> {
        let multigrid = DiffusionMultigrid::new(&d)?;
        let n = d.len();
        let (_, sigma_s, ..) = d.into_parts();
        Ok(Dsa {
            multigrid,
            sigma_s,
            y: vec![0.0; n],
            inner_iterations: 0,
        })
    }

    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        let t0 = std::time::Instant::now();
        let it = self
            .multigrid
            .solve_pcg(r, &mut self.y, DSA_INNER_TOLERANCE, DSA_INNER_MAX);
        self.inner_iterations += it;
        tracing::debug!(
            inner_iterations = it,
            total = self.inner_iterations,
            seconds = t0.elapsed().as_secs_f64(),
            "diffusion-synthetic correction"
        );
        let (y, sigma_s) = (&self.y, &self.sigma_s);
        for_each_mut(z, |i, _| r[i] + sigma_s[i] * y[i]);
    }
}

impl<'a> Preconditioner<'a> {
    pub(crate) fn two_level(coarse: CoarseSpace<'a>, smoothing: usize, n: usize) -> Self {
        let buffer = |used: bool| if used { vec![0.0; n] } else { Vec::new() };
        Preconditioner::TwoLevel {
            coarse,
            smoothing,
            fine: buffer(smoothing > 0),
            power: buffer(smoothing > 0),
            scratch: buffer(smoothing > 0),
        }
    }

    /// `z = M⁻¹ r`; returns `false` for the identity (the caller then uses `r` itself).
    fn apply(&mut self, ctx: &mut Ctx<'_>, w: &[f64], r: &[f64], z: &mut [f64]) -> bool {
        match self {
            Preconditioner::Identity => false,
            Preconditioner::Coarse(c) => {
                z.copy_from_slice(r);
                c.correct(r, Some(w), z);
                true
            }
            Preconditioner::Dsa(d) => {
                d.apply(r, z);
                true
            }
            Preconditioner::TwoLevel {
                coarse,
                smoothing,
                fine,
                power,
                scratch,
            } => {
                if *smoothing == 0 {
                    coarse.balance(r, Some(w), None, z);
                    return true;
                }
                // t = (I − Π) r; fine = Σ_{j≤m} K^j t (Horner: fine ← t + K fine); then
                // (I − Π) fine. K is W-self-adjoint, so the whole map is.
                power.copy_from_slice(r);
                coarse.remove_means(power, Some(w));
                fine.copy_from_slice(power);
                for _ in 0..*smoothing {
                    ctx.apply(fine, scratch);
                    let t: &[f64] = power;
                    let kf: &[f64] = scratch;
                    for_each_mut(fine, |i, _| t[i] + kf[i]);
                }
                coarse.remove_means(fine, Some(w));
                coarse.balance(r, Some(w), Some(fine), z);
                true
            }
        }
    }

    fn is_identity(&self) -> bool {
        matches!(self, Preconditioner::Identity)
    }

    /// Whether `M⁻¹` varies from one application to the next (an inexact inner solve).
    fn is_flexible(&self) -> bool {
        matches!(self, Preconditioner::Dsa(_))
    }
}

/// Conjugate gradients for `A = I − K`, self-adjoint in `⟨x, y⟩_w = Σ w_i x_i y_i` because
/// `diag(w) K` is symmetric. One application per iteration, plus the preconditioner's.
/// Non-positive curvature (the operator is not contractive, so `A` is not positive definite)
/// ends the solve as Stagnated.
pub(crate) fn cg(ctx: &mut Ctx<'_>, x: &mut [f64], w: &[f64], mut pre: Preconditioner<'_>) -> Stop {
    let n = x.len();
    let mut r = vec![0.0; n];
    let mut z = if pre.is_identity() {
        Vec::new()
    } else {
        vec![0.0; n]
    };
    let mut p = vec![0.0; n];
    let mut q = vec![0.0; n];
    // Flexible CG (Polak–Ribière β) for a preconditioner that is not a fixed linear map.
    let flexible = pre.is_flexible();
    let mut z_old = if flexible { vec![0.0; n] } else { Vec::new() };
    let mut k = 0;
    let mut first = true;
    loop {
        let rel = residual(ctx, x, &mut r);
        if let Some(stop) = restart_check(ctx, rel, &mut first) {
            return stop;
        }
        let preconditioned = pre.apply(ctx, w, &r, &mut z);
        p.copy_from_slice(if preconditioned { &z } else { &r });
        let mut rz = ctx.red.weighted_dot(w, &r, &p);
        loop {
            apply_a(ctx, &p, &mut q);
            let curvature = ctx.red.weighted_dot(w, &p, &q);
            if !(curvature > 0.0) {
                tracing::warn!(
                    curvature,
                    "conjugate gradients: I − K is not positive definite"
                );
                return Stop {
                    reason: StopReason::Stagnated,
                    true_residual: None,
                };
            }
            let alpha = rz / curvature;
            axpy(x, alpha, &p);
            axpy(&mut r, -alpha, &q);
            k += 1;
            let estimate = ctx.red.norm(&r) / ctx.scale;
            match ctx.mon.observe(k, estimate) {
                None => {}
                // Confirm with the true residual (and restart from it if the recurrence drifted).
                Some(StopReason::Converged) => break,
                Some(reason) => {
                    return Stop {
                        reason,
                        true_residual: None,
                    }
                }
            }
            if flexible {
                z_old.copy_from_slice(&z);
            }
            let preconditioned = pre.apply(ctx, w, &r, &mut z);
            let zr: &[f64] = if preconditioned { &z } else { &r };
            let rz_new = ctx.red.weighted_dot(w, &r, zr);
            // ⟨r_new, z_new − z_old⟩ / ⟨r_old, z_old⟩; equal to rz_new / rz for a fixed map.
            let beta_numerator = if flexible {
                rz_new - ctx.red.weighted_dot(w, &r, &z_old)
            } else {
                rz_new
            };
            if !(rz_new > 0.0) {
                tracing::warn!(
                    rz_new,
                    "conjugate gradients: preconditioner is not positive"
                );
                return Stop {
                    reason: StopReason::Stagnated,
                    true_residual: None,
                };
            }
            let beta = beta_numerator / rz;
            rz = rz_new;
            for_each_mut(&mut p, |i, pi| zr[i] + beta * pi);
        }
    }
}
