#!/usr/bin/env python3
"""Makes disort_slabs.json: DISORT reference values for homogeneous plane-parallel slabs.

    pip install pydisort==1.8.13          # cdisort 2.1.3 (PyPI wheel for CPython 3.11)
    python3 crates/formfactor/tests/data/make_disort_slabs.py [OUT.json]

Same set-up and conventions as disort.json beside it (see README.md): one homogeneous layer of
optical depth tau, exact Henyey-Greenstein moments chi_l = g^l, a collimated beam of flux 1 (on
a plane perpendicular to it) at cos(theta0) = mu0 on the top, black lower boundary, no thermal
emission, intensity correction off. Fluxes are divided by mu0; radiance is per unit incident
beam flux.

Streams: 128 for every case (disort.json used 64). cdisort always delta-M scales with the
truncated fraction f = chi_nstr = g^nstr; at g = 0.9 and 64 streams that is f = 1.2e-3, which
moves radiances by up to 4 % (the forward peak in transmission, the backscatter side in
reflection). With 128 streams f = g^128 <= 1.4e-6. Every case is
recomputed with 64 streams, and the g = 0.9 cases also with 256, and the differences are
recorded per case and in the header.

Radiance at a user angle: the median of DISORT's values at five cosines mu (1 + k 2e-4),
k = -2 ... 2 (mu = 1: 1 - k 2e-4, k = 0 ... 4). With 128 and 256 streams cdisort's user-angle
radiance has isolated spikes: at tau = 1, g = 0.7, albedo 0.9, mu0 = 0.4 the transmitted
radiance at mu = 0.4, phi = 180 is 0.01931 with 128 streams where 64 and 256 streams, and
128 streams at mu = 0.399 or 0.401, give 0.01826 (smoothly varying); up to 6 % elsewhere, at
one or two of several nearby cosines. The median of five removes up to two such spikes and moves
a smooth value by at most one step (2e-4 relative in mu). With it 128 and 256 streams agree
to 1.3e-4 (they differed by up to 3.8 % on the raw values).
"""

import json
import math
import sys
import time

import numpy as np
import torch
from pydisort import Disort, DisortOptions

TAUS = [1.0, 4.0, 16.0, 64.0]
GS = [0.0, 0.3, 0.6, 0.7, 0.85, 0.9]
ALBEDOS = [0.9, 0.99, 1.0]
MU0S = [1.0, 0.7, 0.4]
MUS = [1.0, 0.7, 0.4]
PHIS = [0.0, 90.0, 180.0]

NSTR = 128
NMOM = 256
CHECK_LOW = (64, 256)
CHECK_HIGH = (256, 512)
CHECK_HIGH_G = [0.9]

F64 = torch.float64


MEDIAN_STEP = 2e-4


def nearby(mu):
    """The five cosines whose median radiance stands for mu's."""
    if mu >= 1.0:
        return [1.0 - k * MEDIAN_STEP for k in range(5)]
    return [mu * (1.0 + k * MEDIAN_STEP) for k in range(-2, 3)]


def run(tau, albedo, g, mu0, nstr=NSTR, nmom=NMOM, mus=MUS, phis=PHIS):
    """Fluxes and radiances of one slab. Returns (R, T_diffuse, T_direct, reflected,
    transmitted), the radiances as dicts mu -> phi -> value, each the median over
    nearby(mu)."""
    r, t_diffuse, t_direct, reflected, transmitted = run_raw(
        tau, albedo, g, mu0, nstr, nmom, sorted({x for m in mus for x in nearby(m)}), phis
    )

    def median(table):
        return {
            f"mu={m}": {
                f"phi={p:g}": sorted(table[x][p] for x in nearby(m))[2] for p in phis
            }
            for m in mus
        }

    return r, t_diffuse, t_direct, median(reflected), median(transmitted)


def run_raw(tau, albedo, g, mu0, nstr, nmom, mus, phis):
    """One DISORT run; radiances as dicts mu -> phi -> value at exactly these cosines."""
    op = DisortOptions().flags("usrtau,usrang,lamber,quiet")
    op.ds().nlyr = 1
    op.ds().nstr = nstr
    op.ds().nmom = nmom
    op.ds().nphase = nstr
    op.user_tau(np.array([0.0, tau]))
    # DISORT wants the cosines increasing: downward (negative) first, then upward.
    user_mu = sorted([-m for m in mus] + list(mus))
    op.user_mu(np.array(user_mu))
    op.user_phi(np.array(phis))
    ds = Disort(op)
    prop = torch.zeros((1, 1, 1, 2 + nmom), dtype=F64)
    prop[..., 0] = tau
    prop[..., 1] = albedo
    prop[..., 2:] = torch.tensor([g ** (l + 1) for l in range(nmom)], dtype=F64)
    ds.forward(
        prop,
        umu0=torch.tensor([mu0], dtype=F64),
        phi0=torch.tensor([0.0], dtype=F64),
        fbeam=torch.tensor([[1.0]], dtype=F64),
        albedo=torch.tensor([[0.0]], dtype=F64),
        fluor=torch.tensor([[0.0]], dtype=F64),
        fisot=torch.tensor([[0.0]], dtype=F64),
    )
    flx = ds.gather_flx()[0, 0].numpy()  # (level, [rfldir, fldn, flup, ...])
    rad = ds.gather_rad()[0, 0].numpy()  # (phi, level, mu)
    r = flx[0, 2] / mu0
    t_diffuse = flx[1, 1] / mu0
    t_direct = flx[1, 0] / mu0
    reflected, transmitted = {}, {}
    for m in mus:
        up, down = user_mu.index(m), user_mu.index(-m)
        reflected[m] = {p: float(rad[i, 0, up]) for i, p in enumerate(phis)}
        transmitted[m] = {p: float(rad[i, 1, down]) for i, p in enumerate(phis)}
    return float(r), float(t_diffuse), float(t_direct), reflected, transmitted


