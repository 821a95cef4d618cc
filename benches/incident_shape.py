#!/usr/bin/env python3
"""How well two shapes of the emitters' uncollided light scatter it (docs/physics.md, *Light
from emitting cells*): at points near a 4-wide cube emitting uniformly in a uniform medium,
the light Henyey-Greenstein g = 0.85 scatters toward cos(theta) from the flux vector, exact
(the light's own Legendre moments, from rays over the sphere) against

- a Henyey-Greenstein lobe of the light's mean cosine (the shape before), and
- a cone of uniform light and an isotropic rest with the light's first two moments
  (medium::phase::IncidentShape).

Prints the relative error of each in percent per cos(theta). A second table takes points
beside the cube and farther out, where the light is not symmetric about its flux vector:
per point its mean cosine and the worst error toward 40 directions all around of the cone
and rest, and of the light sorted into the 192 bins of medium::phase::DirectionBins (each
direction to its nearest point of a Fibonacci lattice), each bin's light a uniform cone about
its own mean direction (ShapeScattering::eval_binned). Pure Python, about 15 s:

    python3 benches/incident_shape.py
"""

import math

G = 0.85
TERMS = 200
COSINES = [1.0, 0.95, 0.9, 0.8, 0.6, 0.3, 0.0, -0.5, -1.0]


def legendre(x, n):
    p = [1.0, x]
    for l in range(1, n):
        p.append(((2 * l + 1) * x * p[l] - l * p[l - 1]) / (l + 1))
    return p


def cone_moments(c, n):
    """Legendre moments of light spread uniformly over a cone of cosine c."""
    p = legendre(c, n + 2)
    return [1.0] + [(p[l - 1] - p[l + 1]) / ((2 * l + 1) * (1 - c)) for l in range(1, n + 1)]


def scattered(moments, mu):
    """Henyey-Greenstein G's scattering of light with these Legendre moments, toward mu."""
    p = legendre(mu, TERMS)
    return sum((2 * l + 1) / (4 * math.pi) * G**l * moments[l] * p[l] for l in range(TERMS + 1))


def hg(g, mu):
    return (1 - g * g) / (4 * math.pi * (1 + g * g - 2 * g * mu) ** 1.5)


def chord(o, d, lo, hi):
    t0, t1 = -1e30, 1e30
    for i in range(3):
        if abs(d[i]) < 1e-15:
            if not lo[i] <= o[i] <= hi[i]:
                return None
            continue
        a, b = (lo[i] - o[i]) / d[i], (hi[i] - o[i]) / d[i]
        t0, t1 = max(t0, min(a, b)), min(t1, max(a, b))
    return (max(t0, 0.0), t1 - max(t0, 0.0)) if t1 > max(t0, 0.0) else None


def light_at(point, sigma, n_theta=240, n_phi=120):
    """(direction of travel, weight) samples of the cube's uncollided light at point."""
    samples = []
    for i in range(n_theta):
        ct = -1 + (i + 0.5) * 2 / n_theta
        st = math.sqrt(1 - ct * ct)
        for k in range(n_phi):
            ph = (k + 0.5) * 2 * math.pi / n_phi
            d = (st * math.cos(ph), st * math.sin(ph), ct)
            hit = chord(point, d, (-2, -2, -4), (2, 2, 0))
            if hit:
                t0, length = hit
                radiance = (1 - math.exp(-sigma * length)) / sigma * math.exp(-sigma * t0)
                samples.append(((-d[0], -d[1], -d[2]), radiance))
    return samples


