#!/usr/bin/env python3
"""Makes disort_ground.json: DISORT reference values for homogeneous plane-parallel slabs over a
Lambertian ground.

    pip install pydisort==1.8.13          # cdisort 2.1.3 (PyPI wheel for CPython 3.11)
    python3 tests/data/make_disort_ground.py [OUT.json]     # default: disort_ground.json

(about 20 s on one core). Same set-up, conventions and JSON layout as
crates/formfactor/tests/data/make_disort_slabs.py (disort_slabs.json), except for the lower
boundary: one homogeneous layer of optical depth tau, exact Henyey-Greenstein moments
chi_l = g^l, a collimated beam of flux 1 (on a plane perpendicular to it) at cos(theta0) = mu0
and phi0 = 0 on the top, a Lambertian ground of albedo ground_albedo under the bottom, no thermal
emission, no other illumination, intensity correction off. Fluxes are divided by mu0; radiance
is per unit incident beam flux. Each user-angle radiance is the median of DISORT's values at five
nearby cosines (nearby() below, as in make_disort_slabs.py).

Cases: tau in {0.5, 1, 2, 4} x g in {0, 0.6} x albedo in {0.9, 1} x ground albedo in
{0, 0.3, 0.8} x mu0 in {1, 0.6} (96 cases).

Streams: 64 (cdisort's always-on delta-M truncates f = g^nstr = 0.6^64 = 6e-15: nothing).
Every case is recomputed with 32 and with 128 streams; the maximum relative difference over
R, T_diffuse, ground_up and all radiances (ground terms only over a reflecting ground) is
recorded per case and in the header. Measured (pydisort 1.8.13): 64 vs 32 streams at most
7.7e-6, 64 vs 128 streams at most 2.8e-6. Both worst values are the transmitted radiance at
mu = mu0 = 1 (looking straight into the beam; at g = 0.6 for 32 streams, g = 0 for 128); with
mu0 = 0.6 every case agrees to 9.4e-7 (32 streams) and 7e-9 (128 streams). Do not use 256
streams as a check at mu0 = 1: there cdisort 2.1.3 returns NaN user-angle radiances and a
direct beam off by 2e-5 (200 streams gave finite values in the one case tried); the
script refuses non-finite values.

Checks made by this script (it stops if one fails):
- ground_up = ground_albedo (T_diffuse + T_direct) to 1e-6 relative (Lambertian ground);
  for ground albedo 0 |ground_up| < 1e-9;
- ground_radiance (upward radiance just above the ground, mu = 1 and 0.4, phi = 0) equals
  ground_up mu0 / pi (isotropic) to 1e-5 relative; for ground albedo 0 |radiance| < 1e-9;
- energy: A = 1 - R - T_diffuse - T_direct + ground_up (absorbed in the slab) agrees with
  DISORT's own flux divergence dF/dtau integrated over the slab (Simpson, 2049 levels) to 1e-6;
  for albedo 1 |A| < 1e-8.
"""

import math
import pathlib
import sys
import time

import numpy as np
import pydisort
import torch
from pydisort import Disort, DisortOptions

# The median-of-five cosines, rounding and the table writer of the black-ground slabs' script.
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[2] / "crates/formfactor/tests/data"))
from make_disort_slabs import nearby, round_sig, write_table  # noqa: E402

TAUS = [0.5, 1.0, 2.0, 4.0]
GS = [0.0, 0.6]
ALBEDOS = [0.9, 1.0]
GROUND_ALBEDOS = [0.0, 0.3, 0.8]
MU0S = [1.0, 0.6]
MUS = [1.0, 0.7, 0.4]
PHIS = [0.0, 90.0, 180.0]
GROUND_MUS = [1.0, 0.4]
GROUND_PHIS = [0.0]

NSTR = 64
NMOM = 256
CHECK_LOW = (32, 256)
CHECK_HIGH = (128, 256)
DIVERGENCE_LEVELS = 2049

F64 = torch.float64

