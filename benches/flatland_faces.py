#!/usr/bin/env python3
"""
Flatland (2D, x-z plane) discrete-ordinates test: does the error of a
step-characteristics sweep with UNIFORM ("step") face fluxes come from the
lateral faces, and how much of it do LINEAR face fluxes remove?

Geometry
  Slab 0 <= z <= tau (z points down, sigma_t = 1), periodic in x with a period
  of ONE square cell of side d = tau / L.  In exact transport the solution is
  x-independent, so the 2D column must reproduce a 1D slab solve.
  Isotropic scattering (albedo `alb`), flatland phase function 1/(2 pi).
  Collimated unit-flux beam at normal incidence on top; its uncollided part
  gives the first-scatter source alb/(2 pi) e^{-z}.  Black bottom/top for the
  diffuse field.

Schemes compared (all: same linear-in-z source per layer, same quadrature)
  1D   : z-only step characteristics (exact exponential along mu = |omega_z|).
  2D K : square-cell step characteristics, each face flux carried with K
         Legendre moments along the face (K=1 uniform "step" faces, K=2
         linear faces, ...).  Each cell's +x face feeds its own -x face
         (periodic, one cell wide), solved as a per-cell fixed point.

Everything in a cell is done in a CANONICAL frame where the direction is
(a, b) = (|omega_x|, |omega_z|), entering through W (x'=0) and N (z'=0),
leaving through E (x'=d) and S (z'=d).  x' flips for omega_x < 0 (irrelevant:
nothing depends on x), z' flips for omega_z < 0 (the source z-slope changes
sign and the layers are swept bottom-up).  In-cell transport is exact along
straight chords; face integrals use Gauss-Legendre on the pieces of each exit
face separated by the corner shadow, so the tables are exact to rounding.

Run:  python3 benches/flatland_faces.py [TAU ...]   (about 90 s for 16 and 64, 1 core;
      needs numpy, Debian's python3-numpy)
"""
import sys
import time
import numpy as np

TWO_PI = 2.0 * np.pi


# ---------------------------------------------------------------------------
# angular quadrature
# ---------------------------------------------------------------------------
def directions(n):
    """n equally spaced angles, offset by half a step (no axis-parallel one)."""
    th = (np.arange(n) + 0.5) * TWO_PI / n
    return np.cos(th), np.sin(th), np.full(n, TWO_PI / n)


# ---------------------------------------------------------------------------
# in-cell chord geometry (canonical frame)
# ---------------------------------------------------------------------------
def _gauss(lo, hi, n):
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (hi - lo) * x + 0.5 * (hi + lo), 0.5 * (hi - lo) * w


def chords(a, b, d, nq=32):
    """Chords through a d x d cell for direction (a, b), a, b > 0,
    parametrised by their EXIT point.

    Returns a dict keyed by exit face 'E' / 'S' with arrays:
      wq    quadrature weight / d (sums to 1 over the face -> face average)
      uout  exit coordinate on [-1, 1] (E: along z', S: along x')
      fin   entry face: 0 = W, 1 = N
      uin   entry coordinate on [-1, 1] (W: along z', N: along x')
      ell   chord length (= optical depth, sigma_t = 1)
      zin, zout  depth z' of entry / exit point
    """
    out = {}
    # exit face E (x'=d), coordinate z in [0, d]; trace back along -(a, b)
    zs = min(d, b * d / a)                      # below zs the chord came from N
    z1, w1 = _gauss(0.0, zs, nq)                # from N
    z2, w2 = _gauss(zs, d, nq)                  # from W
    out['E'] = dict(
        wq=np.r_[w1, w2] / d,
        uout=np.r_[2 * z1 / d - 1, 2 * z2 / d - 1],
        fin=np.r_[np.ones(nq, int), np.zeros(nq, int)],
        uin=np.r_[2 * (d - a * z1 / b) / d - 1, 2 * (z2 - b * d / a) / d - 1],
        ell=np.r_[z1 / b, np.full(nq, d / a)],
        zin=np.r_[np.zeros(nq), z2 - b * d / a],
        zout=np.r_[z1, z2])
    # exit face S (z'=d), coordinate x in [0, d]
    xs = min(d, a * d / b)                      # left of xs the chord came from W
    x1, w1 = _gauss(0.0, xs, nq)                # from W
    x2, w2 = _gauss(xs, d, nq)                  # from N
    out['S'] = dict(
        wq=np.r_[w1, w2] / d,
        uout=np.r_[2 * x1 / d - 1, 2 * x2 / d - 1],
        fin=np.r_[np.zeros(nq, int), np.ones(nq, int)],
        uin=np.r_[2 * (d - b * x1 / a) / d - 1, 2 * (x2 - a * d / b) / d - 1],
        ell=np.r_[x1 / a, np.full(nq, d / b)],
        zin=np.r_[d - b * x1 / a, np.zeros(nq)],
        zout=np.full(2 * nq, d))
    return out