for x, z in [(0, 0.5), (0, 1.5), (0, 3), (0, 6), (1.5, 1.5), (2.5, 2.5)]:
    samples = light_at((x, 0.0, z), 0.6)
    phi = sum(w for _, w in samples)
    j = [sum(w * v[i] for v, w in samples) for i in range(3)]
    axis = [c / math.sqrt(sum(c * c for c in j)) for c in j]
    moments = [0.0] * (TERMS + 1)
    for v, w in samples:
        for l, p in enumerate(legendre(sum(a * b for a, b in zip(v, axis)), TERMS)):
            moments[l] += w / phi * p
    f1, f2 = moments[1], moments[2]
    exact = [scattered(moments, mu) for mu in COSINES]
    lobe = [hg(G * f1, mu) for mu in COSINES]
    c = f2 / f1
    weight = 2 * f1 / (1 + c)
    if weight > 1:
        weight, c = 1.0, 2 * f1 - 1
    cone = cone_moments(c, TERMS)
    shaped = [weight * scattered(cone, mu) + (1 - weight) / (4 * math.pi) for mu in COSINES]
    print(f"point ({x}, {z}) above the cube's top face: mean cosine {f1:.3f}")
    print("  cos(theta)             ", " ".join(f"{mu:+6.2f}" for mu in COSINES))
    for name, model in [("lobe of the mean cosine", lobe), ("cone and rest          ", shaped)]:
        print(f"  {name}", " ".join(f"{100 * (m / e - 1):+5.1f}%" for m, e in zip(model, exact)))


def fibonacci(n):
    """medium::environment::fibonacci_directions."""
    golden = math.pi * (3 - math.sqrt(5))
    out = []
    for i in range(n):
        z = 1 - (2 * i + 1) / n
        r = math.sqrt(max(0.0, 1 - z * z))
        out.append((r * math.cos(golden * i), r * math.sin(golden * i), z))
    return out


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def unit(a):
    length = math.sqrt(dot(a, a))
    return [x / length for x in a]


BINS = fibonacci(192)
OUTGOING = fibonacci(40)


def cone_and_rest(samples):
    phi = sum(w for _, w in samples)
    j = [sum(w * v[i] for v, w in samples) for i in range(3)]
    f1, axis = math.sqrt(dot(j, j)) / phi, unit(j)
    f2 = sum(w * (3 * dot(v, axis) ** 2 - 1) / 2 for v, w in samples) / phi
    c = f2 / f1
    weight = 2 * f1 / (1 + c)
    if weight > 1:
        weight, c = 1.0, 2 * f1 - 1
    cone = cone_moments(min(c, 1 - 1e-9), TERMS)
    return f1, [weight * scattered(cone, dot(axis, o)) + (1 - weight) / (4 * math.pi)
                for o in OUTGOING]


def binned(samples):
    groups = {}
    for v, w in samples:
        k = max(range(len(BINS)), key=lambda i: dot(v, BINS[i]))
        groups.setdefault(k, []).append((v, w))
    phi = sum(w for _, w in samples)
    total = [0.0] * len(OUTGOING)
    for group in groups.values():
        share = sum(w for _, w in group)
        m = [sum(w * v[i] for v, w in group) / share for i in range(3)]
        mean = min(math.sqrt(dot(m, m)), 1 - 1e-9)
        cone = cone_moments(2 * mean - 1, TERMS)
        for i, o in enumerate(OUTGOING):
            total[i] += share / phi * scattered(cone, dot(unit(m), o))
    return total


print()
print("every direction (40 around), worst error: cone and rest, 192 bins")
for point in [(0, 0, 0.5), (0, 0, 3), (0, 0, 6), (2.5, 0, -2), (2.5, 0, 0.5),
              (2.5, 2.5, 0.5), (4.5, 0, -2), (6.5, 0, -2), (9, 0, -2)]:
    samples = light_at(point, 0.6, 160, 80)
    phi = sum(w for _, w in samples)
    exact = [sum(w * hg(G, dot(v, o)) for v, w in samples) / phi for o in OUTGOING]
    f1, shaped = cone_and_rest(samples)
    binned_light = binned(samples)
    worst = [max(abs(m / e - 1) for m, e in zip(model, exact)) for model in (shaped, binned_light)]
    print(f"  point {point}: mean cosine {f1:.3f}, cone and rest {100 * worst[0]:5.1f} %, "
          f"bins {100 * worst[1]:5.1f} %")