def disort(tau, albedo, g, ground_albedo, mu0, nstr, nmom, user_tau, user_mu, phis):
    """One DISORT run; returns (fluxes (level, [rfldir, fldn, flup, dfdt, uavg, ...]),
    radiances (phi, level, mu))."""
    op = DisortOptions().flags("usrtau,usrang,lamber,quiet")
    op.ds().nlyr = 1
    op.ds().nstr = nstr
    op.ds().nmom = nmom
    op.ds().nphase = nstr
    op.user_tau(np.array(user_tau))
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
        albedo=torch.tensor([[ground_albedo]], dtype=F64),
        fluor=torch.tensor([[0.0]], dtype=F64),
        fisot=torch.tensor([[0.0]], dtype=F64),
    )
    return ds.gather_flx()[0, 0].numpy(), ds.gather_rad()[0, 0].numpy()


def run(tau, albedo, g, ground_albedo, mu0, nstr=NSTR, nmom=NMOM):
    """Fluxes and radiances of one slab over its ground. The radiances are dicts
    "mu=.." -> "phi=.." -> value, each the median over nearby(mu)."""
    mus = sorted({x for m in MUS + GROUND_MUS for x in nearby(m)})
    # DISORT wants the cosines increasing: downward (negative) first, then upward.
    user_mu = sorted([-m for m in mus] + mus)
    flx, rad = disort(tau, albedo, g, ground_albedo, mu0, nstr, nmom, [0.0, tau], user_mu, PHIS)

    def median(level, sign, table_mus, table_phis):
        return {
            f"mu={m}": {
                f"phi={p:g}": sorted(
                    float(rad[PHIS.index(p), level, user_mu.index(sign * x)]) for x in nearby(m)
                )[2]
                for p in table_phis
            }
            for m in table_mus
        }

    return {
        "R": float(flx[0, 2] / mu0),
        "T_diffuse": float(flx[1, 1] / mu0),
        "T_direct": float(flx[1, 0] / mu0),
        "ground_up": float(flx[1, 2] / mu0),
        "reflected_radiance": median(0, 1, MUS, PHIS),
        "transmitted_diffuse_radiance": median(1, -1, MUS, PHIS),
        "ground_radiance": median(1, 1, GROUND_MUS, GROUND_PHIS),
    }


def absorbed_by_divergence(tau, albedo, g, ground_albedo, mu0):
    """Absorbed fraction from DISORT's flux divergence (which includes the direct beam),
    integrated over the slab by Simpson's rule on DIVERGENCE_LEVELS levels, / mu0."""
    levels = np.linspace(0.0, tau, DIVERGENCE_LEVELS)
    flx, _ = disort(tau, albedo, g, ground_albedo, mu0, NSTR, NMOM, levels, [-1.0, 1.0], [0.0])
    d = flx[:, 3]
    h = tau / (DIVERGENCE_LEVELS - 1)
    return float(h / 3 * (d[0] + d[-1] + 4 * d[1:-1:2].sum() + 2 * d[2:-1:2].sum()) / mu0)


def values(result, ground_albedo):
    """R, T_diffuse, (ground_up) and every radiance of a result, in a fixed order. The ground
    terms only over a reflecting ground (over a black one they are round-off, ~1e-11)."""
    out = [result["R"], result["T_diffuse"]]
    tables = ["reflected_radiance", "transmitted_diffuse_radiance"]
    if ground_albedo > 0.0:
        out.append(result["ground_up"])
        tables.append("ground_radiance")
    for key in tables:
        for row in result[key].values():
            out.extend(row.values())
    return out


def max_rel_diff(a, b, ground_albedo):
    va, vb = values(a, ground_albedo), values(b, ground_albedo)
    # Python's max() silently skips NaN when it is not first: refuse it instead.
    assert all(math.isfinite(x) for x in va + vb), "non-finite DISORT value"
    return max(abs(x / y - 1.0) for x, y in zip(va, vb) if y != 0.0)


