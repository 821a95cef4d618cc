//! Linear face fluxes for the face-coupled sweep ([`OrdinatesOptions::linear_faces`]): each
//! face's flux carries its mean and its first moments along the face's two tangential
//! coordinates, so that flux crossing a side face keeps the profile it had across it.
//!
//! With uniform faces, a piece that crosses a side face re-enters the next cell spread over
//! the whole face whatever profile it left with: a numerical diffusion across the layers of
//! order `σt h`, which grows with grazing crossings and lets thick, nearly conservative slabs
//! transmit too much (τ = 64, 64 layers, albedo 0.99: +118 % against DISORT;
//! docs/validation.md, *Which part of the sweep lets the light through*).
//!
//! Conventions, in a piece's canonical frame (every direction component ≥ 0, each slot's
//! coordinate from 0 on its upstream face to 1 on its downstream one): the face of slot `k`
//! has tangential slots [`TANGENTS`]`[k]`; a face flux is `m + s₁ x₁ + s₂ x₂` per unit area,
//! `x` the tangential coordinates from −1 to 1, stored as `[m, s₁, s₂]` (moment `i`). The
//! tables are integrated exactly along the chords: every chord is parametrised by its exit
//! point, each exit face split into the convex polygons on which the entry face is constant,
//! and each polygon integrated by collapsed Gauss rules on its triangles.
//!
//! Core types: [`FaceMoments`] (one piece's tables at the source table's nodes),
//! [`MomentTerms`] (the moments' coefficients at one of [`MOMENT_NODES`] optical sides) and
//! [`FaceStep`] (one cell's step: source, transmission, mean radiance, the one-cell periodic
//! loops).
//!
//! [`OrdinatesOptions::linear_faces`]: super::OrdinatesOptions::linear_faces

use glam::DVec3;

use super::sweep::{table_coordinate, CellTerms, SlopeTerms};

/// Moments per face: the mean and one slope per tangential coordinate.
pub(crate) const MOMENTS: usize = 3;

/// The tangential slots of the face of slot `k`, in increasing order.
pub(crate) const TANGENTS: [[usize; 2]; 3] = [[1, 2], [0, 2], [0, 1]];

/// Gauss points per side of a triangle's collapsed rule.
const TRIANGLE_GAUSS: usize = 16;

/// Table nodes: the optical sides of the source table's nodes.
const NODES: usize = super::sweep::SOURCE_TABLE_LEN;

/// One piece's linear-face tables at the source table's nodes `τ0 = σt h` (units of the cell
/// side; per unit flux entering, per unit source density, per unit source slope).
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct FaceMoments {
    /// `T[(3a + i)·9 + 3b + j]`: moment `j` of what leaves unattenuated through face `b` of
    /// unit moment `i` entering through face `a` (moment 0: unit flux, spread uniformly; a
    /// slope moment carries no flux of its own).
    transmit: Vec<[f64; 81]>,
    /// `M[3a + i]`: the mean track (units of h) of moment `i` entering through `a`.
    inflow_track: Vec<[f64; 9]>,
    /// `E[3b + j]`: moment `j` of what a source uniform in the cell sends out through `b`.
    exit: Vec<[f64; 9]>,
    /// `q`: the uniform source's mean track.
    source_track: Vec<f64>,
    /// `G[9c + 3b + j]`: moment `j` of what the source `x_c` (from −1 upstream to 1
    /// downstream along slot `c`) sends out through `b`.
    slope_exit: Vec<[f64; 27]>,
    /// Thin cells: `T ≈ T0 − τ0 T1`, `M ≈ M0 − τ0 M1`, `E ≈ E0 − τ0 E1`, `q ≈ q0 − τ0 q1`,
    /// `G ≈ G0 − τ0 G1`.
    thin_transmit: [[f64; 81]; 2],
    thin_inflow: [[f64; 9]; 2],
    thin_exit: [[f64; 9]; 2],
    thin_source: [f64; 2],
    thin_slope_exit: [[f64; 27]; 2],
}