def legendre(k, u):
    """P_0 .. P_{k-1} at u, shape (k, len(u))."""
    p = np.zeros((k, u.size))
    p[0] = 1.0
    if k > 1:
        p[1] = u
    for n in range(2, k):
        p[n] = ((2 * n - 1) * u * p[n - 1] - (n - 1) * p[n - 2]) / n
    return p


def src_out(b, d, ell, zout):
    """Radiance at a chord exit due to source S = Sbar + g (z' - d/2):
    returns (coefficient of Sbar, coefficient of g); analytic along the chord
    (depth decreases by b per unit length going back from the exit)."""
    e = np.exp(-ell)
    c0 = 1.0 - e
    c1 = (zout - 0.5 * d) * (1.0 - e) - b * (1.0 - e * (1.0 + ell))
    return c0, c1


def face_tables(a, b, d, K, nq=32):
    """Moment-to-moment tables of one cell (canonical frame).

    Face flux on a face is f(u) = sum_k m_k (2k+1) P_k(u), m_k = <f P_k>.
    A[F][G] (K x K): moments of outflow on exit face F per unit inflow moment
    on entry face G;  QS[F], QG[F] (K,): outflow moments per unit Sbar / unit
    z'-slope g.  F in 'E','S'; G index 0 = W, 1 = N.
    """
    ch = chords(a, b, d, nq)
    A, QS, QG = {}, {}, {}
    for F in ('E', 'S'):
        c = ch[F]
        Pout = legendre(K, c['uout']) * c['wq']                # (K, n)
        Bin = legendre(K, c['uin']) * (2 * np.arange(K) + 1)[:, None]
        att = np.exp(-c['ell'])
        A[F] = [Pout @ ((Bin * att) * (c['fin'] == G)).T for G in (0, 1)]
        s0, s1 = src_out(b, d, c['ell'], c['zout'])
        QS[F] = Pout @ s0
        QG[F] = Pout @ s1
    return A, QS, QG


def cell_response_2d(a, b, d, K, nq=32):
    """Eliminate the periodic lateral loop (W inflow = E outflow):
    returns R (K,K), Q0 (K,), Q1 (K,) such that the S-face outflow moments are
        s = R n + Q0 Sbar + Q1 g      (n = N-face inflow moments)."""
    A, QS, QG = face_tables(a, b, d, K, nq)
    M = np.linalg.inv(np.eye(K) - A['E'][0])      # (I - A_EW)^{-1}
    R = A['S'][0] @ M @ A['E'][1] + A['S'][1]
    Q0 = A['S'][0] @ M @ QS['E'] + QS['S']
    Q1 = A['S'][0] @ M @ QG['E'] + QG['S']
    return R, Q0, Q1


def cell_response_1d(b, d):
    """z-only step characteristic over one layer, same source model."""
    tau = d / b
    e = np.exp(-tau)
    c0, c1 = src_out(b, d, np.array([tau]), np.array([d]))
    return np.array([[e]]), np.array([c0[0]]), np.array([c1[0]])