def values(result):
    """R, T_diffuse and every radiance of a result, in a fixed order."""
    r, t, _, refl, trans = result
    out = [r, t]
    for table in (refl, trans):
        for m in table.values():
            out.extend(m.values())
    return out


def max_rel_diff(a, b):
    return max(abs(x / y - 1.0) for x, y in zip(values(a), values(b)) if y != 0.0)


def round_sig(x, digits=10):
    return float(f"{x:.{digits}g}")


def write_table(doc, cases, out_path):
    """Writes `doc` with `cases` appended: header fields indented, one case per line (small,
    and diffs stay readable). Shared with tests/data/make_disort_ground.py."""
    text = json.dumps(doc, indent=1)
    body = ",\n".join("  " + json.dumps(c, separators=(",", ":")) for c in cases)
    text = text[:-2] + ',\n "cases": [\n' + body + "\n ]\n}\n"
    json.loads(text)
    with open(out_path, "w") as f:
        f.write(text)
    print(f"{len(cases)} cases -> {out_path}", file=sys.stderr)


def single_scatter_check():
    """DISORT against analytic single scattering, tau = 1e-4, g = 0.9, mu0 = 0.7."""
    tau, a, g, mu0 = 1e-4, 1.0, 0.9, 0.7
    _, _, _, refl, trans = run(tau, a, g, mu0)

    def hg(c):
        return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * c) ** 1.5)

    s0 = math.sqrt(1 - mu0 * mu0)
    ratios = []
    for m in (0.4, 0.7):
        s = math.sqrt(1 - m * m)
        for phi in (0.0, 180.0):
            cp = math.cos(math.radians(phi))
            # Reflected: travel (s cos phi, s sin phi, m), beam (s0, 0, -mu0).
            c = s * s0 * cp - m * mu0
            want = a * hg(c) * mu0 / (mu0 + m) * -math.expm1(-tau * (1 / mu0 + 1 / m))
            ratios.append(refl[f"mu={m}"][f"phi={phi:g}"] / want)
            c = s * s0 * cp + m * mu0
            if abs(m - mu0) < 1e-12:
                want = a * hg(c) * tau / mu0 * math.exp(-tau / mu0)
            else:
                want = a * hg(c) * mu0 / (m - mu0) * (math.exp(-tau / m) - math.exp(-tau / mu0))
            ratios.append(trans[f"mu={m}"][f"phi={phi:g}"] / want)
    return min(ratios), max(ratios)