/// A cell's linear-face coefficients at one `τ0`, made exactly conservative.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FaceTable {
    pub transmit: [f64; 81],
    pub inflow_track: [f64; 9],
    pub exit: [f64; 9],
    pub source_track: f64,
}

/// Points and weights of a collapsed Gauss rule on the convex polygon `poly` (a fan of
/// triangles from its first vertex).
fn polygon_rule(poly: &[[f64; 2]], gauss: &[(f64, f64)], out: &mut Vec<([f64; 2], f64)>) {
    let v0 = poly[0];
    for k in 1..poly.len().saturating_sub(1) {
        let (v1, v2) = (poly[k], poly[k + 1]);
        let e1 = [v1[0] - v0[0], v1[1] - v0[1]];
        let e2 = [v2[0] - v1[0], v2[1] - v1[1]];
        let jac = (e1[0] * (v2[1] - v0[1]) - e1[1] * (v2[0] - v0[0])).abs();
        if jac < 1e-300 {
            continue;
        }
        for &(xi, wx) in gauss {
            for &(eta, we) in gauss {
                let p = [
                    v0[0] + xi * e1[0] + xi * eta * e2[0],
                    v0[1] + xi * e1[1] + xi * eta * e2[1],
                ];
                out.push((p, wx * we * xi * jac));
            }
        }
    }
}

/// Sutherland–Hodgman: the part of convex `poly` where `c0 p + c1 q + c2 ≤ 0`.
fn clip(poly: &[[f64; 2]], c: [f64; 3]) -> Vec<[f64; 2]> {
    let mut out = Vec::with_capacity(poly.len() + 1);
    let f = |p: [f64; 2]| c[0] * p[0] + c[1] * p[1] + c[2];
    for i in 0..poly.len() {
        let (p, q) = (poly[i], poly[(i + 1) % poly.len()]);
        let (fp, fq) = (f(p), f(q));
        if fp <= 0.0 {
            out.push(p);
        }
        if (fp < 0.0 && fq > 0.0) || (fq < 0.0 && fp > 0.0) {
            let t = fp / (fp - fq);
            out.push([p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1])]);
        }
    }
    out
}