def main():
    out_path = sys.argv[1] if len(sys.argv) > 1 else "disort_ground.json"
    torch.set_num_threads(1)
    start = time.time()
    cases = []
    worst = {"low": 0.0, "high": 0.0, "lambert": 0.0, "iso": 0.0, "black": 0.0, "energy": 0.0}
    worst_conservative = 0.0
    for tau in TAUS:
        for g in GS:
            for a in ALBEDOS:
                for ag in GROUND_ALBEDOS:
                    for mu0 in MU0S:
                        res = run(tau, a, g, ag, mu0)
                        r, t, td, up = res["R"], res["T_diffuse"], res["T_direct"], res["ground_up"]
                        ground = [v for row in res["ground_radiance"].values() for v in row.values()]
                        label = f"tau {tau:g} g {g} a {a} ground {ag} mu0 {mu0}"
                        if ag > 0.0:
                            lam = abs(up / (ag * (t + td)) - 1.0)
                            assert lam < 1e-6, f"{label}: ground_up / (A_g T) - 1 = {lam:.2e}"
                            worst["lambert"] = max(worst["lambert"], lam)
                            iso_want = up * mu0 / math.pi
                            iso = max(abs(v / iso_want - 1.0) for v in ground)
                            assert iso < 1e-5, f"{label}: ground radiance not isotropic, {iso:.2e}"
                            worst["iso"] = max(worst["iso"], iso)
                        else:
                            iso_want = 0.0
                            iso = None
                            black = max(abs(x) for x in ground + [up])
                            assert black < 1e-9, f"{label}: black ground shows {black:.2e}"
                            worst["black"] = max(worst["black"], black)
                        absorbed = 1.0 - r - t - td + up
                        by_div = absorbed_by_divergence(tau, a, g, ag, mu0)
                        energy = abs(absorbed - by_div)
                        assert energy < 1e-6, f"{label}: A {absorbed} vs divergence {by_div}"
                        worst["energy"] = max(worst["energy"], energy)
                        if a == 1.0:
                            assert abs(absorbed) < 1e-8, f"{label}: albedo 1 absorbs {absorbed}"
                            worst_conservative = max(worst_conservative, abs(absorbed))
                        low = max_rel_diff(run(tau, a, g, ag, mu0, *CHECK_LOW), res, ag)
                        high = max_rel_diff(run(tau, a, g, ag, mu0, *CHECK_HIGH), res, ag)
                        worst["low"] = max(worst["low"], low)
                        worst["high"] = max(worst["high"], high)
                        rs = lambda table: {
                            m: {p: round_sig(v) for p, v in row.items()}
                            for m, row in table.items()
                        }
                        case = {
                            "tau": tau,
                            "albedo": a,
                            "g": g,
                            "ground_albedo": ag,
                            "mu0": mu0,
                            "R": round_sig(r),
                            "T_diffuse": round_sig(t),
                            "T_direct": round_sig(td),
                            "T_direct_exact": round_sig(math.exp(-tau / mu0)),
                            "ground_up": round_sig(up),
                            "A": round_sig(absorbed),
                            "A_ground": round_sig(t + td - up),
                            "reflected_radiance": rs(res["reflected_radiance"]),
                            "transmitted_diffuse_radiance": rs(res["transmitted_diffuse_radiance"]),
                            "ground_radiance": rs(res["ground_radiance"]),
                            "ground_radiance_lambert": round_sig(iso_want),
                            "ground_radiance_max_rel_dev": None if iso is None else round_sig(iso, 3),
                            "convergence": {
                                f"max_rel_diff_vs_{CHECK_LOW[0]}_streams": round_sig(low, 3),
                                f"max_rel_diff_vs_{CHECK_HIGH[0]}_streams": round_sig(high, 3),
                            },
                        }
                        cases.append(case)
                        print(
                            f"{label}: R {r:.6f} T {t + td:.6f} up {up:.6f} A {absorbed:.6f} "
                            f"vs {CHECK_LOW[0]} {low:.1e} vs {CHECK_HIGH[0]} {high:.1e}",
                            file=sys.stderr,
                        )
    doc = {
        "description": (
            f"Plane-parallel homogeneous slab over a Lambertian ground, DISORT (cdisort 2.1.3 via "
            f"pydisort {pydisort.__version__}). Collimated beam of flux 1 on a plane "
            "perpendicular to the beam, incident on the top at cos(theta0)=mu0, phi0=0; "
            "Lambertian lower boundary of albedo ground_albedo; no thermal emission; no other "
            "illumination. Fluxes are divided by mu0, radiance is per unit incident beam flux. "
            "Made by make_disort_ground.py beside this file."
        ),
        "generator": "tests/data/make_disort_ground.py",
        "pydisort_version": pydisort.__version__,
        "solver": {
            "nstr": NSTR,
            "nmom": NMOM,
            "phase_moments": "exact Henyey-Greenstein, chi_l = g^l",
            "delta_M": (
                f"cdisort always applies delta-M with truncated fraction f = g^{NSTR} "
                f"(= {0.6 ** NSTR:.0e} at g = 0.6: no effect)"
            ),
            "albedo_one": "albedo 1.0 is passed as is (cdisort uses 1 - 2.2e-14 internally)",
            "intensity_correction": "OFF (as in disort.json and disort_slabs.json)",
            "user_angles": (
                "each radiance is the median of DISORT's values at five cosines mu (1 + k 2e-4), "
                "k = -2..2 (mu = 1: 1 - k 2e-4, k = 0..4), as in disort_slabs.json"
            ),
            "surface": "lamber, albedo = ground_albedo (passed as the albedo tensor)",
            "convergence_check": (
                f"every case recomputed with {CHECK_LOW[0]} and {CHECK_HIGH[0]} streams; max "
                "relative difference over R, T_diffuse, ground_up and all radiances (ground terms "
                f"only for ground_albedo > 0), all cases: {worst['low']:.2e} vs {CHECK_LOW[0]} "
                f"streams, {worst['high']:.2e} vs {CHECK_HIGH[0]} streams. Per case in "
                "'convergence'."
            ),
            "max_rel_diff_vs_32_streams": round_sig(worst["low"], 3),
            "max_rel_diff_vs_128_streams": round_sig(worst["high"], 3),
            "checks": (
                "ground_up = ground_albedo (T_diffuse + T_direct) to "
                f"{worst['lambert']:.1e} relative; ground_radiance = ground_up mu0/pi "
                f"(isotropic) to {worst['iso']:.1e} relative; black ground (ground_albedo 0): "
                f"ground_up and ground_radiance below {worst['black']:.1e} in magnitude; A agrees "
                "with DISORT's flux divergence integrated over the slab "
                f"({DIVERGENCE_LEVELS} levels, Simpson) to {worst['energy']:.1e}; albedo 1: "
                f"|A| <= {worst_conservative:.1e}"
            ),
        },
        "units": {
            "R": "upward diffuse flux at top / mu0",
            "T_diffuse": "downward diffuse flux at bottom / mu0",
            "T_direct": "downward direct-beam flux at bottom / mu0 (= exp(-tau/mu0))",
            "ground_up": (
                "upward flux at the bottom (leaving the ground) / mu0 = ground_albedo "
                "(T_diffuse + T_direct)"
            ),
            "A": (
                "absorbed in the slab: 1 - R - T_diffuse - T_direct + ground_up; "
                "R + A + A_ground = 1"
            ),
            "A_ground": "absorbed by the ground: T_diffuse + T_direct - ground_up",
            "radiance": (
                "radiance per unit incident beam flux (flux 1 on a plane perpendicular to the "
                "beam); i.e. a Lambertian white reflector under the same beam would show "
                "radiance mu0/pi"
            ),
            "ground_radiance": (
                "upward radiance just above the ground (bottom level), mu = 1 and 0.4, phi = 0; "
                "ground_radiance_lambert = ground_up mu0/pi, the isotropic value it must equal; "
                "ground_radiance_max_rel_dev = max |ground_radiance / ground_radiance_lambert - 1| "
                "(null for ground_albedo 0)"
            ),
        },
        "angles": {
            "mu": (
                "cosine of the angle between the radiance travel direction and the outward normal "
                "of the face: reflected_radiance = upward-travelling radiance at the top face "
                "(cos w.r.t. +z up), transmitted_diffuse_radiance = downward-travelling diffuse "
                "radiance at the bottom face (cos w.r.t. -z; includes light reflected by the "
                "ground and scattered back down, excludes the collimated beam), ground_radiance "
                "= upward-travelling radiance at the bottom face (cos w.r.t. +z); mu=1 is the "
                "normal direction"
            ),
            "phi": (
                "relative azimuth between the horizontal component of the radiance TRAVEL "
                "direction and the horizontal TRAVEL direction of the incident beam (DISORT phi - "
                "phi0), as in disort_slabs.json; phi=0: same horizontal direction as the beam; "
                "for mu0=1 or mu=1 the value does not depend on phi"
            ),
        },
        "parameters": {
            "tau": TAUS,
            "albedo": ALBEDOS,
            "g": GS,
            "ground_albedo": GROUND_ALBEDOS,
            "mu0": MU0S,
            "mu": MUS,
            "phi_deg": PHIS,
            "ground_mu": GROUND_MUS,
            "ground_phi_deg": GROUND_PHIS,
        },
        "wall_time_s": round(time.time() - start, 1),
    }
    write_table(doc, cases, out_path)


if __name__ == "__main__":
    main()