def main():
    out_path = sys.argv[1] if len(sys.argv) > 1 else "disort_slabs.json"
    torch.set_num_threads(1)
    start = time.time()
    cases = []
    worst_low, worst_high = 0.0, 0.0
    for tau in TAUS:
        for g in GS:
            for a in ALBEDOS:
                for mu0 in MU0S:
                    main_run = run(tau, a, g, mu0)
                    r, t, td, refl, trans = main_run
                    low = max_rel_diff(run(tau, a, g, mu0, *CHECK_LOW), main_run)
                    worst_low = max(worst_low, low)
                    conv = {f"max_rel_diff_vs_{CHECK_LOW[0]}_streams": round_sig(low, 3)}
                    if g in CHECK_HIGH_G:
                        high = max_rel_diff(run(tau, a, g, mu0, *CHECK_HIGH), main_run)
                        worst_high = max(worst_high, high)
                        conv[f"max_rel_diff_vs_{CHECK_HIGH[0]}_streams"] = round_sig(high, 3)
                    rs = lambda table: {
                        m: {p: round_sig(v) for p, v in row.items()} for m, row in table.items()
                    }
                    cases.append(
                        {
                            "tau": tau,
                            "albedo": a,
                            "g": g,
                            "mu0": mu0,
                            "R": round_sig(r),
                            "T_diffuse": round_sig(t),
                            "T_direct": round_sig(td),
                            "T_direct_exact": round_sig(math.exp(-tau / mu0)),
                            "A": round_sig(1.0 - r - t - td),
                            "reflected_radiance": rs(refl),
                            "transmitted_diffuse_radiance": rs(trans),
                            "convergence": conv,
                        }
                    )
                    print(
                        f"tau {tau:g} g {g} a {a} mu0 {mu0}: R {r:.6f} T {t:.6f} "
                        f"vs {CHECK_LOW[0]} streams {low:.1e}",
                        file=sys.stderr,
                    )
    ss_lo, ss_hi = single_scatter_check()
    doc = {
        "description": (
            "Plane-parallel homogeneous slab, DISORT (cdisort 2.1.3 via pydisort 1.8.13). "
            "Collimated beam of flux 1 on a plane perpendicular to the beam, incident on the top "
            "at cos(theta0)=mu0; black (non-reflecting) lower boundary; no thermal emission; no "
            "other illumination. Made by make_disort_slabs.py beside this file."
        ),
        "solver": {
            "nstr": NSTR,
            "nmom": NMOM,
            "phase_moments": "exact Henyey-Greenstein, chi_l = g^l",
            "delta_M": (
                f"cdisort always applies delta-M with truncated fraction f = chi_nstr = g^{NSTR} "
                f"(<= {0.9 ** NSTR:.1e} at g = 0.9). 64 streams are not enough at g = 0.9: "
                f"f = 1.2e-3 there, and radiances move by up to {100 * worst_low:.1f} % (below)"
            ),
            "albedo_one": (
                "albedo 1.0 is passed as is; cdisort replaces it by 1 - 100 DBL_EPSILON "
                "(2.2e-14) internally; R + T_diffuse + T_direct = 1 to 1e-9"
            ),
            "intensity_correction": (
                "OFF (as in disort.json: in this pydisort build switching it on returns inf/nan "
                "radiances). It only repairs delta-M truncation, <= 1.4e-6 here. "
                "Single-scattering sanity check: tau=1e-4, albedo 1, g=0.9, mu0=0.7, mu=0.4 and "
                "0.7, phi=0/180, reflected and transmitted: DISORT / analytic single scattering "
                f"from {ss_lo:.4f} to {ss_hi:.4f}"
            ),
            "user_angles": (
                "each radiance is the median of DISORT's values at five cosines mu (1 + k 2e-4), "
                "k = -2..2 (mu = 1: 1 - k 2e-4, k = 0..4): cdisort's user-angle radiance has "
                "isolated spikes of up to 6 % at 128 and 256 streams (see make_disort_slabs.py)"
            ),
            "surface": "lamber with albedo 0 (black)",
            "convergence_check": (
                f"every case recomputed with {CHECK_LOW[0]} streams (max relative difference over "
                f"R, T_diffuse and all radiances of all cases: {worst_low:.2e}); the g = 0.9 cases "
                f"also with {CHECK_HIGH[0]} streams (max {worst_high:.2e}). Per case in "
                "'convergence'."
            ),
        },
        "units": {
            "R": "upward diffuse flux at top / mu0",
            "T_diffuse": "downward diffuse flux at bottom / mu0",
            "T_direct": "downward direct-beam flux at bottom / mu0 (= exp(-tau/mu0))",
            "A": "1 - R - T_diffuse - T_direct (absorbed fraction)",
            "radiance": (
                "radiance per unit incident beam flux (flux 1 on a plane perpendicular to the "
                "beam); i.e. a Lambertian white reflector under the same beam would show "
                "radiance mu0/pi"
            ),
        },
        "angles": {
            "mu": (
                "cosine of the angle between the radiance travel direction and the outward normal "
                "of the face: reflected_radiance = upward-travelling radiance at the top face "
                "(cos w.r.t. +z up), transmitted_diffuse_radiance = downward-travelling diffuse "
                "radiance at the bottom face (cos w.r.t. -z); mu=1 is the normal direction. The "
                "collimated beam is excluded from transmitted radiance; where mu = mu0 and phi = 0 "
                "the view looks straight into the beam and sees the diffuse forward peak only"
            ),
            "phi": (
                "relative azimuth between the horizontal component of the radiance TRAVEL "
                "direction and the horizontal TRAVEL direction of the incident beam (DISORT phi - "
                "phi0). phi=0: the radiance travels horizontally the same way as the beam "
                "(reflection: forward-scattering/specular side, the observer looks back toward the "
                "sun azimuth); phi=180: travels back toward the source (reflection: backscatter "
                "side, the observer has the sun behind); for mu0=1 or mu=1 the value does not "
                "depend on phi"
            ),
        },
        "parameters": {
            "tau": TAUS,
            "albedo": ALBEDOS,
            "g": GS,
            "mu0": MU0S,
            "mu": MUS,
            "phi_deg": PHIS,
        },
        "wall_time_s": round(time.time() - start, 1),
    }
    write_table(doc, cases, out_path)


if __name__ == "__main__":
    main()