/// Gauss–Legendre nodes and weights on (0, 1), `(node, weight)`; the weights sum to 1.
pub fn gauss_legendre_unit(n: usize) -> Vec<(f64, f64)> {
    // Newton on P_n from Chebyshev guesses.
    (0..n)
        .map(|i| {
            let mut x = (std::f64::consts::PI * (i as f64 + 0.75) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            let w = 2.0 / ((1.0 - x * x) * dp * dp);
            (0.5 * (x + 1.0), 0.5 * w)
        })
        .collect()
}

/// One chord of the unit cube in the canonical frame, by its exit point.
struct Chord {
    /// Exit face (slot) and entry face (slot).
    exit: usize,
    entry: usize,
    /// `ψ_j`: `1, 3 x₁, 3 x₂` at the exit point (the moments' projections).
    exit_moments: [f64; 3],
    /// `φ_i`: `1, x₁, x₂` at the entry point.
    entry_profile: [f64; 3],
    /// The exit point and the direction.
    point: [f64; 3],
    direction: [f64; 3],
    length: f64,
    /// `ω-weight × |ω_b| dA`.
    weight: f64,
}

/// Visits the chords of directions `dirs` (canonical: every component ≥ 0) through the unit
/// cube, split exactly where their entry face changes.
fn for_chords(dirs: &[(DVec3, f64)], mut visit: impl FnMut(&Chord)) {
    let gauss = gauss_legendre_unit(TRIANGLE_GAUSS);
    let square = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let mut points = Vec::new();
    for &(w, wt) in dirs {
        let w = w.abs().to_array();
        for b in (0..3).filter(|&b| w[b] > 0.0) {
            let [u, v] = TANGENTS[b];
            // The exit point's coordinate along slot `ax` as `c0 p + c1 q + c2`.
            let coordinate = |ax: usize| -> [f64; 3] {
                [
                    f64::from(u8::from(ax == u)),
                    f64::from(u8::from(ax == v)),
                    f64::from(u8::from(ax == b)),
                ]
            };
            for entry in (0..3).filter(|&g| w[g] > 0.0) {
                // Where the distance back to face `entry` is the least.
                let mut poly = square.to_vec();
                for m in (0..3).filter(|&m| m != entry && w[m] > 0.0) {
                    if poly.len() < 3 {
                        break;
                    }
                    let (cg, cm) = (coordinate(entry), coordinate(m));
                    poly = clip(
                        &poly,
                        std::array::from_fn(|k| cg[k] / w[entry] - cm[k] / w[m]),
                    );
                }
                if poly.len() < 3 {
                    continue;
                }
                points.clear();
                polygon_rule(&poly, &gauss, &mut points);
                for &([p, q], area) in &points {
                    let mut point = [0.0; 3];
                    point[b] = 1.0;
                    point[u] = p;
                    point[v] = q;
                    let length = point[entry] / w[entry];
                    let start: [f64; 3] = std::array::from_fn(|k| point[k] - length * w[k]);
                    let [eu, ev] = TANGENTS[entry];
                    visit(&Chord {
                        exit: b,
                        entry,
                        exit_moments: [1.0, 3.0 * (2.0 * p - 1.0), 3.0 * (2.0 * q - 1.0)],
                        entry_profile: [1.0, 2.0 * start[eu] - 1.0, 2.0 * start[ev] - 1.0],
                        point,
                        direction: w,
                        length,
                        weight: wt * w[b] * area,
                    });
                }
            }
        }
    }
}

/// `(1 − e^{−τ l}) / τ` and `∫_0^l t e^{−τ t} dt`, by series where the closed forms cancel.
fn track_integrals(tau: f64, l: f64) -> (f64, f64) {
    let tl = tau * l;
    let g1 = -(-tl).exp_m1() / tau;
    let g2 = if tl < 1e-3 {
        l * l * (0.5 - tl / 3.0 + tl * tl / 8.0)
    } else {
        (1.0 - (-tl).exp() * (1.0 + tl)) / (tau * tau)
    };
    (g1, g2)
}

impl FaceMoments {
    /// The tables for the directions `dirs` (with weights) of one piece, in its canonical
    /// axes.
    pub(crate) fn of(dirs: &[(DVec3, f64)]) -> FaceMoments {
        let nodes: Vec<f64> = (0..NODES).map(super::sweep::table_node).collect();
        let mut t = FaceMoments {
            transmit: vec![[0.0; 81]; NODES],
            inflow_track: vec![[0.0; 9]; NODES],
            exit: vec![[0.0; 9]; NODES],
            source_track: vec![0.0; NODES],
            slope_exit: vec![[0.0; 27]; NODES],
            thin_transmit: [[0.0; 81]; 2],
            thin_inflow: [[0.0; 9]; 2],
            thin_exit: [[0.0; 9]; 2],
            thin_source: [0.0; 2],
            thin_slope_exit: [[0.0; 27]; 2],
        };
        let total_w: f64 = dirs.iter().map(|d| d.1).sum();
        // Unit flux through face a: Σ ω-weight |ω_a| over the unit face.
        let face_w: [f64; 3] =
            std::array::from_fn(|a| dirs.iter().map(|(w, wt)| wt * w.abs()[a]).sum());
        // The volume mean of each coordinate x_c = 2 y_c − 1 as the rule integrates it
        // (zero to rounding), taken off the linear source so that it emits nothing in all.
        let mut mean = [0.0; 3];
        let mut volume = 0.0;
        for_chords(dirs, |ch| {
            volume += ch.weight * ch.length;
            for (k, m) in mean.iter_mut().enumerate() {
                let l = ch.length;
                *m += ch.weight * ((2.0 * ch.point[k] - 1.0) * l - ch.direction[k] * l * l);
            }
        });
        let mean = mean.map(|m| m / volume);
        for_chords(dirs, |ch| {
            let (a, b, l) = (ch.entry, ch.exit, ch.length);
            let entry = ch.weight / face_w[a];
            let source = ch.weight / total_w;
            // The linear source `x_c − x̄_c = α − β t` at distance `t` back from the exit.
            let slope: [(f64, f64); 3] =
                std::array::from_fn(|c| (2.0 * ch.point[c] - 1.0 - mean[c], 2.0 * ch.direction[c]));
            for i in 0..MOMENTS {
                let fi = entry * ch.entry_profile[i];
                t.thin_inflow[0][3 * a + i] += fi * l;
                t.thin_inflow[1][3 * a + i] += fi * l * l / 2.0;
                for j in 0..MOMENTS {
                    let k = (3 * a + i) * 9 + 3 * b + j;
                    let f = fi * ch.exit_moments[j];
                    t.thin_transmit[0][k] += f;
                    t.thin_transmit[1][k] += f * l;
                }
            }
            for j in 0..MOMENTS {
                let e = source * ch.exit_moments[j];
                t.thin_exit[0][3 * b + j] += e * l;
                t.thin_exit[1][3 * b + j] += e * l * l / 2.0;
                for (c, &(alpha, beta)) in slope.iter().enumerate() {
                    let k = 9 * c + 3 * b + j;
                    t.thin_slope_exit[0][k] += e * (alpha * l - beta * l * l / 2.0);
                    t.thin_slope_exit[1][k] += e * (alpha * l * l / 2.0 - beta * l * l * l / 3.0);
                }
            }
            t.thin_source[0] += source * l * l / 2.0;
            t.thin_source[1] += source * l * l * l / 6.0;
            for (n, &tau0) in nodes.iter().enumerate() {
                let att = (-tau0 * l).exp();
                let (g1, g2) = track_integrals(tau0, l);
                for i in 0..MOMENTS {
                    let fi = entry * ch.entry_profile[i];
                    t.inflow_track[n][3 * a + i] += fi * g1;
                    for j in 0..MOMENTS {
                        t.transmit[n][(3 * a + i) * 9 + 3 * b + j] += fi * ch.exit_moments[j] * att;
                    }
                }
                for j in 0..MOMENTS {
                    let e = source * ch.exit_moments[j];
                    t.exit[n][3 * b + j] += e * g1;
                    for (c, &(alpha, beta)) in slope.iter().enumerate() {
                        t.slope_exit[n][9 * c + 3 * b + j] += e * (alpha * g1 - beta * g2);
                    }
                }
                t.source_track[n] += source * (tau0 * l + (-tau0 * l).exp_m1()) / (tau0 * tau0);
            }
        });
        t
    }

    /// The coefficients at `tau0` (`x = table_coordinate(tau0)`), exactly conservative:
    /// a unit flux's row keeps `Σ_b T_(a0)(b0) = 1 − τ0 M_a0`, a slope's row (no flux of its
    /// own) `Σ_b T_(ai)(b0) = −τ0 M_ai`, and the source `Σ_b E_b0 = 1 − τ0 q`.
    pub(crate) fn at(&self, tau0: f64, x: f64) -> FaceTable {
        let last = NODES - 1;
        let (mut t, mut m, mut e, q): ([f64; 81], [f64; 9], [f64; 9], f64);
        let thin = x <= 0.0;
        if thin {
            let ([t0, t1], [m0, m1], [e0, e1], [q0, q1]) = (
                &self.thin_transmit,
                &self.thin_inflow,
                &self.thin_exit,
                self.thin_source,
            );
            t = std::array::from_fn(|k| t0[k] - tau0 * t1[k]);
            m = std::array::from_fn(|k| m0[k] - tau0 * m1[k]);
            e = std::array::from_fn(|k| e0[k] - tau0 * e1[k]);
            q = q0 - tau0 * q1;
        } else if x >= last as f64 {
            // Thick cell: what gets through (edges' short chords, the faces' thin layers)
            // falls as 1/τ0.
            let r = super::sweep::table_node(last) / tau0;
            t = self.transmit[last].map(|v| v * r);
            e = self.exit[last].map(|v| v * r);
            m = [0.0; 9];
            for a in 0..3 {
                let sum: f64 = (0..3).map(|b| t[27 * a + 3 * b]).sum();
                m[3 * a] = (1.0 - sum) / tau0;
            }
            q = (1.0 - e[0] - e[3] - e[6]) / tau0;
        } else {
            let i = x as usize;
            let f = x - i as f64;
            let mix = |a: f64, b: f64| (1.0 - f) * a + f * b;
            t = std::array::from_fn(|k| mix(self.transmit[i][k], self.transmit[i + 1][k]));
            m = std::array::from_fn(|k| mix(self.inflow_track[i][k], self.inflow_track[i + 1][k]));
            e = std::array::from_fn(|k| mix(self.exit[i][k], self.exit[i + 1][k]));
            q = mix(self.source_track[i], self.source_track[i + 1]);
        }
        for a in 0..3 {
            // The unit flux's row: scale what is transmitted (all its moments) to what is
            // left after the track's extinction.
            let row = 27 * a;
            let sum: f64 = (0..3).map(|b| t[row + 3 * b]).sum();
            if sum > 0.0 {
                let scale = (1.0 - tau0 * m[3 * a]).max(0.0) / sum;
                for v in &mut t[row..row + 9] {
                    *v *= scale;
                }
            }
            // The slopes' rows: their mean track is what their transmitted flux lacks.
            for i in 1..MOMENTS {
                let row = (3 * a + i) * 9;
                m[3 * a + i] = if thin {
                    (0..3).map(|b| self.thin_transmit[1][row + 3 * b]).sum()
                } else {
                    -(0..3).map(|b| t[row + 3 * b]).sum::<f64>() / tau0
                };
            }
        }
        let sum = e[0] + e[3] + e[6];
        if sum > 0.0 {
            let scale = (1.0 - tau0 * q).max(0.0) / sum;
            for v in &mut e {
                *v *= scale;
            }
        }
        FaceTable {
            transmit: t,
            inflow_track: m,
            exit: e,
            source_track: q,
        }
    }

    /// `(G, q_c)` at `tau0`: the linear sources' exits (`9c + 3b + j`) and mean tracks,
    /// `τ0 q_c = −Σ_b G_c(b0)` so that a slope neither adds nor removes power.
    pub(crate) fn slope_at(&self, tau0: f64, x: f64) -> ([f64; 27], [f64; 3]) {
        let last = NODES - 1;
        let sums = |g: &[f64; 27]| -> [f64; 3] {
            std::array::from_fn(|c| g[9 * c] + g[9 * c + 3] + g[9 * c + 6])
        };
        if x <= 0.0 {
            let [g0, g1] = &self.thin_slope_exit;
            let g = std::array::from_fn(|k| g0[k] - tau0 * g1[k]);
            return (g, sums(g1));
        }
        let g: [f64; 27] = if x >= last as f64 {
            let r = super::sweep::table_node(last) / tau0;
            self.slope_exit[last].map(|v| v * r)
        } else {
            let i = x as usize;
            let f = x - i as f64;
            std::array::from_fn(|k| {
                (1.0 - f) * self.slope_exit[i][k] + f * self.slope_exit[i + 1][k]
            })
        };
        (g, sums(&g).map(|s| -s / tau0))
    }
}

/// Nodes of the linear faces' moment coefficients ([`MomentTerms`]): node 0 is `τ0 = 0`,
/// nodes 1… are 40 per decade from `10⁻⁴` to `10³`. A cell takes the node nearest its `σt* h`
/// (within ±2.9 %): the moments' coefficients are smooth in `τ0`, and a table per distinct
/// σt (24 k of them in `data/cloud.toml`'s cloud, 1 kB each per piece class) would not stay in
/// cache.
pub(crate) const MOMENT_NODES: usize = 282;
const MOMENT_NODES_PER_DECADE: f64 = 40.0;
const MOMENT_NODE_MIN_LOG10: f64 = -4.0;

/// `τ0` of moment node `n`.
pub(crate) fn moment_node_tau(n: usize) -> f64 {
    if n == 0 {
        0.0
    } else {
        10f64.powf(MOMENT_NODE_MIN_LOG10 + (n - 1) as f64 / MOMENT_NODES_PER_DECADE)
    }
}

/// The moment node nearest `tau0`.
pub(crate) fn moment_node_of(tau0: f64) -> u32 {
    let x = (tau0.log10() - MOMENT_NODE_MIN_LOG10) * MOMENT_NODES_PER_DECADE;
    if x.is_nan() || x < -0.5 {
        return 0;
    }
    (x.round() as usize + 1).min(MOMENT_NODES - 1) as u32
}

/// A piece's linear-face coefficients at one moment node, in its canonical slots like
/// [`CellTerms`] (a face's moments `[mean, slope along the first tangent, slope along the
/// second]`), beside the cell's own [`CellTerms`] and [`SlopeTerms`], which hold the means'
/// part exactly at the cell's σt*.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct MomentTerms {
    /// `T_(ki)(l0)` for the slopes `i = 1, 2` (index `6k + 3(i − 1) + l`): the flux a face's
    /// slope moves from one downstream face to another (it adds none: `Σ_l` is what the
    /// slope's own track extinguishes, `−σt h M_ki`).
    slope_to_mean: [f64; 18],
    /// `T_(ki)(lj)` for the slopes `j = 1, 2` out (index `6(3k + i) + 2l + j − 1`).
    to_moments: [f64; 54],
    /// `h E_lj`, `j = 1, 2` (index `2l + j − 1`): the uniform source's slopes out.
    source_moments: [f64; 6],
    /// `h G_c(lj)`, `j = 1, 2` (index `6c + 2l + j − 1`): a source slope's slopes out.
    slope_source_moments: [f64; 18],
}