# ---------------------------------------------------------------------------
# sweep + source iteration (generic over the per-cell response)
# ---------------------------------------------------------------------------
def solve(tau, L, alb, ndir, scheme, tol=1e-12, maxit=20000):
    """scheme: '1d' or an int K (number of face moments in 2D).
    Returns dict(R, T, phi, iters)."""
    d = tau / L
    ox, oz, w = directions(ndir)
    a, b = np.abs(ox), np.abs(oz)
    down = oz > 0
    K = 1 if scheme == '1d' else scheme
    Rm = np.zeros((ndir, K, K))
    Q0 = np.zeros((ndir, K))
    Q1 = np.zeros((ndir, K))
    cache = {}
    for i in range(ndir):
        key = (round(a[i], 14), round(b[i], 14))
        if key not in cache:
            cache[key] = (cell_response_1d(b[i], d) if scheme == '1d'
                          else cell_response_2d(a[i], b[i], d, K))
        Rm[i], Q0[i], Q1[i] = cache[key]

    z = d * np.arange(L + 1)
    beam = (np.exp(-z[:-1]) - np.exp(-z[1:])) / d     # cell average of e^{-z}
    phi = np.zeros(L)
    R00 = Rm[:, 0, 0]
    for it in range(1, maxit + 1):
        S = alb / TWO_PI * (phi + beam)
        g = np.empty(L)                                # source z-slope
        g[1:-1] = (S[2:] - S[:-2]) / (2 * d)
        g[0] = (S[1] - S[0]) / d
        g[-1] = (S[-1] - S[-2]) / d
        # canonical layer order per direction (upward dirs: reversed, -slope)
        Sc = np.where(down[None, :], S[:, None], S[::-1, None])   # (L, ndir)
        gc = np.where(down[None, :], g[:, None], -g[::-1, None])
        q = Q0[None] * Sc[..., None] + Q1[None] * gc[..., None]   # (L,ndir,K)
        sm = np.empty((L, ndir))                       # S-face outflow means
        s = np.zeros((ndir, K))
        if K == 1:
            s = s[:, 0]
            q = q[..., 0]
            for l in range(L):
                s = R00 * s + q[l]
                sm[l] = s
        else:
            for l in range(L):
                s = np.einsum('dij,dj->di', Rm, s) + q[l]
                sm[l] = s[:, 0]
        nm = np.vstack([np.zeros(ndir), sm[:-1]])     # N-face inflow means
        # cell average from the balance of face means (lateral terms cancel
        # because the periodic W inflow equals the E outflow)
        psib = Sc + b[None] * (nm - sm) / d
        psib = np.where(down[None, :], psib, psib[::-1])          # physical
        phinew = psib @ w
        change = np.max(np.abs(phinew - phi)) / np.max(np.abs(phinew))
        phi = phinew
        if change < tol:
            break
    Tr = np.sum((w * b * sm[-1])[down])
    Rf = np.sum((w * b * sm[-1])[~down])
    return dict(R=Rf, T=Tr, phi=phi, iters=it, change=change)


# ---------------------------------------------------------------------------
# conservation check of a single cell (independent area integral)
# ---------------------------------------------------------------------------
def conservation_check(a, b, d, K, rng):
    """Random inflow moments on W and N, random Sbar, g.  Outflow via the
    tables; extinction via an independent area integral of psi along chords.
    Returns relative residual (in + emitted - out - extinguished)/in, for a
    free W inflow and for the periodic fixed point W = E."""
    A, QS, QG = face_tables(a, b, d, K)
    ch = chords(a, b, d)
    wm, nm = rng.normal(size=K), rng.normal(size=K)
    wm[0], nm[0] = 1.0 + rng.random(), 1.0 + rng.random()
    Sb, g = 0.5 + rng.random(), rng.normal() / d
    res = []
    for periodic in (False, True):
        if periodic:
            wm = np.linalg.solve(np.eye(K) - A['E'][0],
                                 A['E'][1] @ nm + QS['E'] * Sb + QG['E'] * g)
        out = {F: A[F][0] @ wm + A[F][1] @ nm + QS[F] * Sb + QG[F] * g
               for F in ('E', 'S')}
        # area integral: chord exiting face F at spacing ds has width |n.omega| ds
        ext = 0.0
        for F, wdt in (('E', a), ('S', b)):
            c = ch[F]
            mom = np.where(c['fin'][None, :] == 0, wm[:, None], nm[:, None])
            psin = np.sum(mom * legendre(K, c['uin'])
                          * (2 * np.arange(K) + 1)[:, None], axis=0)
            l = c['ell']
            e = np.exp(-l)
            s_in = Sb + g * (c['zin'] - 0.5 * d)      # source at the entry
            slope = g * b                              # dS / d(path)
            ipsi = (psin * (1 - e) + s_in * (l - (1 - e))
                    + slope * (l * l / 2 - l * (1 - e) + (1 - e * (1 + l))))
            ext += wdt * d * np.sum(c['wq'] * ipsi)
        inflow = a * d * wm[0] + b * d * nm[0]
        emitted = d * d * Sb
        outflow = a * d * out['E'][0] + b * d * out['S'][0]
        res.append((inflow + emitted - outflow - ext) / (inflow + emitted))
    return res


