#!/usr/bin/env python3
"""A plane-parallel slab swept as discrete ordinates do, in one dimension: what the step
scheme and the bins' directions cost without the sweep's lateral faces.

The slab (optical depth TAU, isotropic scattering of albedo A) is lit by a beam at normal
incidence over a black bottom. Each layer's flux leaves by the exact step-characteristics
relation for a source linear in the layer (its slope from the neighbouring layers' mean
sources, one-sided at the slab's faces, as volrad's sweep rebuilds it) or uniform in it
(`--flat`), and the layer's mean radiance follows from its balance. Directions are Gauss's
(16 per hemisphere) or volrad's cube-face bins (`--bins 96`: each bin's solid angle and mean
|cos| to the normal). Reflected and diffuse transmitted fluxes are compared with the same
sweep on `--reference-layers` thin layers (σt h = TAU / that).

    python3 benches/slab_step_1d.py --tau 16 --albedo 0.99
    python3 benches/slab_step_1d.py --tau 64 --albedo 0.99 --bins 96     # a few minutes

Needs numpy (Debian's python3-numpy).
"""
import argparse

import numpy as np


def gauss(per_hemisphere):
    x, w = np.polynomial.legendre.leggauss(2 * per_hemisphere)
    return x[x > 0], w[x > 0]


def cube_face_bins(bins):
    """Mean |cos| to the slab normal and share of the hemisphere of each of 6 n² bins."""
    n = int(round((bins / 6) ** 0.5))
    if 6 * n * n != bins:
        raise SystemExit(f"--bins {bins}: must be 6 n²")
    k = 64
    edges = np.linspace(-1.0, 1.0, n + 1)
    mus, weights = [], []
    for normal_face in (True, False, False):  # the faces of one hemisphere's worth: z, x, y
        for i in range(n):
            for j in range(n):
                u = np.linspace(edges[i], edges[i + 1], k + 1)
                v = np.linspace(edges[j], edges[j + 1], k + 1)
                u, v = np.meshgrid((u[:-1] + u[1:]) / 2, (v[:-1] + v[1:]) / 2)
                r2 = u * u + v * v + 1.0
                d_omega = (edges[1] - edges[0]) ** 2 / k**2 / r2**1.5
                cos_z = 1.0 / np.sqrt(r2) if normal_face else np.abs(u) / np.sqrt(r2)
                omega = d_omega.sum()
                mus.append((cos_z * d_omega).sum() / omega)
                weights.append(omega)
    weights = np.array(weights)
    return np.array(mus), weights / weights.sum()


def solve(tau, layers, albedo, linear, quadrature, tol=1e-13, max_iterations=200000):
    """(R, T, iterations): reflected and diffuse transmitted flux per unit incident flux."""
    mu, w = quadrature
    d = tau / layers
    faces = np.linspace(0.0, tau, layers + 1)
    beam = (np.exp(-faces[:-1]) - np.exp(-faces[1:])) / d  # each layer's mean e^{-t}
    a = np.exp(-d / mu)
    flat_exit = 1.0 - a
    # ∫_0^d (t − d/2) e^{−(d−t)/μ} dt/μ: a unit slope's part of the outflow.
    slope_exit = d * (1.0 - a) - (mu * (1.0 - a) - d * a) - d / 2.0 * flat_exit
    phi = np.zeros(layers)
    for iteration in range(max_iterations):
        source = albedo / 2.0 * (phi + beam)
        slope = np.zeros(layers)
        if linear and layers > 1:
            slope[1:-1] = (source[2:] - source[:-2]) / (2.0 * d)
            slope[0] = (source[1] - source[0]) / d
            slope[-1] = (source[-1] - source[-2]) / d
        new = np.zeros(layers)
        fluxes = []
        for sign, order in ((1.0, range(layers)), (-1.0, range(layers - 1, -1, -1))):
            psi = np.zeros_like(mu)
            for i in order:
                out = psi * a + source[i] * flat_exit + sign * slope[i] * slope_exit
                new[i] += np.dot(w, source[i] - mu * (out - psi) / d)
                psi = out
            fluxes.append(np.dot(w * mu, psi))
        change = np.max(np.abs(new - phi)) / np.max(new)
        phi = new
        if change < tol:
            break
    transmitted, reflected = fluxes
    return reflected, transmitted, iteration + 1


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tau", type=float, default=16.0)
    p.add_argument("--albedo", type=float, default=0.99)
    p.add_argument("--layers", default="16,32,64,128")
    p.add_argument("--reference-layers", type=int, default=512)
    p.add_argument("--bins", type=int, help="volrad's cube-face bins (6 n²) instead of Gauss")
    p.add_argument("--flat", action="store_true", help="also the source uniform in each layer")
    args = p.parse_args()
    quadrature = cube_face_bins(args.bins) if args.bins else gauss(16)
    name = f"{args.bins} bins" if args.bins else "Gauss 2x16"
    r0, t0, _ = solve(args.tau, args.reference_layers, args.albedo, True, quadrature)
    print(f"tau {args.tau}, albedo {args.albedo}, {name}: reference "
          f"({args.reference_layers} layers) R {r0:.6g}, T {t0:.6g}")
    for layers in map(int, args.layers.split(",")):
        for linear in (False, True) if args.flat else (True,):
            r, t, _ = solve(args.tau, layers, args.albedo, linear, quadrature)
            label = "linear" if linear else "flat"
            print(f"  {layers:4d} layers (σt h = {args.tau / layers:.3g}), {label:6s} source: "
                  f"R {100 * (r / r0 - 1):+7.2f} %, T {100 * (t / t0 - 1):+8.2f} %")
    if args.bins:
        g = gauss(16)
        rg, tg, _ = solve(args.tau, args.reference_layers, args.albedo, True, g)
        print(f"  the bins' directions against Gauss 2x16 (both {args.reference_layers} layers): "
              f"R {100 * (r0 / rg - 1):+7.2f} %, T {100 * (t0 / tg - 1):+8.2f} %")


if __name__ == "__main__":
    main()