impl MomentTerms {
    /// The coefficients at `tau0` for cells of side `h`.
    pub(crate) fn of(faces: &FaceMoments, tau0: f64, h: f64) -> MomentTerms {
        let x = table_coordinate(tau0);
        let t = faces.at(tau0, x);
        let (g, _) = faces.slope_at(tau0, x);
        let mut m = MomentTerms {
            slope_to_mean: [0.0; 18],
            to_moments: [0.0; 54],
            source_moments: [0.0; 6],
            slope_source_moments: [0.0; 18],
        };
        for k in 0..3 {
            for i in 0..3 {
                for l in 0..3 {
                    let row = (3 * k + i) * 9 + 3 * l;
                    if i > 0 {
                        m.slope_to_mean[6 * k + 3 * (i - 1) + l] = t.transmit[row];
                    }
                    for j in 1..3 {
                        m.to_moments[6 * (3 * k + i) + 2 * l + j - 1] = t.transmit[row + j];
                    }
                }
            }
        }
        for l in 0..3 {
            for j in 1..3 {
                m.source_moments[2 * l + j - 1] = h * t.exit[3 * l + j];
                for c in 0..3 {
                    m.slope_source_moments[6 * c + 2 * l + j - 1] = h * g[9 * c + 3 * l + j];
                }
            }
        }
        m
    }
}