# ---------------------------------------------------------------------------
def main():
    alb, ndir = 0.99, 32
    rng = np.random.default_rng(1)
    t0 = time.time()

    # --- conservation of one cell ------------------------------------------
    worst = 0.0
    for K in (1, 2, 3):
        for d in (0.25, 1.0, 4.0):
            for th in (0.3, 0.7, 1.1):
                worst = max(worst, *np.abs(conservation_check(
                    np.cos(th), np.sin(th), d, K, rng)))
    print(f"conservation (one cell, K=1..3 face moments, d=0.25..4, 3 angles, "
          f"free and periodic W inflow): max |in+emitted-out-extinguished|/"
          f"(in+emitted) = {worst:.1e}")
    # quadrature cross-check of one table entry with a varying integrand:
    # T_NE (uniform N inflow leaving through E), Gauss vs chord midpoints on N
    a_, b_ = 0.6, 0.8
    A_g = face_tables(a_, b_, 1.0, 1)[0]['E'][1][0, 0]
    print(f"T_NE (d=1, dir ({a_},{b_})): Gauss {A_g:.10f}", end='')
    for m in (64, 128):
        x = (np.arange(m) + 0.5) / m                  # entry midpoints on N
        hits_e = x + a_ / b_ > 1                      # chord leaves through E
        ell = (1 - x) / a_
        # flux a*d*<psi_E> = b * sum over N entries (dx) of e^{-ell}
        tne = b_ / a_ * np.mean(np.where(hits_e, np.exp(-ell), 0.0))
        print(f", {m} midpoints {tne:.10f}", end='')
    print()

    # --- table ---------------------------------------------------------------
    taus = [float(t) for t in sys.argv[1:]] or [16.0, 64.0]
    dlist = (1.0, 0.5, 0.25)
    extra = {16.0: (0.125, 0.0625), 64.0: (0.125,)}   # step-face convergence
    Lref = 4096
    rows = []
    for tau in taus:
        ref = solve(tau, Lref, alb, ndir, '1d')
        ref2 = solve(tau, Lref // 2, alb, ndir, '1d')
        print(f"\ntau={tau:g}: reference 1D, {Lref} layers: R={ref['R']:.8f} "
              f"T={ref['T']:.8f} ({ref['iters']} it); with {Lref//2} layers "
              f"dR={100*(ref2['R']/ref['R']-1):+.1e}% "
              f"dT={100*(ref2['T']/ref['T']-1):+.1e}%   [{time.time()-t0:.0f}s]")
        for d in dlist + extra.get(tau, ()):
            L = int(round(tau / d))
            res = {}
            for sch in (('1d', 1, 2, 3) if d in dlist else ('1d', 1, 2)):
                res[sch] = solve(tau, L, alb, ndir, sch)
            rows.append((tau, d, L, ref, res))
            print(f"  d={d:<7g} L={L:<4d} done  [{time.time()-t0:.0f}s]")

    def err(x, r):
        return 100.0 * (x / r - 1.0)

    print(f"\nRelative errors (%) vs 1D reference ({Lref} layers); albedo "
          f"{alb}, {ndir} directions, linear-in-z source")
    hdr = (f"{'tau':>4} {'d':>6} {'L':>4} | {'R 1D':>8} {'R step':>8} "
           f"{'R lin':>8} {'R quad':>8} | {'T 1D':>8} {'T step':>8} "
           f"{'T lin':>8} {'T quad':>8} | {'lin removes':>11}")
    print(hdr)
    print('-' * len(hdr))
    for tau, d, L, ref, res in rows:
        cells_R = [err(res[s]['R'], ref['R']) if s in res else np.nan
                   for s in ('1d', 1, 2, 3)]
        cells_T = [err(res[s]['T'], ref['T']) if s in res else np.nan
                   for s in ('1d', 1, 2, 3)]
        # fraction of the lateral-face error (2D minus 1D at same L) removed
        lat_step = res[1]['T'] - res['1d']['T']
        lat_lin = res[2]['T'] - res['1d']['T']
        removed = 100.0 * (1.0 - lat_lin / lat_step)
        print(f"{tau:4g} {d:6g} {L:4d} | "
              + ' '.join(f"{c:+8.3f}" if np.isfinite(c) else f"{'':>8}"
                         for c in cells_R) + ' | '
              + ' '.join(f"{c:+8.3f}" if np.isfinite(c) else f"{'':>8}"
                         for c in cells_T)
              + f" | {removed:10.1f}%")
    print("  '1D' = z-only sweep at the same L (no lateral faces); 'step' = 2D "
          "uniform faces; 'lin' = 2D linear faces;\n  'quad' = 2D quadratic "
          "faces (3 moments, extra).  'lin removes' = share of the lateral "
          "error in T,\n  (T_step - T_1D), that linear faces remove.")
    print(f"total time {time.time()-t0:.0f}s")


if __name__ == '__main__':
    main()