/// One cell's step with linear faces: its exact means' coefficients and its moment node's.
pub(crate) struct FaceStep<'a> {
    pub ct: &'a CellTerms,
    pub st: Option<&'a SlopeTerms>,
    pub mt: &'a MomentTerms,
    /// `1 / (σt* h)` (0 in a cell without medium, whose slopes move no flux).
    pub inverse_tau: f64,
}

impl FaceStep<'_> {
    /// What the cell's source sends out (by slot, `3l + j`) and its mean radiance: the
    /// density `sd` and, with a linear source, its slopes per slot.
    #[inline(always)]
    pub(crate) fn source(&self, sd: f64, slopes: [f64; 3]) -> ([f64; 9], f64) {
        let (ct, mt) = (self.ct, self.mt);
        let mut out = [0.0; 9];
        let mut mean = sd * ct.source_mean;
        for l in 0..3 {
            out[3 * l] = sd * ct.source_out[l];
            out[3 * l + 1] = sd * mt.source_moments[2 * l];
            out[3 * l + 2] = sd * mt.source_moments[2 * l + 1];
        }
        if let Some(st) = self.st {
            for (c, &s) in slopes.iter().enumerate() {
                mean += s * st.mean[c];
                for l in 0..3 {
                    out[3 * l] += s * st.out[3 * c + l];
                    out[3 * l + 1] += s * mt.slope_source_moments[6 * c + 2 * l];
                    out[3 * l + 2] += s * mt.slope_source_moments[6 * c + 2 * l + 1];
                }
            }
        }
        (out, mean)
    }

    /// Outflow moments through the downstream faces (by slot) for `inflow` moments through
    /// the upstream ones and the source's `source_out`, and the mean radiance with the
    /// source's `source_mean`.
    #[inline(always)]
    pub(crate) fn step(
        &self,
        inflow: &[[f64; 3]; 3],
        source_out: &[f64; 9],
        source_mean: f64,
    ) -> ([[f64; 3]; 3], f64) {
        let (ct, mt) = (self.ct, self.mt);
        let mut o = [
            [source_out[0], source_out[1], source_out[2]],
            [source_out[3], source_out[4], source_out[5]],
            [source_out[6], source_out[7], source_out[8]],
        ];
        let mut mean = source_mean;
        let mut slope_flux = 0.0;
        for (k, face) in inflow.iter().enumerate() {
            mean += face[0] * ct.inflow_mean[k];
            for (l, out) in o.iter_mut().enumerate() {
                let moved = face[1] * mt.slope_to_mean[6 * k + l]
                    + face[2] * mt.slope_to_mean[6 * k + 3 + l];
                out[0] += face[0] * ct.transmit[3 * k + l] + moved;
                slope_flux += moved;
            }
            for (i, &v) in face.iter().enumerate() {
                let row = &mt.to_moments[6 * (3 * k + i)..6 * (3 * k + i) + 6];
                for (out, pair) in o.iter_mut().zip(row.chunks_exact(2)) {
                    out[1] += v * pair[0];
                    out[2] += v * pair[1];
                }
            }
        }
        // A slope's track extinguishes what its rows do not pass on (they carry no flux).
        (o, mean - slope_flux * self.inverse_tau)
    }

    /// [`step`](Self::step) in a cell without medium, for a uniform source density `sd`: the
    /// inflow's mean and slopes pass on to the downstream faces' means in their shares, and
    /// the faces' slopes are not carried across (they would cost the full 81 products per
    /// cell in the 88 % of `data/cloud.toml`'s box that is empty, where nothing is
    /// extinguished: a beam's profile only blurs within a cell's face there, as with uniform
    /// faces, and no power moves).
    #[inline(always)]
    pub(crate) fn vacuum_step(&self, inflow: &[[f64; 3]; 3], sd: f64) -> ([[f64; 3]; 3], f64) {
        let (ct, mt) = (self.ct, self.mt);
        let mut o = [[0.0; 3]; 3];
        let mut mean = sd * ct.source_mean;
        for (k, face) in inflow.iter().enumerate() {
            mean += face[0] * ct.inflow_mean[k];
            for (l, out) in o.iter_mut().enumerate() {
                out[0] += face[0] * ct.transmit[3 * k + l]
                    + face[1] * mt.slope_to_mean[6 * k + l]
                    + face[2] * mt.slope_to_mean[6 * k + 3 + l];
            }
        }
        for (l, out) in o.iter_mut().enumerate() {
            out[0] += sd * ct.source_out[l];
        }
        (o, mean)
    }

    /// `T_(ki)(lj)`, whichever table holds it.
    fn transmit(&self, k: usize, i: usize, l: usize, j: usize) -> f64 {
        match (i, j) {
            (0, 0) => self.ct.transmit[3 * k + l],
            (_, 0) => self.mt.slope_to_mean[6 * k + 3 * (i - 1) + l],
            _ => self.mt.to_moments[6 * (3 * k + i) + 2 * l + j - 1],
        }
    }

    /// Sets the inflow of the `looped` slots (one-cell-wide periodic axes, whose outflow
    /// comes back in through the same face's upstream side with the same profile) to what
    /// the cell sends round: `x = r + A x` solved exactly (at most 6 unknowns).
    pub(crate) fn close_loops(
        &self,
        inflow: &mut [[f64; 3]; 3],
        source_out: &[f64; 9],
        looped: &[usize],
    ) {
        for &k in looped {
            inflow[k] = [0.0; 3];
        }
        // What leaves through each looped face from the given inflows and the source.
        let (given, _) = self.step(inflow, source_out, 0.0);
        let n = 3 * looped.len();
        let mut a = [[0.0; 7]; 6];
        for (r, &k) in looped.iter().enumerate() {
            for j in 0..3 {
                let row = &mut a[3 * r + j];
                for (c, &kk) in looped.iter().enumerate() {
                    for i in 0..3 {
                        row[3 * c + i] = -self.transmit(kk, i, k, j);
                    }
                }
                row[3 * r + j] += 1.0;
                row[n] = given[k][j];
            }
        }
        // Gaussian elimination with partial pivoting.
        for col in 0..n {
            let pivot = (col..n)
                .max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))
                .unwrap_or(col);
            a.swap(col, pivot);
            let (done, below) = a.split_at_mut(col + 1);
            let pivot_row = &done[col];
            for row in &mut below[..n - col - 1] {
                let f = row[col] / pivot_row[col];
                for (v, p) in row[col..=n].iter_mut().zip(&pivot_row[col..=n]) {
                    *v -= f * p;
                }
            }
        }
        let mut x = [0.0; 6];
        for r in (0..n).rev() {
            let tail: f64 = (r + 1..n).map(|c| a[r][c] * x[c]).sum();
            x[r] = (a[r][n] - tail) / a[r][r];
        }
        for (r, &k) in looped.iter().enumerate() {
            inflow[k] = [x[3 * r], x[3 * r + 1], x[3 * r + 2]];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dirs() -> Vec<(DVec3, f64)> {
        vec![
            (DVec3::new(0.8, 0.5, 0.33).normalize(), 0.4),
            (DVec3::new(0.7, 0.6, 0.3).normalize(), 0.6),
        ]
    }

    /// Every row conserves: what a unit flux does not pass on it extinguishes along its
    /// mean track, at every node, thin and thick.
    #[test]
    fn rows_conserve_and_match_the_integrated_tracks() {
        let t = FaceMoments::of(&dirs());
        for n in 0..NODES {
            let tau0 = super::super::sweep::table_node(n);
            for a in 0..3 {
                let sum: f64 = (0..3).map(|b| t.transmit[n][27 * a + 3 * b]).sum();
                let balance = sum + tau0 * t.inflow_track[n][3 * a];
                assert!((balance - 1.0).abs() < 1e-9, "node {n} face {a}: {balance}");
                for i in 1..3 {
                    let row = (3 * a + i) * 9;
                    let sum: f64 = (0..3).map(|b| t.transmit[n][row + 3 * b]).sum();
                    let balance = sum + tau0 * t.inflow_track[n][3 * a + i];
                    assert!(
                        balance.abs() < 1e-9,
                        "node {n} slope row {a},{i}: {balance}"
                    );
                }
            }
            let sum = t.exit[n][0] + t.exit[n][3] + t.exit[n][6];
            assert!((sum + tau0 * t.source_track[n] - 1.0).abs() < 1e-9);
        }
    }

    /// Every moment node is its own nearest node; no medium is node 0.
    #[test]
    fn moment_nodes_round_trip() {
        for n in 0..MOMENT_NODES {
            assert_eq!(moment_node_of(moment_node_tau(n)) as usize, n);
        }
        assert_eq!(moment_node_of(0.0), 0);
        assert_eq!(moment_node_of(1e9) as usize, MOMENT_NODES - 1);
    }

    /// A profile rising along a face's first tangent sends more out through that tangent's
    /// downstream face than the uniform flux does, and makes no flux of its own.
    #[test]
    fn a_linear_profile_is_carried_along_the_chords() {
        let w = DVec3::new(1.0, 1.0, 1.0).normalize();
        let t = FaceMoments::of(&[(w, 1.0)]);
        let uniform_to_1 = t.thin_transmit[0][3];
        let slope_to_1 = t.thin_transmit[0][9 + 3];
        assert!(uniform_to_1 > 0.0 && slope_to_1 > 0.0);
        let row = 9;
        let sum: f64 = (0..3).map(|b| t.thin_transmit[0][row + 3 * b]).sum();
        assert!(sum.abs() < 1e-12, "{sum}");
    }
}
