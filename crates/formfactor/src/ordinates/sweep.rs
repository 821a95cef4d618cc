//! The matrix-free discrete-ordinates operator: scatter with the phase matrix, then per bin a
//! transport sweep in the bin's downwind order that spreads the flux over the bin's solid angle.
//!
//! Transport scheme (exactly conservative, exponential step). A bin is split by the signs of
//! its directions into "pieces" (one per bin when `n` is even; bins that straddle an axis
//! plane have 2 or 4). Radiance uniform over a piece with solid angle `Ω` crosses a face
//! normal to axis `a` at the rate `m_a h² Ω I`, `m_a = (1/Ω)∫|ω_a| dω`. Per cell and piece
//! the sweep carries one flux per face:
//! - **face-coupled** (the default, [`OrdinatesOptions::face_coupling`]): the flux entering
//!   through the upstream face of axis `a` leaves through the downstream face of `b` in the
//!   share `T_ab(σt h)` that the piece's chords from that face give (exactly attenuated,
//!   tabulated per piece), the rest is extinguished; a source uniform in the cell leaves
//!   through face `b` in its exact share `E_b(σt h)`. A beam keeps its direction from cell to
//!   cell, as in the step-characteristics method;
//! - **Max's shares**: a cell's outflow is shared among its downstream faces in the fixed
//!   fractions `f_a = m_a / s` (`s = Σ m_a`) whatever face it came in by, transmitted with
//!   `e^{−σt ℓ}` along the mean chord `ℓ = h / s`, and a uniform source leaves with the cube's
//!   exact escape probability over the piece's directions (tabulated). The fixed shares spread
//!   a beam sideways at every cell (numerical diffusion of order `σt h`).
//!
//! Either way, per cell and piece: inflow + emitted = extinguished + outflow, to rounding,
//! and in the limit of thin cells the scheme tends to exact transport along each direction.
//!
//! The scattered source is linear in each cell ([`OrdinatesOptions::linear_source`], with
//! the face coupling): the sweeps read the source function `J = S / σt*` of the bin and
//! rebuild each cell's slopes from its neighbours' (the lights' first scattering from the
//! beam's own profile in the cell, [`BeamProfiles`]); a slope's exits through each face are
//! tabulated with the coupling and emit nothing in all.

use std::sync::{Arc, Mutex};

use glam::DVec3;
use medium::{light_pass::LightPass, Grid, Light, Medium, PhaseFunction};
use rayon::prelude::*;
use solver::operator::TransportOperator;

use super::bins::{DirectionBins, FaceRect};
use super::faces::{
    moment_node_of, moment_node_tau, FaceMoments, FaceStep, MomentTerms, MOMENT_NODES,
};
use super::phase_matrix::{bin_averaged_phase, default_quadrature, PhaseMatrix};
use super::OrdinatesError;

mod beams;
mod state;
pub use beams::{exponential_half_change, BeamLight, BeamProfiles};
use state::StateCells;

/// Largest transport refinement (sub-cells per cell side of the sweep; a scene's
/// `[solve] transport_refinement`).
pub const MAX_TRANSPORT_REFINEMENT: usize = 4;

/// Options of the ordinates operator.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OrdinatesOptions {
    /// Periodic side boundaries in x and y (for slabs); z always has vacuum outside.
    pub periodic_xy: bool,
    /// Sub-squares per bin side for the phase matrix (`None`: [`default_quadrature`]).
    pub phase_quadrature: Option<usize>,
    /// Sub-squares per bin side for first-bounce bin averages of the phase function.
    pub first_bounce_quadrature: usize,
    /// Bins updated together in one Gauss–Seidel step (they are swept in parallel).
    pub gauss_seidel_group: usize,
    /// Make the phase matrix's discrete mean cosine the phase function's: from
    /// [`FORWARD_MATCH_MIN_BINS`] bins on by less scattering into the neighbouring bins
    /// ([`PhaseMatrix::match_asymmetry_forward`]), below by a tilt
    /// ([`PhaseMatrix::match_asymmetry`]).
    pub match_asymmetry: bool,
    /// With Max's face shares (`face_coupling` off): transmit each cell's inflow by the exact
    /// mean `⟨e^{−σt ℓ}⟩` over its chords ([`Piece`]), not by `e^{−σt ⟨ℓ⟩}` of the mean chord.
    /// Off by default: on the 7³ blob of `tests/it/ordinates_zonal.rs` it doubles that sweep's
    /// gap to zonal (3.5 % → 7.3 % RMS), because the mean chord's smaller transmission partly
    /// offsets the shares' sideways spreading. The face-coupled sweep attenuates along the
    /// chords already, and ignores it.
    pub exact_transmission: bool,
    /// Sweep each cell as `r × r × r` sub-cells (1..=4; the unknowns stay per cell, the
    /// source uniform in it): the step scheme's sideways spreading (numerical diffusion)
    /// shrinks with the sub-cell size. Sweep cost × r³. Vacuum sides only.
    pub transport_refinement: usize,
    /// δ-M truncation of a forward peak narrower than the bins (Wiscombe's δ-M, with the
    /// peak cut off flat inside a cone): the phase function inside this half-angle (degrees)
    /// of the forward direction is clipped to its value on the cone, and the clipped mass `f`
    /// is treated as not scattering at all, `p = f δ + (1 − f) p*`. Scattering into the
    /// δ-peak does not change a photon's direction, so the scattered radiance obeys exactly
    /// the transport equation with `σt* = σt − f σs`, `σs* = (1 − f) σs` and `p*`, which is
    /// flat where the bins cannot follow `p` and equal to `p/(1 − f)` elsewhere (side and
    /// back scattering unchanged, unlike δ-Eddington's `HG(g/(1+g))`). The first scattering
    /// of the light (the source) and the final gather keep the true phase function and σs,
    /// so the solution is still the true scattered radiance. `0` (the default): none.
    /// Henyey–Greenstein with `g > 0` only.
    pub forward_truncation_degrees: f64,
    /// Couple each cell's faces (step characteristics): the flux entering through one face
    /// leaves through each downstream face in the share the piece's chords from that face
    /// give, `T_ab(σt h)`, tabulated per piece ([`FaceMoments`]), instead of Max's shares
    /// `f_b` whatever face it came in by. A beam then keeps its direction across cells (at
    /// 45° a square passes all of it from one face to the other: no spreading at all) where
    /// Max's shares spread it sideways at every cell, a numerical diffusion of order `σt h`
    /// that let thick slabs transmit 27 % too much at `σt h = 0.25` and brightened the
    /// silhouettes of forward-scattering clouds. The uniform source leaves through each face
    /// in its exact share too, integrated in depth exactly. Still exactly conservative.
    pub face_coupling: bool,
    /// Sweep each cell's scattered source as linear in the cell, not uniform (the default;
    /// needs the face coupling, ignored with Max's shares): per bin, the slopes are
    /// reconstructed from the neighbouring cells' source function `J = S / σt*` (central
    /// differences; one-sided at the grid's sides and next to a cell of under a quarter of
    /// the σt*), and a slope's exits per face are tabulated with the coupling. A flat source
    /// is first order in `σt h`, and in thick, highly scattering media its error compounds
    /// over the orders: a slab of τ = 64 in 64 layers (albedo 0.99) transmitted 4.3× DISORT's
    /// light, 2.2× with the slopes; the cloud24 cloud at 4× its σt went from 6.0 % to 3.1 %
    /// RMS over 8 views (docs/validation.md). No state is added and the operator stays linear
    /// (the slopes are the neighbours' values); a sweep reads up to 6 neighbours per cell
    /// (`data/cloud.toml`'s solve 13.0 → 17.5 s). Emission is swept flat
    /// ([`OrdinatesOperator::transport_emission`]).
    pub linear_source: bool,
    /// Carry each face's flux with its first moments along the face's two tangential
    /// coordinates, not uniform over the face (needs the face coupling; cells swept as
    /// sub-cells and periodic layers more than one cell wide sweep uniform faces). A piece
    /// crossing a side face then re-enters the next cell with the profile it left with:
    /// uniform faces spread it over the face, a numerical diffusion across the layers of
    /// order `σt h` that let a slab of τ = 64 in 64 layers (albedo 0.99) transmit 2.2×
    /// DISORT's light ([`faces`](super::faces); docs/validation.md). A cell with medium's
    /// step goes from 9 to 81 multiply-adds per piece.
    pub linear_faces: bool,
    /// With `match_asymmetry`, raise the mean cosine the phase matrix is matched to (every
    /// phase function, isotropic too) from the truncated `g*` to `g* + ε (1 − g*)`, `ε` the
    /// bins' [`diffusion_loss`](DirectionBins::diffusion_loss): radiance constant over each
    /// bin carries `1 − ε` of the current a fluence gradient drives (the bins lose the spread
    /// of directions within them each time the flux is gathered on a face), so far from the
    /// light, where transport is diffusion with `D = 1 / (3 σt (1 − ω g))`, the discrete
    /// field's `D` is `(1 − ε)` too small and thick slabs transmitted too little: at τ = 64,
    /// albedo 0.99, `T` −9.2 % (96 bins), −5.2 % (216), −3.7 % (384). The raised `g` makes
    /// `(1 − ω g_d) = (1 − ε)(1 − ω g)` hold at `ω = 1`, where diffusion carries light far;
    /// (docs/validation.md, *The bins' diffusion coefficient*).
    pub match_diffusion: bool,
    /// With `linear_source`, sweep the lights' first scattering with the slopes of the
    /// beam's own profile in each cell (`e^{−τ}`, its first moment exact), not the
    /// neighbours' differences ([`BeamProfiles`]; off, the profiles are empty). Thick cells
    /// along an oblique beam put the first scattering too deep with the differences: at
    /// τ = 64 on layers of optical depth 1, μ0 = 0.4, a slab transmitted 5 points too much.
    pub beam_profiles: bool,
}

/// The fewest bins whose phase matrix makes up its lost mean cosine by scattering less into
/// the neighbouring bins ([`PhaseMatrix::match_asymmetry_forward`]) rather than by a tilt
/// that thins side and back scattering ([`PhaseMatrix::match_asymmetry`]). With bins 15° or
/// less across (6 or more per cube face) the jumps to the neighbours are what the quadrature
/// makes of deflections the bins cannot resolve: the cloud24 cloud at g = 0.85 (384 bins)
/// went from image means −1.3 … +2.0 % to −0.3 … +1.5 % over 8 views, and DISORT slab fluxes
/// at τ = 4 and 16 moved toward DISORT at 216 and 384 bins. With Max's 96 bins (22° across)
/// the tilt stays: the 192-class cloud's worst view went 4.9 → 5.4 % with the forward rule
/// (docs/validation.md, *Forward-scattering clouds from every side*).
pub const FORWARD_MATCH_MIN_BINS: usize = 216;

impl Default for OrdinatesOptions {
    fn default() -> Self {
        OrdinatesOptions {
            periodic_xy: false,
            phase_quadrature: None,
            first_bounce_quadrature: 12,
            gauss_seidel_group: 8,
            match_asymmetry: true,
            exact_transmission: false,
            transport_refinement: 1,
            forward_truncation_degrees: 0.0,
            face_coupling: true,
            linear_source: true,
            linear_faces: true,
            match_diffusion: true,
            beam_profiles: true,
        }
    }
}

/// The forward-peak cone volrad truncates by default for `phase` swept in `bins`: the cone
/// with one bin's solid angle, `cos θ = 1 − 2/M` (11.7° for Max's 96 bins, 5.9° for 384),
/// for Henyey–Greenstein with `g > 0`; `0` (no truncation) otherwise. A peak narrower than
/// a bin is what the bins cannot follow.
pub fn default_forward_truncation_degrees(bins: &DirectionBins, phase: &PhaseFunction) -> f64 {
    match *phase {
        PhaseFunction::HenyeyGreenstein { g } if g > 0.0 => {
            (1.0 - 2.0 / bins.len() as f64).acos().to_degrees()
        }
        _ => 0.0,
    }
}

/// The fraction `f` of `phase`'s scattering that δ-M truncation in a forward cone of
/// `degrees` (half-angle) treats as unscattered ([`OrdinatesOptions::forward_truncation_degrees`]):
/// `0` for no cone; a cone needs `0 < degrees < 90` and Henyey–Greenstein with `g > 0`. The one
/// rule the operator, the scene checker and `volrad info` apply.
pub fn forward_truncation_fraction(
    degrees: f64,
    phase: &PhaseFunction,
) -> Result<f64, OrdinatesError> {
    match *phase {
        _ if degrees == 0.0 => Ok(0.0),
        PhaseFunction::HenyeyGreenstein { g } if degrees > 0.0 && degrees < 90.0 && g > 0.0 => {
            Ok(forward_peak_fraction(g, degrees.to_radians().cos()))
        }
        _ => Err(OrdinatesError::Option(format!(
            "forward-peak cone {degrees}°: needs 0 < degrees < 90 and a Henyey–Greenstein phase \
             function with g > 0 (0 turns truncation off)"
        ))),
    }
}

/// The mass of Henyey–Greenstein(`g`) above its value at `μc`, inside the cone `μ > μc`:
/// `1 − 2π[∫_{−1}^{μc} p dμ + (1 − μc) p(μc)]`, with HG's closed-form integral
/// `2π∫_{−1}^{μ} p dμ = (1 − g²)/(2g) · (1/√(1 + g² − 2gμ) − 1/(1 + g))`.
pub fn forward_peak_fraction(g: f64, mu_c: f64) -> f64 {
    let below =
        (1.0 - g * g) / (2.0 * g) * (1.0 / (1.0 + g * g - 2.0 * g * mu_c).sqrt() - 1.0 / (1.0 + g));
    let cap = 2.0
        * std::f64::consts::PI
        * (1.0 - mu_c)
        * PhaseFunction::HenyeyGreenstein { g }.eval(mu_c);
    (1.0 - below - cap).max(0.0)
}

/// A piece of a bin with one sign per axis: the unit of a transport sweep.
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    pub bin: usize,
    /// Travel direction per axis: `true` for increasing index.
    pub forward: [bool; 3],
    pub solid_angle: f64,
    /// `Ω_piece / Ω_bin`: its share of the bin's (isotropic within the bin) source.
    pub weight: f64,
    /// Face-flux fractions `f_a = m_a / s`.
    pub fractions: [f64; 3],
    /// `s = Σ_a m_a`: the chord is `h / s`.
    pub projected: f64,
    /// Escape of a uniform source inside a cell, exactly for the cube: `1 − E` tabulated
    /// where `E = ⟨e^{−τ0 d}⟩` over points of the unit cube and the piece's directions,
    /// `d` the distance to the cube's surface (`τ0 = σt h`). Tabulated, see [`Piece::source_terms`].
    source_table: [f64; SOURCE_TABLE_LEN],
    /// `⟨d⟩` and `⟨d²⟩` (units of h) for the thin-cell limit.
    exit_moments: [f64; 2],
    /// Exact inflow transmission ([`OrdinatesOptions::exact_transmission`]):
    /// `T(τ0) = ⟨e^{−τ0 ℓ}⟩` tabulated like `source_table`, over the chords `ℓ` (units of h)
    /// of flux entering the upwind faces uniformly (each face weighted by its projected
    /// area `|ω_a|`) along the piece's directions, and `⟨ℓ⟩`, `⟨ℓ²⟩` for thin cells.
    /// `None`: `e^{−τ0/s}`, the mean chord's transmission (by Jensen's inequality too small).
    transmission: Option<([f64; SOURCE_TABLE_LEN], [f64; 2])>,
    /// Face-coupled transport tables ([`OrdinatesOptions::face_coupling`]; their means'
    /// part for uniform faces, all of them for [`OrdinatesOptions::linear_faces`]), in the
    /// piece's canonical axes (shared by its images); `None` with Max's shares.
    faces: Option<Arc<FaceMoments>>,
    /// The piece's axes in decreasing share (`fractions`): a piece's cell terms are stored
    /// with its axes in this order, so that pieces that are one another's images under the
    /// cube's symmetries (axis permutations and reflections) share them.
    canonical_axes: [usize; 3],
}

impl Piece {
    /// Escape slot ([`SweepEnergy::escaped`]) of the piece's flux leaving along `axis`:
    /// `2 axis + forward`.
    #[inline]
    fn side(&self, axis: usize) -> usize {
        2 * axis + usize::from(self.forward[axis])
    }
}

/// Source-escape table: `τ0` from 10^-2 to 10^2, 10 points per decade (log-linear).
pub(crate) const SOURCE_TABLE_LEN: usize = 41;
const SOURCE_TABLE_MIN_LOG10: f64 = -2.0;
const SOURCE_TABLE_PER_DECADE: f64 = 10.0;

impl Piece {
    /// Per-cell coefficients for cell optical side `tau0 = σt h`:
    /// `(t, inflow_escape, source_escape, source_track)`: the inflow's transmission
    /// `e^{−τ}` and mean-radiance factor `(1 − e^{−τ})/τ` along the chord (`τ = tau0 / s`),
    /// the fraction of a uniform in-cell source that leaves, and its mean track length per
    /// unit source (units of h), with `1 − source_escape = tau0 · source_track`.
    #[inline]
    pub fn cell_terms(&self, tau0: f64) -> (f64, f64, f64, f64) {
        self.cell_terms_at(tau0, table_coordinate(tau0))
    }

    /// [`cell_terms`](Self::cell_terms) with `x = table_coordinate(tau0)` precomputed.
    #[inline]
    pub fn cell_terms_at(&self, tau0: f64, x: f64) -> (f64, f64, f64, f64) {
        let q = self.source_terms_at(tau0, x);
        let Some((table, [l1, l2])) = &self.transmission else {
            let tau = tau0 / self.projected;
            let em1 = (-tau).exp_m1();
            let esc = if tau < 1e-6 {
                1.0 - 0.5 * tau + tau * tau / 6.0
            } else {
                -em1 / tau
            };
            return (1.0 + em1, esc, 1.0 - tau0 * q, q);
        };
        let last = SOURCE_TABLE_LEN - 1;
        // (transmission, (1 − T)/τ0: the inflow's mean track per unit inflow, units of h).
        let (t, track) = if x <= 0.0 {
            (
                1.0 - tau0 * l1 + 0.5 * tau0 * tau0 * l2,
                l1 - 0.5 * tau0 * l2,
            )
        } else {
            let t = if x >= last as f64 {
                // Thick cell: only chords shorter than ~1/τ0 (near the edges) get through,
                // and their density is finite at 0, so T ∝ 1/τ0.
                let tau_last = table_node(last);
                table[last] * tau_last / tau0
            } else {
                let i = x.floor() as usize;
                let f = x - i as f64;
                (1.0 - f) * table[i] + f * table[i + 1]
            };
            (t, (1.0 - t) / tau0)
        };
        // `esc` is the mean-radiance factor in units of the mean chord h/s.
        (t, track * self.projected, 1.0 - tau0 * q, q)
    }

    /// The piece's coefficients for a (sub-)cell of side `h` and optical side `tau0` (`x =
    /// table_coordinate(tau0)`), in its canonical axes: face-coupled, or Max's shares.
    fn canonical_terms(&self, tau0: f64, x: f64, h: f64, face_coupling: bool) -> CellTerms {
        let ax = self.canonical_axes;
        if let (true, Some(faces)) = (face_coupling, &self.faces) {
            // The means' part of the face tables.
            let t = faces.at(tau0, x);
            CellTerms {
                transmit: std::array::from_fn(|kl| t.transmit[27 * (kl / 3) + 3 * (kl % 3)]),
                inflow_mean: std::array::from_fn(|k| t.inflow_track[3 * k]),
                source_out: std::array::from_fn(|l| h * t.exit[3 * l]),
                source_mean: h * t.source_track,
            }
        } else {
            let (t, esc, src_esc, track) = self.cell_terms_at(tau0, x);
            let f = self.fractions;
            CellTerms {
                transmit: std::array::from_fn(|i| t * f[ax[i % 3]]),
                inflow_mean: [esc / self.projected; 3],
                source_out: std::array::from_fn(|l| h * src_esc * f[ax[l]]),
                source_mean: h * track,
            }
        }
    }

    /// The piece's linear-source coefficients for a (sub-)cell of side `h` and optical side
    /// `tau0` (`x = table_coordinate(tau0)`), in its canonical axes (face coupling only).
    fn slope_terms(&self, tau0: f64, x: f64, h: f64) -> SlopeTerms {
        let faces = self
            .faces
            .as_ref()
            .expect("a linear source is swept with the face coupling's tables");
        let (g, q) = faces.slope_at(tau0, x);
        SlopeTerms {
            out: std::array::from_fn(|cl| h * g[9 * (cl / 3) + 3 * (cl % 3)]),
            mean: q.map(|v| h * v),
        }
    }

    /// `q(τ0) = (1 − ⟨e^{−τ0 d}⟩)/τ0`: the source's mean track length in units of h.
    #[inline]
    pub fn source_terms(&self, tau0: f64) -> f64 {
        self.source_terms_at(tau0, table_coordinate(tau0))
    }

    /// [`source_terms`](Self::source_terms) with `x = table_coordinate(tau0)` precomputed.
    #[inline]
    pub fn source_terms_at(&self, tau0: f64, x: f64) -> f64 {
        if x <= 0.0 {
            // Thin cell: 1 − ⟨e^{−τ0 d}⟩ ≈ τ0⟨d⟩ − τ0²⟨d²⟩/2.
            let [d1, d2] = self.exit_moments;
            return d1 - 0.5 * tau0 * d2;
        }
        let last = (SOURCE_TABLE_LEN - 1) as f64;
        if x >= last {
            // Thick cell: only a surface layer escapes, ⟨e^{−τ0 d}⟩ → s/τ0.
            return (1.0 - self.projected / tau0) / tau0;
        }
        let i = x.floor() as usize;
        let f = x - i as f64;
        // The table holds τ0·q = 1 − ⟨e^{−τ0 d}⟩ (smooth and bounded).
        let a = self.source_table[i];
        let b = self.source_table[i + 1];
        ((1.0 - f) * a + f * b) / tau0
    }
}

/// The optical side `τ0 = σt h` of node `i` of the pieces' tables (the inverse of
/// [`table_coordinate`] at whole coordinates).
pub(crate) fn table_node(i: usize) -> f64 {
    10f64.powf(SOURCE_TABLE_MIN_LOG10 + i as f64 / SOURCE_TABLE_PER_DECADE)
}

/// Position of `tau0` in the source-escape table (one `log10`, shared by all pieces).
#[inline]
pub fn table_coordinate(tau0: f64) -> f64 {
    (tau0.max(1e-300).log10() - SOURCE_TABLE_MIN_LOG10) * SOURCE_TABLE_PER_DECADE
}

/// Distances to the unit cube's surface from `POINTS³` midpoints, for directions `dirs`.
fn source_table_of(dirs: &[(DVec3, f64)]) -> ([f64; SOURCE_TABLE_LEN], [f64; 2]) {
    const POINTS: usize = 8;
    let total_w: f64 = dirs.iter().map(|d| d.1).sum();
    let mut samples = Vec::with_capacity(POINTS * POINTS * POINTS * dirs.len());
    for a in 0..POINTS {
        for b in 0..POINTS {
            for c in 0..POINTS {
                let x = [a, b, c].map(|v| (v as f64 + 0.5) / POINTS as f64);
                for &(w, wt) in dirs {
                    let w = w.to_array();
                    let mut d = f64::INFINITY;
                    for ax in 0..3 {
                        if w[ax] > 0.0 {
                            d = d.min((1.0 - x[ax]) / w[ax]);
                        } else if w[ax] < 0.0 {
                            d = d.min(x[ax] / -w[ax]);
                        }
                    }
                    samples.push((d, wt / (total_w * (POINTS * POINTS * POINTS) as f64)));
                }
            }
        }
    }
    let d1: f64 = samples.iter().map(|(d, w)| d * w).sum();
    let d2: f64 = samples.iter().map(|(d, w)| d * d * w).sum();
    let mut table = [0.0; SOURCE_TABLE_LEN];
    for (i, q) in table.iter_mut().enumerate() {
        let tau0 = table_node(i);
        let escape: f64 = samples.iter().map(|(d, w)| w * (-tau0 * d).exp()).sum();
        *q = 1.0 - escape;
    }
    (table, [d1, d2])
}

/// Visits `points²` midpoints of each face of the unit cube that the directions `dirs` cross,
/// per direction: `visit(face axis, |ω| per axis, the direction's weight / points², the point)`,
/// the point's coordinate along the face's own axis left 0.
fn for_face_points(
    dirs: &[(DVec3, f64)],
    points: usize,
    mut visit: impl FnMut(usize, [f64; 3], f64, [f64; 3]),
) {
    for &(w, wt) in dirs {
        let w = w.abs().to_array();
        for face in (0..3).filter(|&face| w[face] != 0.0) {
            let (u, v) = ((face + 1) % 3, (face + 2) % 3);
            for a in 0..points {
                for b in 0..points {
                    let mut y = [0.0; 3];
                    y[u] = (a as f64 + 0.5) / points as f64;
                    y[v] = (b as f64 + 0.5) / points as f64;
                    visit(face, w, wt / (points * points) as f64, y);
                }
            }
        }
    }
}

/// Chords of flux entering the unit cube's upwind faces (`ENTRY_POINTS²` midpoints per face,
/// each face weighted by `|w_a|`) along directions `dirs`: the transmission table and the
/// chord moments `⟨ℓ⟩`, `⟨ℓ²⟩` (see [`Piece::transmission`]).
fn transmission_table_of(dirs: &[(DVec3, f64)]) -> ([f64; SOURCE_TABLE_LEN], [f64; 2]) {
    const ENTRY_POINTS: usize = 12;
    let mut samples = Vec::with_capacity(3 * ENTRY_POINTS * ENTRY_POINTS * dirs.len());
    for_face_points(dirs, ENTRY_POINTS, |entry, w, wt, x| {
        let chord = (0..3)
            .filter(|&ax| w[ax] > 0.0)
            .map(|ax| (1.0 - x[ax]) / w[ax])
            .fold(f64::INFINITY, f64::min);
        samples.push((chord, wt * w[entry] * (ENTRY_POINTS * ENTRY_POINTS) as f64));
    });
    let total: f64 = samples.iter().map(|s| s.1).sum();
    let l1 = samples.iter().map(|(l, w)| l * w).sum::<f64>() / total;
    let l2 = samples.iter().map(|(l, w)| l * l * w).sum::<f64>() / total;
    let mut table = [0.0; SOURCE_TABLE_LEN];
    for (i, t) in table.iter_mut().enumerate() {
        let tau0 = table_node(i);
        *t = samples
            .iter()
            .map(|(l, w)| w * (-tau0 * l).exp())
            .sum::<f64>()
            / total;
    }
    (table, [l1, l2])
}

/// Sub-squares per side for the pieces' mean direction components.
const PIECE_QUADRATURE: usize = 24;

pub(crate) fn pieces_of(
    bins: &DirectionBins,
    exact_transmission: bool,
    face_coupling: bool,
) -> Vec<Piece> {
    let split = |lo: f64, hi: f64| -> Vec<[f64; 2]> {
        if lo < 0.0 && hi > 0.0 {
            vec![[lo, 0.0], [0.0, hi]]
        } else {
            vec![[lo, hi]]
        }
    };
    let mut rects = Vec::new();
    for bin in 0..bins.len() {
        let r = bins.rect(bin);
        for u in split(r.u[0], r.u[1]) {
            for v in split(r.v[0], r.v[1]) {
                rects.push((bin, FaceRect { face: r.face, u, v }));
            }
        }
    }
    // Each piece's face tables are set below, once per set of images.
    let made = rects
        .into_par_iter()
        .map(|(bin, piece)| {
            let solid_angle = piece.solid_angle();
            let mut q = Vec::new();
            piece.quadrature(PIECE_QUADRATURE, &mut q);
            let mean_abs = q.iter().fold(DVec3::ZERO, |a, &(d, w)| a + d.abs() * w) / solid_angle;
            let mid = piece.point(
                0.5 * (piece.u[0] + piece.u[1]),
                0.5 * (piece.v[0] + piece.v[1]),
            );
            let s = mean_abs.x + mean_abs.y + mean_abs.z;
            q.clear();
            piece.quadrature(2, &mut q);
            let (source_table, exit_moments) = source_table_of(&q);
            let transmission = exact_transmission.then(|| {
                q.clear();
                piece.quadrature(4, &mut q);
                transmission_table_of(&q)
            });
            let fractions = (mean_abs / s).to_array();
            let mut canonical_axes = [0, 1, 2];
            canonical_axes.sort_by(|&a, &b| fractions[b].total_cmp(&fractions[a]));
            // The piece's directions in its canonical axes, which its images share.
            q.clear();
            piece.quadrature(3, &mut q);
            let mut canonical_dirs: Vec<(DVec3, f64)> = q
                .iter()
                .map(|&(d, w)| {
                    let d = d.abs().to_array();
                    (DVec3::from_array(canonical_axes.map(|a| d[a])), w)
                })
                .collect();
            canonical_dirs.sort_by(|a, b| {
                (a.0.x, a.0.y, a.0.z)
                    .partial_cmp(&(b.0.x, b.0.y, b.0.z))
                    .unwrap_or(std::cmp::Ordering::Equal)
            });
            (
                canonical_dirs,
                Piece {
                    bin,
                    forward: [mid.x >= 0.0, mid.y >= 0.0, mid.z >= 0.0],
                    solid_angle,
                    weight: solid_angle / bins.solid_angles()[bin],
                    fractions,
                    projected: s,
                    source_table,
                    exit_moments,
                    transmission,
                    faces: None,
                    canonical_axes,
                },
            )
        })
        .collect::<Vec<_>>();
    // One coupling table per set of images (3 for Max's 96 bins): the same directions in
    // canonical axes, to rounding.
    let same = |a: &[(DVec3, f64)], b: &[(DVec3, f64)]| {
        a.len() == b.len()
            && a.iter().zip(b).all(|(x, y)| {
                (x.0 - y.0).abs().max_element() <= 1e-12 && (x.1 - y.1).abs() <= 1e-12 * x.1
            })
    };
    let mut groups: Vec<usize> = Vec::new();
    let group_of: Vec<usize> = made
        .iter()
        .enumerate()
        .map(|(p, (dirs, _))| {
            groups
                .iter()
                .position(|&g| same(&made[g].0, dirs))
                .unwrap_or_else(|| {
                    groups.push(p);
                    groups.len() - 1
                })
        })
        .collect();
    let tables: Vec<Option<Arc<FaceMoments>>> = groups
        .par_iter()
        .map(|&g| face_coupling.then(|| Arc::new(FaceMoments::of(&made[g].0))))
        .collect();
    made.into_iter()
        .zip(group_of)
        .map(|((_, piece), g)| Piece {
            faces: tables[g].clone(),
            ..piece
        })
        .collect()
}

/// Power bookkeeping of one transport (units: power, i.e. radiance × area × solid angle).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SweepEnergy {
    /// Power emitted by the source density, `Σ S V Ω`.
    pub emitted: f64,
    /// Power extinguished in the cells, `Σ σt V Ω I`.
    pub extinguished: f64,
    /// Power leaving through the grid's sides, ordered `−x, +x, −y, +y, −z, +z`.
    pub escaped: [f64; 6],
}

impl SweepEnergy {
    pub fn escaped_total(&self) -> f64 {
        self.escaped.iter().sum()
    }

    fn add(&mut self, o: &SweepEnergy) {
        self.emitted += o.emitted;
        self.extinguished += o.extinguished;
        for (a, b) in self.escaped.iter_mut().zip(o.escaped) {
            *a += b;
        }
    }

    /// Tallies one swept (sub-)cell of side `h` (units of `Ω h²`): source density `sd`
    /// emitted, and what it extinguishes: `σt h` times its mean radiance `mean` (`tau0 = σt
    /// h`; the coefficients keep `Σ_l T_kl + σt h M_k = 1`, so this is what did not leave).
    #[inline(always)]
    fn tally_cell(&mut self, mean: f64, tau0: f64, sd: f64, h: f64) {
        self.emitted += sd * h;
        self.extinguished += tau0 * mean;
    }

    /// Ends a piece's sweep through (sub-)cells of side `h`: when tallying, the z outflow of
    /// the last layer (`last_layer`) escapes; then the tally goes from per-`(Ω h²)` units to
    /// power.
    fn finish_sweep<F: FaceFlux>(
        mut self,
        piece: &Piece,
        h: f64,
        last_layer: &[F],
        tally: bool,
    ) -> Self {
        if tally {
            self.escaped[piece.side(2)] += last_layer.iter().map(|f| f.flux()).sum::<f64>();
        }
        let unit = piece.solid_angle * h * h;
        self.emitted *= unit;
        self.extinguished *= unit;
        for e in &mut self.escaped {
            *e *= unit;
        }
        self
    }
}

/// A face's flux as a sweep carries it: the flux alone (uniform faces) or with its slopes
/// across the face ([`OrdinatesOptions::linear_faces`], `[mean, slope, slope]`).
trait FaceFlux: Copy {
    const NONE: Self;
    /// The power through the face (its mean, per `Ω h²`).
    fn flux(self) -> f64;
}

impl FaceFlux for f64 {
    const NONE: f64 = 0.0;
    #[inline(always)]
    fn flux(self) -> f64 {
        self
    }
}

impl FaceFlux for [f64; 3] {
    const NONE: [f64; 3] = [0.0; 3];
    #[inline(always)]
    fn flux(self) -> f64 {
        self[0]
    }
}

/// One layer's cell step for [`OrdinatesOperator::downwind_layer`]: `step(cell in the layer,
/// ijk, inflows by grid axis)`. A trait with `#[inline(always)]` steps rather than a closure:
/// the step must be inlined into the sweep (a closure the compiler left out of line lost the
/// AVX2 build of the linear faces' sweep and cost it 40 %).
trait LayerCells<F> {
    fn step(&mut self, lc: usize, ijk: [usize; 3], inflow: [F; 3]) -> CellStep<F>;
}

/// Uniform faces' cells of one layer: the layer's first cell `base`, its cells' `level`s,
/// the bin's `density` column, the class's coefficients per level (cell and slope terms),
/// the piece's canonical `axes`, its one-cell periodic `loops` and the lights' own slopes.
struct UniformCells<'a> {
    op: &'a OrdinatesOperator,
    piece: &'a Piece,
    base: usize,
    level: &'a [u32],
    density: &'a [f64],
    coefficients: (&'a [CellTerms], &'a [SlopeTerms]),
    axes: [usize; 3],
    loops: [bool; 3],
    beams: Option<&'a BeamProfiles>,
}

impl LayerCells<f64> for UniformCells<'_> {
    #[inline(always)]
    fn step(&mut self, lc: usize, ijk: [usize; 3], mut inflow: [f64; 3]) -> CellStep<f64> {
        let (terms, slopes) = self.coefficients;
        let level = self.level[lc] as usize;
        let ct = &terms[level];
        let (op, axes) = (self.op, self.axes);
        let src = op.cell_source(
            (ct, slopes.get(level)),
            self.density,
            (self.base + lc, ijk),
            (self.piece, axes),
            self.beams,
        );
        let out = if op.options.periodic_xy {
            ct.outflow_looped(&mut inflow, &src, axes, self.loops)
        } else {
            ct.outflow(inflow, &src, axes)
        };
        CellStep {
            out,
            mean: ct.mean_radiance(inflow, &src, axes),
            density: src.density,
        }
    }
}

/// Linear faces' cells of one layer ([`OrdinatesOperator::face_cell`]): piece `p`, the
/// layer's first cell `base`, its cells' `level`s, the bin's `density` column and the
/// step's `(axes, linear source, looped slots)`.
struct FaceCells<'a> {
    op: &'a OrdinatesOperator,
    p: usize,
    base: usize,
    level: &'a [u32],
    density: &'a [f64],
    modes: FaceModes<'a>,
}

/// A linear faces' step's `(canonical axes, linear source, looped slots, the lights' own
/// slopes)`.
type FaceModes<'a> = ([usize; 3], bool, &'a [usize], Option<&'a BeamProfiles>);

impl LayerCells<[f64; 3]> for FaceCells<'_> {
    #[inline(always)]
    fn step(&mut self, lc: usize, ijk: [usize; 3], inflow: [[f64; 3]; 3]) -> CellStep<[f64; 3]> {
        let cell = (self.base + lc, ijk, self.level[lc] as usize);
        self.op
            .face_cell(self.p, cell, inflow, self.density, self.modes)
    }
}

/// What one cell's step gave: its outflows by grid axis, its mean radiance and the source
/// density it emitted.
struct CellStep<F> {
    out: [F; 3],
    mean: f64,
    density: f64,
}

/// Energy balance of a solution: external source power vs absorbed + escaped.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EnergyBalance {
    /// Power of the external density (emission + first bounce), `Σ S V Ω`.
    pub source: f64,
    /// Power absorbed, `Σ (1 − a) σt V Σ_l I_l Ω_l`.
    pub absorbed: f64,
    /// Power escaping the grid (per side, `−x, +x, −y, +y, −z, +z`).
    pub escaped: [f64; 6],
}

impl EnergyBalance {
    /// `|source − absorbed − escaped| / source`.
    pub fn relative_imbalance(&self) -> f64 {
        let esc: f64 = self.escaped.iter().sum();
        if self.source == 0.0 {
            return (self.absorbed + esc).abs();
        }
        (self.source - self.absorbed - esc).abs() / self.source
    }
}

/// Per-piece layer buffers, allocated once.
struct LayerBuffers {
    /// z outflow of each cell of the layer: the previous layer's until a cell is updated,
    /// then the current layer's.
    out: Vec<f64>,
    /// y outflow of each cell of the layer (the row before's, then the current row's).
    out_y: Vec<f64>,
    /// x outflow of each cell of the layer (periodic layers iterated to convergence only).
    out_x: Vec<f64>,
    /// With linear faces ([`OrdinatesOptions::linear_faces`]), the moments of the z and y
    /// outflows (as `out` and `out_y`, by the piece's slots' tangents); empty otherwise.
    faces_z: Vec<[f64; 3]>,
    faces_y: Vec<[f64; 3]>,
    /// z-inflow into the current layer (periodic layers iterated to convergence only).
    inz: Vec<f64>,
}

/// What one group of bins needs at a time: every sweep (Gauss–Seidel's, an application of
/// `K`, a transport) runs group by group ([`OrdinatesOperator::groups`]), so these hold
/// one group's bins and pieces, not all of them (at 216 bins, 8 of the 216 columns).
struct Scratch {
    /// Bin-major densities of the group's bins, `S[(l − l0)·stride + c]` (radiance per
    /// length): each sweep reads one bin's densities contiguously.
    density: Vec<f64>,
    /// Piece-major cell-average radiances of the group's pieces, `pieces × stride`.
    piece_out: Vec<f64>,
    /// One per piece of the largest group.
    layers: Vec<LayerBuffers>,
}

/// A piece's per-cell transport coefficients in the sweep's units, with the piece's axes in
/// its canonical order ([`Piece::canonical_axes`]: slot `k` is axis `axes[k]`), precomputed
/// once per cell for each class of pieces that share them, so the sweep does no exponentials
/// or table look-ups. Faces are named by slot: a cell's inflow through the upstream face of
/// slot `k`, its outflow through the downstream face of slot `l`.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct CellTerms {
    /// `T_kl` (index `3k + l`): the share of the inflow through `k` leaving through `l`.
    pub(super) transmit: [f64; 9],
    /// Mean radiance per unit inflow through `k`: its mean track, `(1 − Σ_l T_kl) / (σt h)`.
    pub(super) inflow_mean: [f64; 3],
    /// Outflow through `l` per unit source density: `h E_l`.
    pub(super) source_out: [f64; 3],
    /// Cell-average radiance per unit source density: `h q`.
    pub(super) source_mean: f64,
}

/// A piece's per-cell coefficients for a source's slopes ([`OrdinatesOptions::linear_source`]),
/// in its canonical slots like [`CellTerms`]; kept apart so that the flat source's sweep
/// reads no more than before.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct SlopeTerms {
    /// Outflow through `l` per unit slope of the source density along slot `c` (index
    /// `3c + l`; the source `sd + Σ_c s_c x_c`, `x_c` from −1 upstream to 1 downstream):
    /// `h G_cl`.
    pub(super) out: [f64; 9],
    /// Cell-average radiance per unit slope along slot `c`: `h q_c`.
    pub(super) mean: [f64; 3],
}

/// What a cell's own source sends out of it: the outflow through each downstream face (by
/// slot) and the mean radiance it makes in the cell.
#[derive(Clone, Copy, Debug, Default)]
struct CellSource {
    out: [f64; 3],
    mean: f64,
    /// The cell's mean source density (what it emits per unit length).
    density: f64,
}

impl CellTerms {
    /// The source density `sd`, uniform in the cell.
    #[inline(always)]
    fn uniform_source(&self, sd: f64) -> CellSource {
        CellSource {
            out: self.source_out.map(|e| sd * e),
            mean: sd * self.source_mean,
            density: sd,
        }
    }

    /// The source density `sd` plus the slopes `slope` (per grid axis, in the piece's
    /// direction of travel along it: `sd + slope_a` on the downstream face of axis `a`).
    #[inline(always)]
    fn linear_source(
        &self,
        st: &SlopeTerms,
        sd: f64,
        slope: [f64; 3],
        axes: [usize; 3],
    ) -> CellSource {
        let s = [slope[axes[0]], slope[axes[1]], slope[axes[2]]];
        let g = &st.out;
        CellSource {
            out: std::array::from_fn(|l| {
                sd * self.source_out[l] + s[0] * g[l] + s[1] * g[3 + l] + s[2] * g[6 + l]
            }),
            mean: sd * self.source_mean + s[0] * st.mean[0] + s[1] * st.mean[1] + s[2] * st.mean[2],
            density: sd,
        }
    }

    /// Outflows through the downstream faces (piece axes) for `inflow` through the upstream
    /// faces (piece axes) and the cell's source `src`.
    #[inline(always)]
    fn outflow(&self, inflow: [f64; 3], src: &CellSource, axes: [usize; 3]) -> [f64; 3] {
        let t = &self.transmit;
        let i = [inflow[axes[0]], inflow[axes[1]], inflow[axes[2]]];
        let mut o = [0.0; 3];
        for l in 0..3 {
            o[axes[l]] = i[0] * t[l] + i[1] * t[3 + l] + i[2] * t[6 + l] + src.out[l];
        }
        o
    }

    /// [`outflow`](Self::outflow) where the outflow through a face of an axis in `loops`
    /// (a one-cell-wide periodic axis) comes back in through that axis's upstream face:
    /// solved exactly, and `inflow` updated with what comes back.
    #[inline]
    fn outflow_looped(
        &self,
        inflow: &mut [f64; 3],
        src: &CellSource,
        axes: [usize; 3],
        loops: [bool; 3],
    ) -> [f64; 3] {
        let t = &self.transmit;
        let (mut looped, mut count) = ([0usize; 2], 0);
        for k in 0..3 {
            if loops[axes[k]] {
                looped[count] = k;
                count += 1;
            }
        }
        // What leaves through each slot from the inflows that are given.
        let mut r = [0.0; 3];
        for (l, rl) in r.iter_mut().enumerate() {
            *rl = src.out[l];
            for k in 0..3 {
                if !loops[axes[k]] {
                    *rl += inflow[axes[k]] * t[3 * k + l];
                }
            }
        }
        match count {
            0 => {}
            1 => {
                let k = looped[0];
                inflow[axes[k]] = r[k] / (1.0 - t[3 * k + k]);
            }
            _ => {
                let [k0, k1] = looped;
                let (t00, t01, t10, t11) = (
                    t[3 * k0 + k0],
                    t[3 * k0 + k1],
                    t[3 * k1 + k0],
                    t[3 * k1 + k1],
                );
                let det = (1.0 - t00) * (1.0 - t11) - t10 * t01;
                inflow[axes[k0]] = (r[k0] * (1.0 - t11) + t10 * r[k1]) / det;
                inflow[axes[k1]] = (r[k1] * (1.0 - t00) + t01 * r[k0]) / det;
            }
        }
        self.outflow(*inflow, src, axes)
    }

    /// Cell-average radiance for `inflow` (piece axes) and the cell's source `src`.
    #[inline(always)]
    fn mean_radiance(&self, inflow: [f64; 3], src: &CellSource, axes: [usize; 3]) -> f64 {
        inflow[axes[0]] * self.inflow_mean[0]
            + inflow[axes[1]] * self.inflow_mean[1]
            + inflow[axes[2]] * self.inflow_mean[2]
            + src.mean
    }
}

/// A class-major table of the piece classes' coefficients (one per class `representatives`
/// and level `level_tau`): `make(piece, τ0, table_coordinate(τ0))`.
fn per_class_and_level<T: Send>(
    (representatives, pieces, level_tau): (&[usize], &[Piece], &[f64]),
    make: &(dyn Fn(&Piece, f64, f64) -> T + Sync),
) -> Vec<T> {
    let levels = level_tau.len();
    (0..representatives.len() * levels)
        .into_par_iter()
        .map(|k| {
            let tau0 = level_tau[k % levels];
            make(
                &pieces[representatives[k / levels]],
                tau0,
                table_coordinate(tau0),
            )
        })
        .collect()
}

/// `1 / τ0`, the factor from a source density to the source function `J = S / (σt* h)`, and
/// 1 for a cell without medium (which keeps its density).
#[inline(always)]
fn per_optical_side(tau0: f64) -> f64 {
    if tau0 > 0.0 {
        1.0 / tau0
    } else {
        1.0
    }
}

/// The least extinction of a neighbour, relative to the cell's, whose source function a
/// linear source's slope uses: a steeper jump in σt is an edge, not a smooth field, and
/// there `J = S / σt` of an optically thin neighbour (emission in thin smoke, say) would
/// make a slope many times the cell's own source. With it, a slope is at most twice the
/// neighbour's source density.
const SLOPE_NEIGHBOUR_MIN_RATIO: f64 = 0.25;

/// Cell `c`'s (at `ijk` in a grid of `dims`) lower and upper neighbours along `axis`, wrapped
/// at the grid's sides (meaningful where [`source_neighbour_mask`] says they are there).
#[inline(always)]
fn neighbour_cells(dims: [usize; 3], c: usize, ijk: [usize; 3], axis: usize) -> [usize; 2] {
    let stride = match axis {
        0 => 1,
        1 => dims[0],
        _ => dims[0] * dims[1],
    };
    let (i, len) = (ijk[axis], dims[axis]);
    let lo = if i > 0 {
        c - stride
    } else {
        c + (len - 1) * stride
    };
    let hi = if i + 1 < len {
        c + stride
    } else {
        c - (len - 1) * stride
    };
    [lo, hi]
}

/// Per cell, bit `2a` (lower) and `2a + 1` (upper): the neighbour along axis `a` a linear
/// source's slope may use, inside the grid or across a periodic side (x and y when
/// `periodic`, grids wider than one cell), with an extinction `sigma_t` at least
/// [`SLOPE_NEIGHBOUR_MIN_RATIO`] of the cell's; none for an empty cell.
fn source_neighbour_mask(dims: [usize; 3], periodic: bool, sigma_t: &[f64]) -> Vec<u8> {
    let [nx, ny, nz] = dims;
    (0..nx * ny * nz)
        .into_par_iter()
        .map(|c| {
            if sigma_t[c] <= 0.0 {
                return 0;
            }
            let has_medium = |nb: usize| sigma_t[nb] >= SLOPE_NEIGHBOUR_MIN_RATIO * sigma_t[c];
            let ijk = [c % nx, (c / nx) % ny, c / (nx * ny)];
            let mut mask = 0u8;
            for a in 0..3 {
                let (i, len) = (ijk[a], dims[a]);
                let wraps = periodic && a < 2 && len > 1;
                let [lo, hi] = neighbour_cells(dims, c, ijk, a);
                if (i > 0 || wraps) && has_medium(lo) {
                    mask |= 1 << (2 * a);
                }
                if (i + 1 < len || wraps) && has_medium(hi) {
                    mask |= 2 << (2 * a);
                }
            }
            mask
        })
        .collect()
}

/// What one piece's sweep does besides transporting.
#[derive(Clone, Copy, Debug)]
struct Sweep<'a> {
    /// Tally power ([`SweepEnergy`]).
    tally: bool,
    /// Give each cell's source its slopes (with [`OrdinatesOptions::linear_source`]).
    linear: bool,
    /// The lights' first scattering's own slopes ([`BeamProfiles`]; with `linear`).
    beams: Option<&'a BeamProfiles>,
}

/// The six orders of three axes ([`Piece::canonical_axes`]).
const AXIS_ORDERS: [[usize; 3]; 6] = [
    [0, 1, 2],
    [0, 2, 1],
    [1, 0, 2],
    [1, 2, 0],
    [2, 0, 1],
    [2, 1, 0],
];

/// Position along an axis of `len` cells at step `t` of a sweep: `t` travelling forward,
/// `len − 1 − t` backward.
#[inline(always)]
fn at(t: usize, len: usize, fwd: bool) -> usize {
    if fwd {
        t
    } else {
        len - 1 - t
    }
}

/// Column length of bin-major scratch for `n` cells: padded by one cache line so that the
/// columns a loop reads side by side do not all map to the same L1 sets (with `8 n` a
/// multiple of 4096 bytes, as for 64×64×48, the unpadded gather ran 5× slower).
fn padded_stride(n: usize) -> usize {
    n + 8
}

/// Cells per block of the cell-major ↔ bin-major copies.
const TRANSPOSE_BLOCK: usize = 64;

/// Cells per block of the scattering product (one GEMM call each).
const SCATTER_BLOCK: usize = 512;

/// The cells the scattering product multiplies each sweep (`M²` multiply-adds each), given
/// which cells hold medium (the state's) and which scatter (cell index order): every cell
/// with medium of a block of [`SCATTER_BLOCK`] cells that holds a scattering one. Blocks of
/// empty or absorbing cells are skipped; a medium that scatters everywhere (a shield, a
/// uniform block) costs its every cell.
pub fn scattering_product_cells(medium: &[bool], scatters: &[bool]) -> usize {
    assert_eq!(medium.len(), scatters.len());
    medium
        .chunks(SCATTER_BLOCK)
        .zip(scatters.chunks(SCATTER_BLOCK))
        .filter(|(_, s)| s.iter().any(|&s| s))
        .map(|(m, _)| m.iter().filter(|&&m| m).count())
        .sum()
}

/// Where [`OrdinatesOperator::scatter_into`] writes: the state's rows `S[k·M + l]`, or
/// every cell bin-major, `S[l·stride + c]`.
#[derive(Clone, Copy, PartialEq)]
enum Layout {
    Rows,
    BinMajor,
}

/// A raw pointer shared by rayon tasks that write disjoint elements.
#[derive(Clone, Copy)]
struct SharedMut(*mut f64);
// SAFETY: every task writes a disjoint set of cells (its block), see `scatter_into`.
unsafe impl Send for SharedMut {}
unsafe impl Sync for SharedMut {}

impl SharedMut {
    /// The pointer (a method, so that closures capture the `Sync` wrapper, not the field).
    #[inline(always)]
    fn ptr(self) -> *mut f64 {
        self.0
    }
}

/// Pieces whose cell coefficients agree (they are images of each other under the cube's
/// symmetries): `(class of each piece, one representative per class)`.
/// Classes of pieces with the same cell coefficients in their canonical axes (compared at
/// optical sides from empty to thick): the class of each piece, and one piece per class.
fn piece_classes(pieces: &[Piece], face_coupling: bool) -> (Vec<usize>, Vec<usize>) {
    const PROBES: [f64; 9] = [0.0, 1e-3, 0.05, 0.3, 1.0, 3.0, 10.0, 40.0, 300.0];
    let signature = |p: &Piece| -> Vec<f64> {
        PROBES
            .iter()
            .flat_map(|&tau0| {
                let ct = p.canonical_terms(tau0, table_coordinate(tau0), 1.0, face_coupling);
                ct.transmit
                    .into_iter()
                    .chain(ct.inflow_mean)
                    .chain(ct.source_out)
                    .chain([ct.source_mean])
            })
            .collect()
    };
    // Images share one coupling table (the same numbers); Max's shares' tables of images sum
    // their samples in other orders (rounding, beyond 1e-12 at 384 bins).
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-9 * a.abs().max(b.abs());
    let signatures: Vec<Vec<f64>> = pieces.iter().map(signature).collect();
    let mut reps: Vec<usize> = Vec::new();
    let mut class = Vec::with_capacity(pieces.len());
    for (p, sig) in signatures.iter().enumerate() {
        let same = |r: &usize| sig.iter().zip(&signatures[*r]).all(|(a, b)| close(*a, *b));
        match reps.iter().position(same) {
            Some(k) => class.push(k),
            None => {
                class.push(reps.len());
                reps.push(p);
            }
        }
    }
    (class, reps)
}

/// The discrete-ordinates operator `K` for one colour channel (see the module doc).
///
/// # Invariants
/// Built only by [`OrdinatesOperator::new`], from one channel of a valid [`Medium`]: σt, σs
/// and the emission (`n` values each, finite, `0 ≤ σs ≤ σt`) and the phase function are that
/// channel's, and the per-cell sweep coefficients and the phase matrix are derived from them
/// (and from the δ-M truncation of [`OrdinatesOptions::forward_truncation_degrees`]: the
/// sweep through `σt − f σs`, the matrix of the clipped phase function scaled by `1 − f`)
/// once; the fields are private, so they stay consistent.
pub struct OrdinatesOperator {
    grid: Grid,
    /// The cells that carry unknowns (σt > 0): the state vectors' rows, `S[k·M + l]` for
    /// row `k`'s cell.
    state: StateCells,
    sigma_t: Vec<f64>,
    sigma_s: Vec<f64>,
    /// The δ-M fraction `f` the sweep treats as unscattered (`σt* = σt − f σs`).
    truncation: f64,
    /// The channel's emission per cell (the isotropic part of the external density).
    emission: Vec<f64>,
    /// Class of each piece ([`piece_classes`]).
    piece_class: Vec<usize>,
    /// Class-major coefficients, `classes × levels` ([`OrdinatesOperator::cell_level`]).
    terms: Vec<CellTerms>,
    /// Class-major linear-face moment coefficients, `classes × MOMENT_NODES`
    /// ([`OrdinatesOptions::linear_faces`] where it applies; empty otherwise).
    moment_terms: Vec<MomentTerms>,
    /// Per level, its moment node ([`moment_node_of`]) and `1 / (σt* h)` (0 for none); empty
    /// without linear faces.
    level_moments: Vec<(u32, f64)>,
    /// Per cell, its level: the index of its σt* among the medium's distinct values.
    cell_level: Vec<u32>,
    /// Per cell, `σs / (σt* h)` with a linear source ([`sweep_scale`](Self::sweep_scale));
    /// empty otherwise.
    source_function_scale: Vec<f64>,
    /// Class-major slope coefficients like `terms` ([`OrdinatesOptions::linear_source`];
    /// empty otherwise).
    slope_terms: Vec<SlopeTerms>,
    /// Per cell, the neighbours a linear source's slopes use ([`source_neighbour_mask`]);
    /// empty unless [`OrdinatesOptions::linear_source`].
    source_neighbours: Vec<u8>,
    /// Per level, the swept (sub-)cell's optical side `σt* h`: what a cell extinguishes is
    /// this times its mean radiance.
    level_tau: Vec<f64>,
    /// Distance between consecutive bins' (pieces') columns in the bin-major scratch.
    stride: usize,
    bins: DirectionBins,
    phase: PhaseFunction,
    matrix: PhaseMatrix,
    /// `P_lj Ω_j`, row-major.
    scatter: Vec<f64>,
    pieces: Vec<Piece>,
    /// Indices of each bin's pieces.
    bin_pieces: Vec<Vec<usize>>,
    /// The bins swept together (`gauss_seidel_group` in index order), and each group's
    /// pieces (consecutive: pieces come in bin order).
    groups: Vec<std::ops::Range<usize>>,
    group_pieces: Vec<std::ops::Range<usize>>,
    options: OrdinatesOptions,
    scratch: Mutex<Scratch>,
}

/// What [`OrdinatesOperator::sweep_until_change`] reached.
#[derive(Clone, Debug)]
pub struct SweepSolve {
    pub solution: Vec<f64>,
    pub iterations: usize,
    /// `‖Δg‖ / ‖E‖` of the last sweep.
    pub final_change: f64,
}

impl OrdinatesOperator {
    /// The operator for channel `channel` of `medium` (whose σt, albedo, emission and phase
    /// function are valid by [`Medium`]'s invariants; a changed medium is built through
    /// [`Medium::with_channel`] or [`Medium::new`]).
    pub fn new(
        medium: &Medium,
        channel: usize,
        bins: DirectionBins,
        options: OrdinatesOptions,
    ) -> Result<Self, OrdinatesError> {
        let channel = medium
            .channels()
            .get(channel)
            .ok_or(OrdinatesError::Channel {
                channel,
                channels: medium.channels().len(),
            })?;
        let grid = *medium.grid();
        let phase = medium.phase();
        let n = grid.cell_count();
        let r = options.transport_refinement;
        if !(1..=MAX_TRANSPORT_REFINEMENT).contains(&r) {
            return Err(OrdinatesError::Option(format!(
                "transport_refinement = {r}: must be in 1..={MAX_TRANSPORT_REFINEMENT}"
            )));
        }
        if r > 1 && options.periodic_xy {
            return Err(OrdinatesError::Option(
                "transport_refinement > 1 supports vacuum sides only, not periodic_xy".into(),
            ));
        }
        let sigma_t: Vec<f64> = channel.sigma_t.iter().map(|&s| s as f64).collect();
        let sigma_s: Vec<f64> = (0..n)
            .map(|i| sigma_t[i] * channel.albedo.get(i) as f64)
            .collect();
        let emission: Vec<f64> = (0..n).map(|i| channel.emission.get(i) as f64).collect();
        let degrees = options.forward_truncation_degrees;
        let f = forward_truncation_fraction(degrees, &phase)?;
        // Transport through σt* = σt − f σs: scattering into the peak is not an interaction.
        let sweep_sigma_t: Vec<f64> = sigma_t
            .iter()
            .zip(&sigma_s)
            .map(|(&st, &ss)| (st - f * ss).max(0.0))
            .collect();
        let k = options
            .phase_quadrature
            .unwrap_or_else(|| default_quadrature(&bins));
        let mut matrix = if degrees > 0.0 {
            // p* ∝ p(min(μ, μc)): HG grows with μ, so this clips the peak flat.
            let mu_c = degrees.to_radians().cos();
            PhaseMatrix::from_density(&bins, |mu| phase.eval(mu.min(mu_c)), k)
        } else {
            PhaseMatrix::new(&bins, &phase, k)
        };
        if options.match_asymmetry && (options.match_diffusion || !phase.is_isotropic()) {
            // The δ-peak carries f of the asymmetry: g = f + (1 − f) g*.
            let g_truncated = (phase.mean_cosine() - f) / (1.0 - f);
            let target = if options.match_diffusion {
                g_truncated + bins.diffusion_loss() * (1.0 - g_truncated)
            } else {
                g_truncated
            };
            if bins.len() >= FORWARD_MATCH_MIN_BINS {
                matrix.match_asymmetry_forward(&bins, target);
            } else {
                matrix.match_asymmetry(&bins, target);
            }
        }
        let m = bins.len();
        let omega = bins.solid_angles();
        // σs* = (1 − f) σs: the factor rides on the weights, as σs scales the rows.
        let scatter: Vec<f64> = (0..m * m)
            .map(|idx| (1.0 - f) * matrix.values()[idx] * omega[idx % m])
            .collect();
        // Linear faces where the sweep carries them: whole cells, vacuum sides or a
        // one-cell-wide periodic column.
        let faces = options.linear_faces
            && options.face_coupling
            && r == 1
            && !(options.periodic_xy && (grid.dims[0] > 1 || grid.dims[1] > 1));
        let pieces = pieces_of(&bins, options.exact_transmission, options.face_coupling);
        let mut bin_pieces = vec![Vec::new(); m];
        for (p, piece) in pieces.iter().enumerate() {
            bin_pieces[piece.bin].push(p);
        }
        let group = options.gauss_seidel_group.max(1);
        let groups: Vec<std::ops::Range<usize>> = (0..m)
            .step_by(group)
            .map(|start| start..(start + group).min(m))
            .collect();
        // Pieces are made bin by bin, so a group's are consecutive.
        let group_pieces: Vec<std::ops::Range<usize>> = groups
            .iter()
            .map(|bins| {
                let first = bin_pieces[bins.start].first().copied();
                let last = bin_pieces[bins.end - 1].last().copied();
                match (first, last) {
                    (Some(p0), Some(p1)) => p0..p1 + 1,
                    _ => 0..0,
                }
            })
            .collect();
        debug_assert!(group_pieces
            .iter()
            .zip(&groups)
            .all(|(ps, bins)| ps.clone().all(|p| bins.contains(&pieces[p].bin))));
        let most_pieces = group_pieces.iter().map(|p| p.len()).max().unwrap_or(0);
        let layer = grid.dims[0] * grid.dims[1] * r * r;
        let stride = padded_stride(n);
        let scratch = Scratch {
            density: vec![0.0; stride * group.min(m)],
            piece_out: vec![0.0; stride * most_pieces],
            layers: (0..most_pieces)
                .map(|_| LayerBuffers {
                    out: vec![0.0; layer],
                    out_y: vec![0.0; layer],
                    out_x: vec![0.0; if options.periodic_xy { layer } else { 0 }],
                    inz: vec![0.0; layer],
                    faces_z: vec![[0.0; 3]; if faces { layer } else { 0 }],
                    faces_y: vec![[0.0; 3]; if faces { layer } else { 0 }],
                })
                .collect(),
        };
        let (piece_class, representatives) = piece_classes(&pieces, options.face_coupling);
        tracing::debug!(
            pieces = pieces.len(),
            classes = representatives.len(),
            "discrete-ordinates sweep pieces"
        );
        // Coefficients of the swept (sub-)cells.
        let h = grid.cell_size / r as f64;
        // The coefficients depend on a cell's σt* alone: one set per distinct value (all
        // empty cells share one), so a sweep streams a 4-byte index per cell and reads
        // coefficients that mostly stay in cache.
        let mut level_sigma: Vec<f64> = sweep_sigma_t.clone();
        level_sigma.sort_by(f64::total_cmp);
        level_sigma.dedup();
        let cell_level: Vec<u32> = sweep_sigma_t
            .par_iter()
            .map(|s| level_sigma.partition_point(|v| v < s) as u32)
            .collect();
        let level_tau: Vec<f64> = level_sigma.iter().map(|s| s * h).collect();
        let levels = level_tau.len();
        tracing::debug!(levels, cells = n, "discrete-ordinates coefficient levels");
        let classes = (&representatives[..], &pieces[..], &level_tau[..]);
        let terms: Vec<CellTerms> = per_class_and_level(classes, &|piece, tau0, x| {
            piece.canonical_terms(tau0, x, h, options.face_coupling)
        });
        let (moment_terms, level_moments) = if faces {
            let nodes: Vec<f64> = (0..MOMENT_NODES).map(moment_node_tau).collect();
            let moments = per_class_and_level((&representatives, &pieces, &nodes), &|p, t, _| {
                let faces = p
                    .faces
                    .as_ref()
                    .expect("pieces have face tables with linear faces");
                MomentTerms::of(faces, t, h)
            });
            let per_level = level_tau
                .iter()
                .map(|&t| (moment_node_of(t), if t > 0.0 { 1.0 / t } else { 0.0 }))
                .collect();
            (moments, per_level)
        } else {
            (Vec::new(), Vec::new())
        };
        // The linear source's state: the slopes' coefficients, the scattering product's
        // scale to the source function, and which neighbours each cell's slopes read.
        let linear = options.linear_source && options.face_coupling;
        let (slope_terms, source_function_scale, source_neighbours) = if linear {
            (
                per_class_and_level(classes, &|piece, tau0, x| piece.slope_terms(tau0, x, h)),
                sigma_s
                    .iter()
                    .zip(&cell_level)
                    .map(|(s, &l)| s * per_optical_side(level_tau[l as usize]))
                    .collect(),
                source_neighbour_mask(grid.dims, options.periodic_xy, &sweep_sigma_t),
            )
        } else {
            (Vec::new(), Vec::new(), Vec::new())
        };
        let state = StateCells::new(&sigma_t, SCATTER_BLOCK).ok_or_else(|| {
            OrdinatesError::Medium(format!("{n} cells: more than a 32-bit index reaches"))
        })?;
        tracing::debug!(
            state_cells = state.len(),
            cells = n,
            "discrete-ordinates state: the cells with medium"
        );
        Ok(OrdinatesOperator {
            grid,
            state,
            sigma_t,
            sigma_s,
            truncation: f,
            emission,
            bins,
            phase,
            matrix,
            scatter,
            pieces,
            bin_pieces,
            groups,
            group_pieces,
            piece_class,
            terms,
            moment_terms,
            level_moments,
            source_function_scale,
            slope_terms,
            source_neighbours,
            cell_level,
            level_tau,
            stride,
            options,
            scratch: Mutex::new(scratch),
        })
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// The cells that carry unknowns, in cell order: those with medium (σt > 0). Every
    /// cells × bins vector of this operator (a solution, a density, a transported field)
    /// holds their rows, `v[k·M + l]` for bin `l` of cell `state_cells()[k]`; light crosses
    /// the empty cells in the sweeps alone.
    pub fn state_cells(&self) -> &[u32] {
        self.state.cells()
    }

    /// Cell `c`'s row in the operator's vectors, if it carries state.
    pub fn state_row(&self, c: usize) -> Option<usize> {
        self.state.row(c)
    }

    pub fn bins(&self) -> &DirectionBins {
        &self.bins
    }

    pub fn phase_matrix(&self) -> &PhaseMatrix {
        &self.matrix
    }

    /// Piece `p`'s outflows through cell `c`'s downstream faces (by grid axis; each face's
    /// moments, [`OrdinatesOptions::linear_faces`], or its flux alone in moment 0 with uniform
    /// faces) and its mean radiance there, for `inflow` through its upstream faces and source
    /// density `sd`: the sweep's step, for the assembled operator.
    pub(crate) fn cell_response(
        &self,
        p: usize,
        c: usize,
        ijk: [usize; 3],
        inflow: [[f64; 3]; 3],
        density: &[f64],
    ) -> ([[f64; 3]; 3], f64) {
        let levels = self.level_tau.len();
        let k = self.piece_class[p] * levels + self.cell_level[c] as usize;
        let piece = &self.pieces[p];
        let axes = piece.canonical_axes;
        if self.linear_faces() {
            let cell = (c, ijk, self.cell_level[c] as usize);
            let modes = (
                self.pieces[p].canonical_axes,
                self.linear_source(),
                &[][..],
                None,
            );
            let step = self.face_cell(p, cell, inflow, density, modes);
            return (step.out, step.mean);
        }
        let terms = (&self.terms[k], self.slope_terms.get(k));
        let src = self.cell_source(terms, density, (c, ijk), (piece, axes), None);
        let ct = terms.0;
        let flux = inflow.map(|f| f[0]);
        (
            ct.outflow(flux, &src, axes).map(|f| [f, 0.0, 0.0]),
            ct.mean_radiance(flux, &src, axes),
        )
    }

    /// Cell coefficients of piece class `class` at level `level` with linear faces (the
    /// source's slopes' only where `linear`).
    #[inline(always)]
    fn face_step(&self, class: usize, level: usize, linear: bool) -> FaceStep<'_> {
        let k = class * self.level_tau.len() + level;
        let (node, inverse_tau) = self.level_moments[level];
        FaceStep {
            ct: &self.terms[k],
            st: if linear {
                self.slope_terms.get(k)
            } else {
                None
            },
            mt: &self.moment_terms[class * MOMENT_NODES + node as usize],
            inverse_tau,
        }
    }

    /// Piece `p`'s step with linear faces through `cell` (its index, `ijk` and level) for
    /// `inflow` moments by grid axis and the bin's `density` column (the source function
    /// where `linear`), `axes` the piece's canonical axes (a constant in the compiled sweeps),
    /// closing the one-cell periodic `looped` slots: the sweep's and the
    /// assembled operator's one cell step.
    #[inline(always)]
    fn face_cell(
        &self,
        p: usize,
        (c, ijk, level): (usize, [usize; 3], usize),
        inflow: [[f64; 3]; 3],
        density: &[f64],
        (axes, linear, looped, beams): FaceModes<'_>,
    ) -> CellStep<[f64; 3]> {
        let piece = &self.pieces[p];
        let mut inflow = axes.map(|a| inflow[a]);
        let step = self.face_step(self.piece_class[p], level, linear);
        let (sd, o, mean) = if step.inverse_tau == 0.0 && looped.is_empty() {
            // No medium (most of a cloud's box): its source (emission only) is uniform, the
            // source function column holding S there.
            let sd = density[c];
            let (o, mean) = step.vacuum_step(&inflow, sd);
            (sd, o, mean)
        } else {
            let (sd, slopes) = if linear {
                let (sd, s) = self.source_slopes(density, c, ijk, piece, beams);
                (sd, axes.map(|a| s[a]))
            } else {
                (density[c], [0.0; 3])
            };
            let (source_out, source_mean) = step.source(sd, slopes);
            if !looped.is_empty() {
                step.close_loops(&mut inflow, &source_out, looped);
            }
            let (o, mean) = step.step(&inflow, &source_out, source_mean);
            (sd, o, mean)
        };
        let mut out = [[0.0; 3]; 3];
        for (slot, &axis) in axes.iter().enumerate() {
            out[axis] = o[slot];
        }
        CellStep {
            out,
            mean,
            density: sd,
        }
    }

    /// Whether the sweep carries linear face fluxes ([`OrdinatesOptions::linear_faces`] where
    /// it applies: whole cells, vacuum sides or a one-cell-wide periodic column).
    pub fn linear_faces(&self) -> bool {
        !self.moment_terms.is_empty()
    }

    /// Whether the sweep's sources are linear in each cell
    /// ([`OrdinatesOptions::linear_source`] with the face coupling).
    pub fn linear_source(&self) -> bool {
        !self.slope_terms.is_empty()
    }

    /// What a unit source density in cell `c` is in the sweep's column: itself, or with a
    /// linear source the source function `1 / (σt* h)`.
    pub(crate) fn source_function_of_unit_density(&self, c: usize) -> f64 {
        if self.linear_source() {
            per_optical_side(self.level_tau[self.cell_level[c] as usize])
        } else {
            1.0
        }
    }

    pub fn pieces(&self) -> &[Piece] {
        &self.pieces
    }

    pub fn options(&self) -> &OrdinatesOptions {
        &self.options
    }

    /// σt per cell (f64).
    pub fn sigma_t(&self) -> &[f64] {
        &self.sigma_t
    }

    /// σs = a σt per cell.
    pub fn sigma_s(&self) -> &[f64] {
        &self.sigma_s
    }

    /// Block Gauss–Seidel sweeps from `g = E` until the relative change `‖Δg‖ / ‖E‖` falls
    /// below `tolerance` (or `max_iterations` sweeps): the solve that the discrete-ordinates
    /// benchmark and `examples/ordinates_timing.rs` time, with no report or cancellation
    /// overhead (volrad's solves go through `solver`).
    pub fn sweep_until_change(
        &self,
        e: &[f64],
        tolerance: f64,
        max_iterations: usize,
    ) -> SweepSolve {
        let norm_e = e.iter().map(|x| x * x).sum::<f64>().sqrt();
        let mut g = e.to_vec();
        let mut before = g.clone();
        let (mut iterations, mut change) = (0, f64::INFINITY);
        while change >= tolerance && iterations < max_iterations {
            before.copy_from_slice(&g);
            self.sweep_in_place(&mut g, e, 1.0);
            iterations += 1;
            let d: f64 = g
                .iter()
                .zip(&before)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            change = d / norm_e;
        }
        SweepSolve {
            solution: g,
            iterations,
            final_change: change,
        }
    }

    /// Bytes of the operator's own buffers (f64 scratch of one group of bins: density,
    /// sweep output and layer buffers; the per-cell coefficients), excluding the solver's
    /// vectors.
    pub fn scratch_bytes(&self) -> usize {
        let s = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        (s.density.len() + s.piece_out.len()) * 8
            + s.layers
                .iter()
                .map(|l| {
                    (l.out.len() + l.out_y.len() + l.out_x.len() + l.inz.len()) * 8
                        + (l.faces_z.len() + l.faces_y.len()) * 24
                })
                .sum::<usize>()
            + self.terms.len() * std::mem::size_of::<CellTerms>()
            + self.moment_terms.len() * std::mem::size_of::<MomentTerms>()
            + self.level_moments.len() * 16
            + self.slope_terms.len() * std::mem::size_of::<SlopeTerms>()
            + self.source_neighbours.len()
            + self.source_function_scale.len() * 8
            + self.cell_level.len() * 4
            + self.level_tau.len() * 8
            + self.state.bytes()
    }

    /// Scattering density `S[k·M + l] = σs Σ_j P_lj x_j Ω_j` of each state row (radiance
    /// per length).
    pub fn scatter_density(&self, x: &[f64], density: &mut [f64]) {
        let m = self.bins.len();
        assert!(
            x.len() == self.len() && density.len() == self.len(),
            "scatter_density: vectors must have state cells × bins entries"
        );
        self.scatter_into(&self.scatter, x, density, Layout::Rows, 0..m);
    }

    /// Scattering densities of `bins` in `layout`, by blocks of cells: one GEMM
    /// `X_block (rows × M) · Wᵀ (M × bins)` per block of the state's rows, then the rows
    /// scaled by σs. Blocks without scattering cells are written as zeros without the
    /// product. `weights` (`W[l·M + j]`, M × M row-major) is the solve's `P_lj Ω_j`
    /// (`self.scatter`) or the final gather's weights ([`gather_density`](Self::gather_density)).
    /// `Rows` `dst` holds every bin of the state's rows; bin-major `dst` holds `bins` alone,
    /// from its first column, for every cell (zero where no state is).
    fn scatter_into(
        &self,
        weights: &[f64],
        x: &[f64],
        dst: &mut [f64],
        layout: Layout,
        bins: std::ops::Range<usize>,
    ) {
        let n = self.grid.cell_count();
        let m = self.bins.len();
        assert!(
            x.len() == self.len()
                && bins.start < bins.end
                && bins.end <= m
                && weights.len() == m * m
        );
        assert!(
            dst.len()
                >= match layout {
                    Layout::BinMajor => bins.len() * self.stride,
                    Layout::Rows => self.len(),
                }
        );
        let first_column = match layout {
            Layout::BinMajor => bins.start,
            Layout::Rows => 0,
        };
        // Bin-major densities are the sweeps' input: the source function with a linear source.
        let scale = match layout {
            Layout::BinMajor => self.sweep_scale(),
            Layout::Rows => &self.sigma_s,
        };
        let base = SharedMut(dst.as_mut_ptr());
        (0..n.div_ceil(SCATTER_BLOCK))
            .into_par_iter()
            .for_each(|b| {
                // SAFETY: `x` has the state's rows (asserted), `dst` is large enough for
                // `layout` (asserted above), and block b is this task's alone.
                unsafe {
                    self.scatter_block(
                        (weights, scale),
                        x.as_ptr(),
                        (base, layout, first_column),
                        bins.clone(),
                        b,
                    )
                };
            });
    }

    /// [`scatter_into`](Self::scatter_into) for the cells of block `block` (of
    /// [`SCATTER_BLOCK`] cells) from the state rows `x`, written into `dst`: `(pointer,
    /// layout, the bin of its first column)`.
    ///
    /// # Safety
    /// `weights` must hold M × M values, `x` must point to the state's rows (`len()`
    /// values), `dst` to a whole array in `layout` whose columns (bin-major) start at its
    /// first column's bin and reach past `bins`, and no one else may write `x` for these
    /// cells, or access the elements (cell or row of this block, `l` in `bins`) of `dst`,
    /// while this runs.
    unsafe fn scatter_block(
        &self,
        (weights, scale): (&[f64], &[f64]),
        x: *const f64,
        (dst, layout, first_column): (SharedMut, Layout, usize),
        bins: std::ops::Range<usize>,
        block: usize,
    ) {
        let m = self.bins.len();
        let rows = self.state.rows_of_block(block);
        let cells = self.state.cells_of_block(block);
        let row_cells = &self.state.cells()[rows.clone()];
        let scatters = row_cells.iter().any(|&c| scale[c as usize] != 0.0);
        debug_assert!(bins.start >= first_column);
        let product = |out: *mut f64, rsc: usize, csc: usize| {
            matrixmultiply::dgemm(
                rows.len(),
                m,
                bins.len(),
                1.0,
                x.add(rows.start * m),
                m as isize,
                1,
                weights.as_ptr().add(bins.start * m),
                1,
                m as isize,
                0.0,
                out,
                rsc as isize,
                csc as isize,
            )
        };
        match layout {
            Layout::Rows => {
                let at = |k: usize, l: usize| dst.ptr().add(k * m + l - first_column);
                if scatters {
                    product(at(rows.start, bins.start), m, 1);
                }
                for (k, &c) in rows.zip(row_cells) {
                    for l in bins.clone() {
                        *at(k, l) = if scatters {
                            *at(k, l) * scale[c as usize]
                        } else {
                            0.0
                        };
                    }
                }
            }
            Layout::BinMajor => {
                let column = |l: usize| dst.ptr().add((l - first_column) * self.stride);
                if scatters {
                    // The product's rows land packed from the block's first cell, then
                    // move out to their cells from the last: a row's cell is never before
                    // its packed place, nor at a packed place not yet read.
                    product(column(bins.start).add(cells.start), 1, self.stride);
                }
                for l in bins {
                    let col = column(l);
                    if scatters {
                        for (i, &c) in row_cells.iter().enumerate().rev() {
                            let c = c as usize;
                            *col.add(c) = *col.add(cells.start + i) * scale[c];
                        }
                        for c in self.state.empty_cells_of_block(block) {
                            *col.add(c) = 0.0;
                        }
                    } else {
                        for c in cells.clone() {
                            *col.add(c) = 0.0;
                        }
                    }
                }
            }
        }
    }

    /// Copies the columns `bins` of the state rows `src` into bin-major `dst` (columns
    /// `stride` apart, the first `bins.start`'s; zero at cells without state), by blocks of
    /// cells so that both sides stream.
    fn cells_to_bins(&self, src: &[f64], bins: std::ops::Range<usize>, dst: &mut [f64]) {
        let n = self.grid.cell_count();
        let m = self.bins.len();
        assert!(src.len() == self.len() && bins.end <= m && dst.len() >= bins.len() * self.stride);
        let base = SharedMut(dst.as_mut_ptr());
        (0..n.div_ceil(SCATTER_BLOCK))
            .into_par_iter()
            .for_each(|b| {
                let rows = self.state.rows_of_block(b);
                let row_cells = &self.state.cells()[rows.clone()];
                for l in bins.clone() {
                    let column = (l - bins.start) * self.stride;
                    // SAFETY: inside `dst` (asserted); block b's cells are this task's.
                    unsafe {
                        for c in self.state.empty_cells_of_block(b) {
                            *base.ptr().add(column + c) = 0.0;
                        }
                        for (k, &c) in rows.clone().zip(row_cells) {
                            *base.ptr().add(column + c as usize) = src[k * m + l];
                        }
                    }
                }
            });
    }

    /// The lights' first-bounce density `σs p̄_l(d) irradiance` (`lights`: flow direction,
    /// per-cell mean `E·T_L`), the state's rows. Directional lights use exact bin averages
    /// `p̄_l(d)`. (The channel's emission is the operator's own:
    /// [`transport_external`](Self::transport_external) sweeps it.)
    pub fn external_density(&self, lights: &[(DVec3, &[f64])]) -> Result<Vec<f64>, OrdinatesError> {
        let n = self.grid.cell_count();
        let mut density = vec![0.0; self.len()];
        for &(dir, irradiance) in lights {
            if irradiance.len() != n {
                return Err(OrdinatesError::Length {
                    what: "cell irradiance",
                    got: irradiance.len(),
                    expected: n,
                });
            }
            let pbar = bin_averaged_phase(
                &self.bins,
                &self.phase,
                dir,
                self.options.first_bounce_quadrature,
            );
            self.for_each_row(&mut density, |c, d| {
                let w = self.sigma_s[c] * irradiance[c];
                if w != 0.0 {
                    for (dl, p) in d.iter_mut().zip(&pbar) {
                        *dl += w * p;
                    }
                }
            });
        }
        Ok(density)
    }

    /// `f(cell, bins)` for each row of a state vector, in parallel.
    fn for_each_row(&self, v: &mut [f64], f: impl Fn(usize, &mut [f64]) + Sync) {
        let cells = self.state.cells();
        v.par_chunks_mut(self.bins.len())
            .zip(cells)
            .for_each(|(d, &c)| f(c as usize, d));
    }

    /// The lights' first-bounce density from a light pass (which must be for this
    /// operator's grid), the state's rows: [`external_density`](Self::external_density) for
    /// directional lights; point and spot lights use `p(ω_l·d)` at bin centres for the
    /// direction `d` from the light to each cell centre, renormalised per cell (a bin-centre
    /// approximation).
    pub fn first_bounce_density_from_pass(
        &self,
        pass: &LightPass,
    ) -> Result<Vec<f64>, OrdinatesError> {
        self.density_from_pass(pass)
    }

    /// That `pass` is of this operator's grid and each of its fields holds a cell irradiance
    /// per cell (the pass's fields are public: their lengths are not guaranteed).
    fn check_pass(&self, pass: &LightPass) -> Result<(), OrdinatesError> {
        let n = self.grid.cell_count();
        if pass.grid != self.grid {
            return Err(OrdinatesError::ForeignLightPass);
        }
        match pass.fields.iter().find(|f| f.cell_irradiance.len() != n) {
            Some(f) => Err(OrdinatesError::Length {
                what: "cell irradiance",
                got: f.cell_irradiance.len(),
                expected: n,
            }),
            None => Ok(()),
        }
    }

    fn density_from_pass(&self, pass: &LightPass) -> Result<Vec<f64>, OrdinatesError> {
        let m = self.bins.len();
        self.check_pass(pass)?;
        let mut directional = Vec::new();
        let mut irr_store = Vec::new();
        for f in &pass.fields {
            irr_store.push(
                f.cell_irradiance
                    .iter()
                    .map(|&v| v as f64)
                    .collect::<Vec<f64>>(),
            );
        }
        for (f, irr) in pass.fields.iter().zip(&irr_store) {
            if let Light::Directional { direction, .. } = f.light {
                directional.push((direction, irr.as_slice()));
            }
        }
        let mut density = self.external_density(&directional)?;
        let omega = self.bins.solid_angles();
        let centres = self.bins.centres();
        for (f, irr) in pass.fields.iter().zip(&irr_store) {
            if matches!(f.light, Light::Directional { .. }) {
                continue;
            }
            self.for_each_row(&mut density, |c, d| {
                let w = self.sigma_s[c] * irr[c];
                if w == 0.0 {
                    return;
                }
                let (dir, _) = f.light.arriving_at(self.grid.cell_center(c));
                let norm: f64 = (0..m)
                    .map(|l| self.phase.eval(centres[l].dot(dir)) * omega[l])
                    .sum();
                for (l, dl) in d.iter_mut().enumerate() {
                    *dl += w * self.phase.eval(centres[l].dot(dir)) / norm;
                }
            });
        }
        Ok(density)
    }

    /// Adds the first-collision density of the uncollided light an emitter pass gives (per
    /// cell its scalar flux, net flux vector and mean squared cosine about it) to `density`
    /// (the state's rows). The light's angular shape is a uniform cone about `J` and an
    /// isotropic rest with the pass's three moments ([`medium::phase::IncidentShape`]; a beam,
    /// an isotropic field and a compact uniform source seen from outside are exact), scattered
    /// by [`medium::phase::ShapeScattering`] toward the bin centres, renormalised per cell as
    /// for point lights. So `Σ_l density Ω_l` grows by `σs φ` per cell. (A Henyey–Greenstein
    /// lobe of the same mean cosine, the shape before, scattered a nearby emitter's light,
    /// which arrives from a wide cone with sharp edges, 2.6–3.4× too strongly forward:
    /// `benches/incident_shape.py`.)
    pub fn add_collision_density(
        &self,
        pass: &medium::emitter_pass::EmitterPass,
        density: &mut [f64],
    ) -> Result<(), OrdinatesError> {
        let n = self.grid.cell_count();
        let m = self.bins.len();
        let fluence = pass.fluence();
        if fluence.len() != n {
            return Err(OrdinatesError::Length {
                what: "emitter pass",
                got: fluence.len(),
                expected: n,
            });
        }
        if density.len() != self.len() {
            return Err(OrdinatesError::Length {
                what: "density",
                got: density.len(),
                expected: self.len(),
            });
        }
        let omega = self.bins.solid_angles();
        let centres = self.bins.centres();
        let table = self.phase.shape_scattering();
        self.for_each_row(density, |c, d| {
            let ss = self.sigma_s[c];
            let phi = fluence[c];
            if ss == 0.0 || phi <= 0.0 {
                return;
            }
            let (shape, dir) = pass.incident_shape(c);
            let scattered = |l: usize| table.eval(shape, centres[l].dot(dir));
            let norm: f64 = (0..m).map(|l| scattered(l) * omega[l]).sum();
            for (l, dl) in d.iter_mut().enumerate() {
                *dl += ss * phi * scattered(l) / norm;
            }
        });
        Ok(())
    }

    /// Transports a density (`S[k·M + l]` of the state's rows, radiance per length) through
    /// the grid: `out[k·M + l]` = the cell- and bin-averaged radiance it produces. Returns the power
    /// bookkeeping. The density is taken as scattered light, `σs` times a smooth field (the
    /// lights' first scattering, a first-collision density): with
    /// [`OrdinatesOptions::linear_source`] its slopes are the source function's. Emission goes
    /// through [`transport_emission`](Self::transport_emission).
    pub fn transport(&self, density: &[f64], out: &mut [f64]) -> SweepEnergy {
        self.transport_density(density, out, true, None, None)
    }

    /// [`transport`](Self::transport) of a density that holds the first scattering of the
    /// lights `beams` profiles (with anything else, such as a first-collision density): their
    /// part of each cell's slopes is the beam's own profile, not the neighbours' differences
    /// ([`BeamProfiles`]). With `fluence` (one value per cell) adds to it the transported
    /// light's fluence at every cell, those without state too.
    pub fn transport_first_bounce(
        &self,
        density: &[f64],
        beams: &BeamProfiles,
        out: &mut [f64],
        fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        self.transport_density(density, out, true, Some(beams), fluence)
    }

    /// The radiance of an isotropic emission density `emission` (one value per cell, any
    /// cell): swept uniform in each cell whatever [`OrdinatesOptions::linear_source`] says,
    /// since emission need not follow σt (a glow given per length is smooth in itself, not
    /// over σt) and its slopes from the source function would be wrong where σt varies.
    pub fn transport_emission(
        &self,
        emission: &[f64],
        out: &mut [f64],
    ) -> Result<SweepEnergy, OrdinatesError> {
        if emission.len() != self.grid.cell_count() {
            return Err(OrdinatesError::Length {
                what: "emission",
                got: emission.len(),
                expected: self.grid.cell_count(),
            });
        }
        Ok(self.transport_emitted(emission, out, false, None))
    }

    fn transport_density(
        &self,
        density: &[f64],
        out: &mut [f64],
        linear: bool,
        beams: Option<&BeamProfiles>,
        fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        let n = self.grid.cell_count();
        let m = self.bins.len();
        assert!(
            density.len() == self.len() && out.len() == self.len(),
            "transport: vectors must have state cells × bins entries"
        );
        // Empty profiles (a flat source, the option off, no directional light) change nothing.
        let beams = beams.filter(|b| b.lights() > 0);
        assert!(
            beams.is_none_or(|b| b.fits(n, m)),
            "transport: beam profiles made by another operator"
        );
        // Each group's bin-major copy for the sweeps.
        let fill = |bins: std::ops::Range<usize>, dst: &mut [f64]| {
            self.cells_to_bins(density, bins.clone(), dst);
            if linear && self.linear_source() {
                self.densities_to_source_function(dst, bins.len());
            }
        };
        self.transport_tallied(out, (linear, beams), false, fill, fluence)
    }

    /// [`transport_all`](Self::transport_all) with power tallied, under the scratch's lock.
    fn transport_tallied(
        &self,
        out: &mut [f64],
        (linear, beams): (bool, Option<&BeamProfiles>),
        add: bool,
        fill: impl Fn(std::ops::Range<usize>, &mut [f64]),
        fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let sweep = Sweep {
            tally: true,
            linear,
            beams,
        };
        self.transport_all(Some(out), &mut guard, sweep, add, fill, fluence)
    }

    /// `T_e(emission)` into `out` (added to it with `add`): each cell's isotropic emission
    /// density straight into every bin's column, swept flat.
    fn transport_emitted(
        &self,
        emission: &[f64],
        out: &mut [f64],
        add: bool,
        fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        let fill = |bins: std::ops::Range<usize>, dst: &mut [f64]| {
            let stride = self.stride;
            dst[..bins.len() * stride]
                .par_chunks_mut(stride)
                .for_each(|column| column[..emission.len()].copy_from_slice(emission));
        };
        self.transport_tallied(out, (false, None), add, fill, fluence)
    }

    /// The system's source from the lights' first scattering `scattered` (the state's rows,
    /// as [`first_bounce_density_from_pass`](Self::first_bounce_density_from_pass) gives it,
    /// with any first-collision density of emitters added) and the channel's own emission:
    /// `out = T(scattered) + T_e(emission)`, the emission swept as
    /// [`transport_emission`](Self::transport_emission) does, straight from the per-cell
    /// values (no density vector of its own; empty cells emit too). With `beams` (the lights'
    /// profiles, [`beam_profiles_from_pass`](Self::beam_profiles_from_pass)) the first
    /// scattering's slopes are the beams' own
    /// ([`transport_first_bounce`](Self::transport_first_bounce)). With `fluence` (one value
    /// per cell) adds to it the source's fluence at every cell, those without state too.
    pub fn transport_external(
        &self,
        scattered: &[f64],
        beams: Option<&BeamProfiles>,
        out: &mut [f64],
        mut fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        let mut energy =
            self.transport_density(scattered, out, true, beams, fluence.as_deref_mut());
        if self.emission.iter().any(|&e| e != 0.0) {
            energy.add(&self.transport_emitted(&self.emission, out, true, fluence));
        }
        energy
    }

    /// Group by group ([`groups`](Self::groups)): `fill(bins, density)` writes the group's
    /// bin-major densities, every piece of the group is swept through them, and the pieces
    /// are gathered into the state rows `out` (added to it with `add`; none without `out`);
    /// tallies power when `sweep.tally`. With `fluence` (one value per cell) adds to it the
    /// transported light's `Σ_l I_l Ω_l` at every cell, those without state too.
    fn transport_all(
        &self,
        mut out: Option<&mut [f64]>,
        s: &mut Scratch,
        sweep: Sweep<'_>,
        add: bool,
        fill: impl Fn(std::ops::Range<usize>, &mut [f64]),
        mut fluence: Option<&mut [f64]>,
    ) -> SweepEnergy {
        let m = self.bins.len();
        let stride = self.stride;
        assert!(out.as_ref().is_none_or(|o| o.len() == self.len()));
        assert!(fluence
            .as_ref()
            .is_none_or(|f| f.len() == self.grid.cell_count()));
        let omega = self.bins.solid_angles();
        let mut total = SweepEnergy::default();
        for (bins, pieces) in self.groups.iter().zip(&self.group_pieces) {
            fill(bins.clone(), &mut s.density);
            let density = &s.density;
            let energies: Vec<SweepEnergy> = s.piece_out[..pieces.len() * stride]
                .par_chunks_mut(stride)
                .zip(s.layers[..pieces.len()].par_iter_mut())
                .enumerate()
                .map(|(i, (po, buf))| {
                    self.sweep_piece(pieces.start + i, density, bins.start, po, buf, sweep)
                })
                .collect();
            for e in &energies {
                total.add(e);
            }
            let piece_out = &s.piece_out;
            // Sum of each bin's pieces, by blocks of rows so that both sides stream.
            let cells = self.state.cells();
            if let Some(out) = out.as_deref_mut() {
                out.par_chunks_mut(m * TRANSPOSE_BLOCK)
                    .enumerate()
                    .for_each(|(b, rows)| {
                        let k0 = b * TRANSPOSE_BLOCK;
                        for l in bins.clone() {
                            for (i, row) in rows.chunks_mut(m).enumerate() {
                                let c = cells[k0 + i] as usize;
                                if !add {
                                    row[l] = 0.0;
                                }
                                for &p in &self.bin_pieces[l] {
                                    row[l] += piece_out[(p - pieces.start) * stride + c];
                                }
                            }
                        }
                    });
            }
            if let Some(fluence) = fluence.as_deref_mut() {
                fluence
                    .par_chunks_mut(TRANSPOSE_BLOCK)
                    .enumerate()
                    .for_each(|(b, fl)| {
                        let c0 = b * TRANSPOSE_BLOCK;
                        for l in bins.clone() {
                            for &p in &self.bin_pieces[l] {
                                let column = &piece_out[(p - pieces.start) * stride..];
                                for (i, f) in fl.iter_mut().enumerate() {
                                    *f += omega[l] * column[c0 + i];
                                }
                            }
                        }
                    });
            }
        }
        total
    }

    /// Piece `p`, its bin's column of the bin-major group `density` (whose first column is
    /// bin `first_bin`) and its class's coefficients per level: what either sweep reads.
    #[inline]
    fn piece_inputs<'a>(
        &'a self,
        p: usize,
        density: &'a [f64],
        first_bin: usize,
    ) -> (&'a Piece, &'a [f64], &'a [CellTerms], &'a [SlopeTerms]) {
        let piece = &self.pieces[p];
        let n = self.grid.cell_count();
        let levels = self.level_tau.len();
        let (column, class) = ((piece.bin - first_bin) * self.stride, self.piece_class[p]);
        let per_class = |k: usize| k * levels..(k + 1) * levels;
        (
            piece,
            &density[column..column + n],
            &self.terms[per_class(class)],
            // Empty for a flat source.
            self.slope_terms.get(per_class(class)).unwrap_or(&[]),
        )
    }

    /// One piece's sweep through its bin's densities (the bin-major group `density` from bin
    /// `first_bin`; the source function where `sweep.linear` and the operator's source is
    /// linear): writes `weight · I_avg` per cell into `out` (length N). Tallies power only
    /// when `sweep.tally`.
    fn sweep_piece(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        if self.options.transport_refinement > 1 {
            return self.sweep_piece_refined(p, density, first_bin, out, buf, sweep);
        }
        if self.linear_faces() {
            return match AXIS_ORDERS
                .iter()
                .position(|&o| o == self.pieces[p].canonical_axes)
            {
                Some(0) => self.sweep_piece_faces::<0>(p, density, first_bin, out, buf, sweep),
                Some(1) => self.sweep_piece_faces::<1>(p, density, first_bin, out, buf, sweep),
                Some(2) => self.sweep_piece_faces::<2>(p, density, first_bin, out, buf, sweep),
                Some(3) => self.sweep_piece_faces::<3>(p, density, first_bin, out, buf, sweep),
                Some(4) => self.sweep_piece_faces::<4>(p, density, first_bin, out, buf, sweep),
                _ => self.sweep_piece_faces::<5>(p, density, first_bin, out, buf, sweep),
            };
        }
        // One compiled sweep per order of the piece's axes, so that the cell step's
        // permutations are constants.
        match AXIS_ORDERS
            .iter()
            .position(|&o| o == self.pieces[p].canonical_axes)
        {
            Some(0) => self.sweep_piece_ordered::<0>(p, density, first_bin, out, buf, sweep),
            Some(1) => self.sweep_piece_ordered::<1>(p, density, first_bin, out, buf, sweep),
            Some(2) => self.sweep_piece_ordered::<2>(p, density, first_bin, out, buf, sweep),
            Some(3) => self.sweep_piece_ordered::<3>(p, density, first_bin, out, buf, sweep),
            Some(4) => self.sweep_piece_ordered::<4>(p, density, first_bin, out, buf, sweep),
            _ => self.sweep_piece_ordered::<5>(p, density, first_bin, out, buf, sweep),
        }
    }

    /// [`sweep_piece`](Self::sweep_piece) for a piece whose canonical axes are
    /// `AXIS_ORDERS[ORDER]`.
    fn sweep_piece_ordered<const ORDER: usize>(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        let (piece, density, terms, slopes) = self.piece_inputs(p, density, first_bin);
        let slopes = if sweep.linear { slopes } else { &[] };
        let tally = sweep.tally;
        let [nx, ny, nz] = self.grid.dims;
        let h = self.grid.cell_size;
        let weight = piece.weight;
        let axes = AXIS_ORDERS[ORDER];
        let periodic = self.options.periodic_xy;
        // A one-cell-wide periodic axis feeds a cell's outflow through it back into it:
        // that self-loop is solved exactly per cell.
        let loops = [periodic && nx == 1, periodic && ny == 1, false];
        // Wrapped inflows from other cells lag one pass: iterate such layers to convergence.
        let lagged = periodic && (nx > 1 || ny > 1);
        let [fwx, fwy, fwz] = piece.forward;
        let layer = nx * ny;
        let mut energy = SweepEnergy::default();
        buf.out.fill(0.0);
        for tz in 0..nz {
            let k = at(tz, nz, fwz);
            let base = layer * k;
            let level = &self.cell_level[base..base + layer];
            let out = &mut out[base..base + layer];
            if lagged {
                // Inflows through x and y from the upstream cells (wrapped at the first).
                let inflow_of = |bx: &[f64], by: &[f64], inz: &[f64], tx: usize, ty: usize| {
                    let (i, j) = (at(tx, nx, fwx), at(ty, ny, fwy));
                    let in_x = if tx > 0 {
                        bx[at(tx - 1, nx, fwx) + nx * j]
                    } else if nx > 1 {
                        bx[at(nx - 1, nx, fwx) + nx * j]
                    } else {
                        0.0
                    };
                    let in_y = if ty > 0 {
                        by[i + nx * at(ty - 1, ny, fwy)]
                    } else if ny > 1 {
                        by[i + nx * at(ny - 1, ny, fwy)]
                    } else {
                        0.0
                    };
                    [in_x, in_y, inz[i + nx * j]]
                };
                // Cell (tx, ty) of the layer: its index in the layer, inflows, coefficients
                // and source.
                let cell = |buf: &LayerBuffers, tx: usize, ty: usize| {
                    let ijk = [at(tx, nx, fwx), at(ty, ny, fwy), k];
                    let lc = ijk[0] + nx * ijk[1];
                    let inflow = inflow_of(&buf.out_x, &buf.out_y, &buf.inz, tx, ty);
                    let ct = &terms[level[lc] as usize];
                    let slope = slopes.get(level[lc] as usize);
                    let src = self.cell_source(
                        (ct, slope),
                        density,
                        (base + lc, ijk),
                        (piece, axes),
                        sweep.beams,
                    );
                    (lc, inflow, ct, src)
                };
                buf.inz.copy_from_slice(&buf.out);
                let mut passes = 0;
                loop {
                    let (mut change, mut scale) = (0.0f64, 0.0f64);
                    for ty in 0..ny {
                        for tx in 0..nx {
                            let (lc, mut inflow, ct, src) = cell(buf, tx, ty);
                            let new = ct.outflow_looped(&mut inflow, &src, axes, loops);
                            let old = [buf.out_x[lc], buf.out_y[lc], buf.out[lc]];
                            for k in 0..3 {
                                change = change.max((new[k] - old[k]).abs());
                                scale = scale.max(new[k].abs());
                            }
                            buf.out_x[lc] = new[0];
                            buf.out_y[lc] = new[1];
                            buf.out[lc] = new[2];
                        }
                    }
                    passes += 1;
                    if change <= 1e-15 * scale || passes >= 100_000 {
                        break;
                    }
                }
                for ty in 0..ny {
                    for tx in 0..nx {
                        let (lc, mut inflow, ct, src) = cell(buf, tx, ty);
                        ct.outflow_looped(&mut inflow, &src, axes, loops);
                        let mean = ct.mean_radiance(inflow, &src, axes);
                        out[lc] = weight * mean;
                        if tally {
                            energy.tally_cell(
                                mean,
                                self.level_tau[level[lc] as usize],
                                src.density,
                                h,
                            );
                        }
                    }
                }
            } else {
                let mut cells = UniformCells {
                    op: self,
                    piece,
                    base,
                    level,
                    density,
                    coefficients: (terms, slopes),
                    axes,
                    loops,
                    beams: sweep.beams,
                };
                let faces = (&mut buf.out[..], &mut buf.out_y[..]);
                let energy = (tally, &mut energy);
                self.downwind_layer(piece, (k, level), faces, out, energy, &mut cells);
            }
        }
        energy.finish_sweep(piece, h, &buf.out, tally)
    }

    /// One layer (`k`, its cells' `level`s) of a piece's downwind pass through a grid with
    /// vacuum sides or one-cell-wide periodic ones: `step(cell in the layer, ijk, inflows by
    /// grid axis)` is the cell's step. `faces` holds the z outflows of the previous layer
    /// until a cell is updated (the z inflow is read just before it is overwritten) and the
    /// y outflows of the row before; the upwind x cell's is carried along the row. Writes
    /// `weight · I_avg` into the layer's `out` and, when tallying, the power.
    #[inline(always)]
    fn downwind_layer<F: FaceFlux>(
        &self,
        piece: &Piece,
        (k, level): (usize, &[u32]),
        (faces_z, faces_y): (&mut [F], &mut [F]),
        out: &mut [f64],
        (tally, energy): (bool, &mut SweepEnergy),
        cells: &mut impl LayerCells<F>,
    ) {
        let [nx, ny, _] = self.grid.dims;
        let [fwx, fwy, _] = piece.forward;
        let periodic = self.options.periodic_xy;
        for ty in 0..ny {
            let j = at(ty, ny, fwy);
            let row = nx * j;
            let up_row = (ty > 0).then(|| nx * at(ty - 1, ny, fwy));
            let mut up_x = F::NONE;
            for tx in 0..nx {
                let i = at(tx, nx, fwx);
                let lc = row + i;
                let in_y = up_row.map_or(F::NONE, |r| faces_y[r + i]);
                let cell = cells.step(lc, [i, j, k], [up_x, in_y, faces_z[lc]]);
                faces_z[lc] = cell.out[2];
                faces_y[lc] = cell.out[1];
                up_x = cell.out[0];
                out[lc] = piece.weight * cell.mean;
                if tally {
                    let tau0 = self.level_tau[level[lc] as usize];
                    energy.tally_cell(cell.mean, tau0, cell.density, self.grid.cell_size);
                    if !periodic && tx == nx - 1 {
                        energy.escaped[piece.side(0)] += cell.out[0].flux();
                    }
                    if !periodic && ty == ny - 1 {
                        energy.escaped[piece.side(1)] += cell.out[1].flux();
                    }
                }
            }
        }
    }

    /// [`sweep_piece_faces_body`](Self::sweep_piece_faces_body), with AVX2 where the CPU has
    /// it: the moments' 81 products per cell and piece four at a time. Multiplications and
    /// additions stay apart (no fused multiply-add), so the results are the portable build's
    /// bit for bit.
    fn sweep_piece_faces<const ORDER: usize>(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU has AVX2 (checked just above).
            return unsafe {
                self.sweep_piece_faces_avx2::<ORDER>(p, density, first_bin, out, buf, sweep)
            };
        }
        self.sweep_piece_faces_body::<ORDER>(p, density, first_bin, out, buf, sweep)
    }

    /// [`sweep_piece_faces_body`](Self::sweep_piece_faces_body) compiled for AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn sweep_piece_faces_avx2<const ORDER: usize>(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        self.sweep_piece_faces_body::<ORDER>(p, density, first_bin, out, buf, sweep)
    }

    /// [`sweep_piece`](Self::sweep_piece) with linear faces
    /// ([`OrdinatesOptions::linear_faces`]) for a piece whose canonical axes are
    /// `AXIS_ORDERS[ORDER]`: vacuum sides, or a one-cell-wide periodic column.
    #[inline(always)]
    fn sweep_piece_faces_body<const ORDER: usize>(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        let (piece, density, _, _) = self.piece_inputs(p, density, first_bin);
        let linear = sweep.linear && self.linear_source();
        let tally = sweep.tally;
        let [nx, ny, nz] = self.grid.dims;
        let h = self.grid.cell_size;
        let axes = AXIS_ORDERS[ORDER];
        let periodic = self.options.periodic_xy;
        // A one-cell-wide periodic axis feeds a cell's outflow through it back into it.
        let loops = [periodic && nx == 1, periodic && ny == 1, false];
        let mut looped = [0usize; 2];
        let mut count = 0;
        for (k, &axis) in axes.iter().enumerate() {
            if loops[axis] {
                looped[count] = k;
                count += 1;
            }
        }
        let looped = &looped[..count];
        let layer = nx * ny;
        let mut energy = SweepEnergy::default();
        buf.faces_z[..layer].fill([0.0; 3]);
        for tz in 0..nz {
            let k = at(tz, nz, piece.forward[2]);
            let base = layer * k;
            let level = &self.cell_level[base..base + layer];
            let out = &mut out[base..base + layer];
            let mut cells = FaceCells {
                op: self,
                p,
                base,
                level,
                density,
                modes: (axes, linear, looped, sweep.beams),
            };
            let faces = (&mut buf.faces_z[..], &mut buf.faces_y[..]);
            self.downwind_layer(
                piece,
                (k, level),
                faces,
                out,
                (tally, &mut energy),
                &mut cells,
            );
        }
        energy.finish_sweep(piece, h, &buf.faces_z[..layer], tally)
    }

    /// Cell `c`'s source for a piece with axes `axes`: the bin's density there (`density` is
    /// the bin's column), uniform, or with its slopes ([`OrdinatesOptions::linear_source`]).
    #[inline(always)]
    fn cell_source(
        &self,
        (ct, st): (&CellTerms, Option<&SlopeTerms>),
        density: &[f64],
        (c, ijk): (usize, [usize; 3]),
        (piece, axes): (&Piece, [usize; 3]),
        beams: Option<&BeamProfiles>,
    ) -> CellSource {
        match st {
            Some(st) => {
                let (sd, slope) = self.source_slopes(density, c, ijk, piece, beams);
                ct.linear_source(st, sd, slope, axes)
            }
            None => ct.uniform_source(density[c]),
        }
    }

    /// What scattering is scaled by per cell for the sweeps: σs, or with a linear source
    /// σs / (σt* h), which makes the source function
    /// ([`densities_to_source_function`](Self::densities_to_source_function)) in the same pass.
    fn sweep_scale(&self) -> &[f64] {
        if self.linear_source() {
            &self.source_function_scale
        } else {
            &self.sigma_s
        }
    }

    /// Turns a group's bin-major source densities (`columns` of the bins' columns, `stride`
    /// apart) into the source function `J = S / σt*` a linear source's sweep reads
    /// ([`source_slopes`](Self::source_slopes)); cells without medium keep `S`.
    fn densities_to_source_function(&self, columns: &mut [f64], bins: usize) {
        let n = self.grid.cell_count();
        // Once per call, not a division per cell and bin.
        let inverse: Vec<f64> = self
            .level_tau
            .iter()
            .map(|&t| per_optical_side(t))
            .collect();
        columns[..bins * self.stride]
            .par_chunks_mut(self.stride)
            .for_each(|column| {
                for (v, &level) in column[..n].iter_mut().zip(&self.cell_level) {
                    *v *= inverse[level as usize];
                }
            });
    }

    /// Cell `c`'s source density and its slopes per grid axis, as half the change across the
    /// cell (the value on the downstream face less the mean), signed for `piece`'s direction,
    /// from a bin's column of the source function `J = S / σt*`
    /// ([`densities_to_source_function`](Self::densities_to_source_function)): the
    /// neighbours' [`central_differences`](Self::central_differences), with `beams` the
    /// lights' first scattering's own profile in place of its differences
    /// ([`BeamProfiles`]). The source function (the in-scattered radiance times the albedo)
    /// is what varies smoothly across cells; `S` jumps with σt* from cell to cell, and slopes
    /// of `S` brightened a cloud by 2 %.
    #[inline(always)]
    fn source_slopes(
        &self,
        source_function: &[f64],
        c: usize,
        ijk: [usize; 3],
        piece: &Piece,
        beams: Option<&BeamProfiles>,
    ) -> (f64, [f64; 3]) {
        let tau_c = self.level_tau[self.cell_level[c] as usize];
        let own = source_function[c];
        // `J τ0` (no division in the sweep's innermost step); a cell without medium keeps S.
        let density = if tau_c > 0.0 { tau_c * own } else { own };
        let [sx, sy, sz] = self.central_differences(source_function, c, ijk);
        let forward = piece.forward;
        let sign = |f: bool| if f { tau_c } else { -tau_c };
        let mut slopes = [
            sign(forward[0]) * sx,
            sign(forward[1]) * sy,
            sign(forward[2]) * sz,
        ];
        if let Some(beams) = beams {
            // (Zero in cells without medium.)
            let unit = forward.map(|f| if f { 1.0 } else { -1.0 });
            beams.add_to(c, piece.bin, unit, &mut slopes);
        }
        (density, slopes)
    }

    /// Half the change across cell `c` along each grid axis (upper less lower) of a column
    /// of the source function, from central differences between the neighbours, one-sided
    /// where one is outside the grid or much thinner ([`source_neighbour_mask`]), none for an
    /// empty cell. Periodic sides wrap; a one-cell-wide axis has no slope.
    #[inline(always)]
    fn central_differences(&self, source_function: &[f64], c: usize, ijk: [usize; 3]) -> [f64; 3] {
        let has = self.source_neighbours[c];
        let [nx, ny, nz] = self.grid.dims;
        let own = source_function[c];
        // Weights of (lower, own, upper) by which neighbours are there (bits 2a, 2a + 1):
        // no branches, and the three axes written out so that their loads overlap.
        const WEIGHTS: [[f64; 3]; 4] = [
            [0.0, 0.0, 0.0],
            [-0.5, 0.5, 0.0],
            [0.0, -0.5, 0.5],
            [-0.25, 0.0, 0.25],
        ];
        // Wrapped at the grid's sides: always a cell of the grid, weighted 0 where it is not
        // a neighbour.
        let dims = [nx, ny, nz];
        let [xl, xh] = neighbour_cells(dims, c, ijk, 0);
        let [yl, yh] = neighbour_cells(dims, c, ijk, 1);
        let [zl, zh] = neighbour_cells(dims, c, ijk, 2);
        let [ax, ay, az] = [0, 1, 2].map(|a| WEIGHTS[((has >> (2 * a)) & 3) as usize]);
        [
            ax[0] * source_function[xl] + ax[1] * own + ax[2] * source_function[xh],
            ay[0] * source_function[yl] + ay[1] * own + ay[2] * source_function[yh],
            az[0] * source_function[zl] + az[1] * own + az[2] * source_function[zh],
        ]
    }

    /// [`sweep_piece`](Self::sweep_piece) through `r³` sub-cells per cell
    /// ([`OrdinatesOptions::transport_refinement`]; vacuum sides): each cell's output is
    /// the mean over its sub-cells. Kept apart so the plain sweep has no index divisions.
    fn sweep_piece_refined(
        &self,
        p: usize,
        density: &[f64],
        first_bin: usize,
        out: &mut [f64],
        buf: &mut LayerBuffers,
        sweep: Sweep<'_>,
    ) -> SweepEnergy {
        let (piece, density, terms, slopes) = self.piece_inputs(p, density, first_bin);
        let slopes = if sweep.linear { slopes } else { &[] };
        let (tally, beams) = (sweep.tally, sweep.beams);
        let r = self.options.transport_refinement;
        let [nx, ny, nz] = self.grid.dims;
        let [fnx, fny, fnz] = [nx * r, ny * r, nz * r];
        let n = self.grid.cell_count();
        let h = self.grid.cell_size / r as f64;
        let axes = piece.canonical_axes;
        let share = piece.weight / (r * r * r) as f64;
        let [fwx, fwy, fwz] = piece.forward;
        let mut energy = SweepEnergy::default();
        buf.out[..fnx * fny].fill(0.0);
        out[..n].fill(0.0);
        for tz in 0..fnz {
            let fk = at(tz, fnz, fwz);
            let cz = fk / r;
            for ty in 0..fny {
                let fj = at(ty, fny, fwy);
                let row = fnx * fj;
                let coarse_row = nx * (fj / r + ny * cz);
                let up_row = (ty > 0).then(|| fnx * at(ty - 1, fny, fwy));
                let mut up_x = 0.0;
                for tx in 0..fnx {
                    let fi = at(tx, fnx, fwx);
                    let lc = row + fi;
                    let c = coarse_row + fi / r;
                    let in_y = up_row.map_or(0.0, |u| buf.out_y[u + fi]);
                    let inflow = [up_x, in_y, buf.out[lc]];
                    let ct = &terms[self.cell_level[c] as usize];
                    let src = if !slopes.is_empty() {
                        // The coarse cell's linear source on this sub-cell: its value at the
                        // sub-cell's centre, and the slopes over the sub-cell's width.
                        let (mean, slope) =
                            self.source_slopes(density, c, [fi / r, fj / r, cz], piece, beams);
                        let sub = [fi % r, fj % r, fk % r];
                        let sign = piece.forward.map(|f| if f { 1.0 } else { -1.0 });
                        let sd = mean
                            + (0..3)
                                .map(|a| {
                                    let centre = (2 * sub[a] + 1) as f64 / r as f64 - 1.0;
                                    slope[a] * sign[a] * centre
                                })
                                .sum::<f64>();
                        let st = &slopes[self.cell_level[c] as usize];
                        ct.linear_source(st, sd, slope.map(|v| v / r as f64), axes)
                    } else {
                        ct.uniform_source(density[c])
                    };
                    let o = ct.outflow(inflow, &src, axes);
                    buf.out[lc] = o[2];
                    buf.out_y[lc] = o[1];
                    up_x = o[0];
                    let mean = ct.mean_radiance(inflow, &src, axes);
                    out[c] += share * mean;
                    if tally {
                        energy.tally_cell(
                            mean,
                            self.level_tau[self.cell_level[c] as usize],
                            src.density,
                            h,
                        );
                        if tx == fnx - 1 {
                            energy.escaped[piece.side(0)] += o[0];
                        }
                        if ty == fny - 1 {
                            energy.escaped[piece.side(1)] += o[1];
                        }
                    }
                }
            }
        }
        energy.finish_sweep(piece, h, &buf.out[..fnx * fny], tally)
    }

    /// Energy balance of a solution `I` of `I = T(external) + T_e(emission) + K I` (the
    /// source [`transport_external`](Self::transport_external) makes): transports
    /// `external + scatter(I)` and the channel's emission once and tallies the escape;
    /// absorption from `I` itself. `beams`: the profiles `external` was transported with
    /// ([`transport_first_bounce`](Self::transport_first_bounce)), so that the escape is the
    /// solve's own.
    pub fn energy_balance(
        &self,
        solution: &[f64],
        external: &[f64],
        beams: Option<&BeamProfiles>,
    ) -> EnergyBalance {
        let m = self.bins.len();
        let mut density = vec![0.0; self.len()];
        self.scatter_density(solution, &mut density);
        for (d, e) in density.iter_mut().zip(external) {
            *d += e;
        }
        let mut out = vec![0.0; self.len()];
        let sweep = self.transport_external(&density, beams, &mut out, None);
        let v = self.grid.cell_volume();
        let omega = self.bins.solid_angles();
        let four_pi: f64 = omega.iter().sum();
        let source: f64 = external
            .chunks(m)
            .map(|d| d.iter().zip(omega).map(|(a, b)| a * b).sum::<f64>() * v)
            .sum::<f64>()
            + self.emission.iter().sum::<f64>() * four_pi * v;
        let absorbed: f64 = solution
            .chunks(m)
            .zip(self.state.cells())
            .map(|(x, &c)| {
                let c = c as usize;
                (self.sigma_t[c] - self.sigma_s[c])
                    * v
                    * x.iter().zip(omega).map(|(a, b)| a * b).sum::<f64>()
            })
            .sum();
        EnergyBalance {
            source,
            absorbed,
            escaped: sweep.escaped,
        }
    }

    /// The final gather's higher-order source towards each bin centre, from a solution `x`:
    /// `out[k·M + l] = σs Σ_j p̄_j(ω_l) x_j Ω_j` (the state's rows), with `p̄_j(ω)` the true phase function
    /// averaged over the incoming bin `j` for the exact outgoing direction `ω_l` (one final
    /// directional bounce, Max §VII.D, as physics.md asks). Not
    /// [`scatter_density`](Self::scatter_density), whose phase matrix also averages over the
    /// outgoing bin and is tilted to keep the solve's asymmetry. (On the g = 0.7 DISORT slab
    /// the two give reflected radiances within 1 % of each other, worst 2.7 % vs 2.5 % at
    /// 384 bins; what mattered there was the interpolation near face edges.) Between bin
    /// centres a renderer interpolates ([`face_bilinear`](super::bins::face_bilinear)).
    pub fn gather_density(&self, x: &[f64], out: &mut [f64]) {
        let m = self.bins.len();
        assert!(
            x.len() == self.len() && out.len() == self.len(),
            "gather_density: vectors must have state cells × bins entries"
        );
        let omega = self.bins.solid_angles();
        // The phase matrix's incoming-bin nodes: as fine as the solve itself resolved.
        let k = 1 + self
            .options
            .phase_quadrature
            .unwrap_or_else(|| default_quadrature(&self.bins));
        // weights[l·M + j] = p̄_j(ω_l) Ω_j (p̄ is symmetric in its two directions).
        let weights: Vec<f64> = self
            .bins
            .centres()
            .par_iter()
            .flat_map_iter(|&centre| {
                bin_averaged_phase(&self.bins, &self.phase, centre, k)
                    .into_iter()
                    .zip(omega)
                    .map(|(p, w)| p * w)
            })
            .collect();
        // The same block product as the solve's scattering, with these weights.
        self.scatter_into(&weights, x, out, Layout::Rows, 0..m);
    }

    /// The uncollided radiance, cell- and bin-averaged, of light entering the grid from
    /// outside with radiance `along[l]` in each bin `l` (an environment: at the bin centre,
    /// or its mean over the bin), in the sweep's own discretisation: the source `σt* L_l`
    /// with that inflow keeps `L_l` everywhere, so `ψ = L_l − T(σt* L_l)`. A non-absorbing
    /// medium in a uniform inflow then holds it everywhere (the white furnace) to the
    /// solver's tolerance.
    pub fn inflow_radiance(&self, along: &[f64]) -> Result<Uncollided, OrdinatesError> {
        let m = self.bins.len();
        if along.len() != m {
            return Err(OrdinatesError::Length {
                what: "inflow radiances",
                got: along.len(),
                expected: m,
            });
        }
        Ok(self.inflow_field(|_, l| along[l]))
    }

    /// The uncollided radiance of light that enters through the boundary with radiance
    /// `field(c, l)` along bin `l` on the line through cell `c`'s centre (any cell): a field
    /// that is constant along each bin's lines (what enters stays what it is, as a uniform
    /// environment's light, or a ground's seen back along the line). Along a line the
    /// uncollided radiance is `f − u`, where `u` is the light the line's cells extinguish,
    /// `u' = −σ u + σ f` from zero at the boundary: one transport sweep of the density `σ f`,
    /// so a non-absorbing medium stays at `f` in the sweep's own discretisation.
    pub fn inflow_field(&self, field: impl Fn(usize, usize) -> f64 + Sync) -> Uncollided {
        let m = self.bins.len();
        let n = self.grid.cell_count();
        // The field at the state's rows, read once; σt* f is the density.
        let mut psi = vec![0.0; self.len()];
        self.for_each_row(&mut psi, |c, f| {
            for (l, fl) in f.iter_mut().enumerate() {
                *fl = field(c, l);
            }
        });
        let mut density = psi.clone();
        self.for_each_row(&mut density, |c, d| {
            let sweep_sigma = (self.sigma_t[c] - self.truncation * self.sigma_s[c]).max(0.0);
            d.iter_mut().for_each(|v| *v *= sweep_sigma);
        });
        let mut extinguished = vec![0.0; self.len()];
        let mut fluence = vec![0.0; n];
        self.transport_density(&density, &mut extinguished, true, None, Some(&mut fluence));
        drop(density);
        for (p, u) in psi.iter_mut().zip(&extinguished) {
            *p = (*p - u).max(0.0);
        }
        drop(extinguished);
        // Empty cells: what entered less what the medium upstream took; the rest, ψ's own.
        let omega = self.bins.solid_angles();
        fluence.par_iter_mut().enumerate().for_each(|(c, fl)| {
            if self.state.row(c).is_none() {
                *fl = ((0..m).map(|l| field(c, l) * omega[l]).sum::<f64>() - *fl).max(0.0);
            }
        });
        self.rows_fluence_into(&psi, &mut fluence);
        Uncollided {
            radiance: psi,
            fluence,
        }
    }

    /// Angular integral `Σ_l I_l Ω_l` of the state rows `solution`, per cell (the zonal
    /// `4π ×` mean radiance); 0 at cells without state (see
    /// [`fluence_everywhere`](Self::fluence_everywhere)).
    pub fn fluence(&self, solution: &[f64]) -> Vec<f64> {
        let mut fluence = vec![0.0; self.grid.cell_count()];
        self.rows_fluence_into(solution, &mut fluence);
        fluence
    }

    /// Writes the state rows' `Σ_l x_l Ω_l` into their cells of `fluence` (the others are
    /// left as they are).
    fn rows_fluence_into(&self, rows: &[f64], fluence: &mut [f64]) {
        let omega = self.bins.solid_angles();
        for (x, &c) in rows.chunks(self.bins.len()).zip(self.state.cells()) {
            fluence[c as usize] = x.iter().zip(omega).map(|(a, b)| a * b).sum();
        }
    }

    /// Every cell's fluence of a solution `total` (the state's rows) of `I = F + K I`, where
    /// `fixed` is the fluence of `F` at every cell (what
    /// [`transport_external`](Self::transport_external) and [`inflow_field`](Self::inflow_field)
    /// tally: the source and any uncollided inflow): the state cells' own `Σ_l I_l Ω_l`, and
    /// elsewhere `fixed` plus the fluence of `K total`, which costs one sweep (none when
    /// every cell carries state).
    pub fn fluence_everywhere(&self, total: &[f64], fixed: &[f64]) -> Vec<f64> {
        assert!(total.len() == self.len() && fixed.len() == self.grid.cell_count());
        let mut fluence = fixed.to_vec();
        if !self.state.is_every_cell() {
            self.scatter_and_transport(total, None, Some(&mut fluence));
        }
        self.rows_fluence_into(total, &mut fluence);
        fluence
    }

    /// `K x` into the state rows `y` and its fluence added to `fluence` at every cell,
    /// either or both.
    fn scatter_and_transport(&self, x: &[f64], y: Option<&mut [f64]>, fluence: Option<&mut [f64]>) {
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let sweep = Sweep {
            tally: false,
            linear: true,
            beams: None,
        };
        self.transport_all(
            y,
            &mut guard,
            sweep,
            false,
            |bins, dst| self.scatter_into(&self.scatter, x, dst, Layout::BinMajor, bins),
            fluence,
        );
    }
}

/// The uncollided light of an inflow through the boundary
/// ([`OrdinatesOperator::inflow_field`]).
pub struct Uncollided {
    /// `ψ[k·M + l]`, the state's rows.
    pub radiance: Vec<f64>,
    /// `Σ_l ψ_l Ω_l` at every cell, those without state too.
    pub fluence: Vec<f64>,
}

impl TransportOperator for OrdinatesOperator {
    fn len(&self) -> usize {
        self.state.len() * self.bins.len()
    }

    /// `y = K x`: scatter `x` once with the phase matrix, transport the result.
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.scatter_and_transport(x, Some(y), None);
    }

    /// Block Gauss–Seidel over bins: groups of `gauss_seidel_group` bins in index order; each
    /// group's scattering source uses the bins already updated in this sweep.
    ///
    /// Works on `g` and `source` where they are (cell-major: a group's bins of a cell are one
    /// or two cache lines), with no copies of either: the update of one group and the
    /// scattering density of the next are one pass over the cells (the density of a cell
    /// needs only that cell's radiances).
    fn sweep_in_place(&self, g: &mut [f64], source: &[f64], omega: f64) -> bool {
        let n = self.grid.cell_count();
        let m = self.bins.len();
        assert!(
            g.len() == self.len() && source.len() == self.len(),
            "sweep_in_place: vectors must have state cells × bins entries"
        );
        let stride = self.stride;
        let mut guard = self.scratch.lock().unwrap_or_else(|e| e.into_inner());
        let s = &mut *guard;
        let g_cells = SharedMut(g.as_mut_ptr());
        let density = SharedMut(s.density.as_mut_ptr());
        let blocks = n.div_ceil(SCATTER_BLOCK);
        let scatter_block = |bins: std::ops::Range<usize>, block: usize| {
            // SAFETY: `g` has the state's rows (asserted), the density buffer a group's
            // columns of `stride` (≥ n) elements; each block's cells belong to one task.
            unsafe {
                self.scatter_block(
                    (&self.scatter, self.sweep_scale()),
                    g_cells.ptr(),
                    (density, Layout::BinMajor, bins.start),
                    bins,
                    block,
                )
            }
        };
        // Scattering density for the first group's bins from the current g.
        (0..blocks)
            .into_par_iter()
            .for_each(|b| scatter_block(self.groups[0].clone(), b));
        for (k, (bins, pieces)) in self.groups.iter().zip(&self.group_pieces).enumerate() {
            let density_ref = &s.density;
            s.piece_out[..pieces.len() * stride]
                .par_chunks_mut(stride)
                .zip(s.layers[..pieces.len()].par_iter_mut())
                .enumerate()
                .for_each(|(i, (po, buf))| {
                    let sweep = Sweep {
                        tally: false,
                        linear: true,
                        beams: None,
                    };
                    self.sweep_piece(pieces.start + i, density_ref, bins.start, po, buf, sweep);
                });
            let piece_out = &s.piece_out;
            let next = self.groups.get(k + 1).cloned();
            (0..blocks).into_par_iter().for_each(|b| {
                let rows = self.state.rows_of_block(b);
                for (row, &c) in rows.clone().zip(&self.state.cells()[rows]) {
                    for l in bins.clone() {
                        let kg: f64 = self.bin_pieces[l]
                            .iter()
                            .map(|&p| piece_out[(p - pieces.start) * stride + c as usize])
                            .sum();
                        let i = row * m + l;
                        // SAFETY: inside g (the state's rows, asserted); these rows are
                        // this task's.
                        unsafe {
                            let gl = g_cells.ptr().add(i);
                            *gl = (1.0 - omega) * *gl + omega * (source[i] + kg);
                        }
                    }
                }
                if let Some(next) = next.clone() {
                    // The next group's densities of these cells: this task's alone, and
                    // nobody reads them now (this group's sweeps are done).
                    scatter_block(next, b);
                }
            });
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pieces that are images of one another under the cube's symmetries share their cell
    /// coefficients, in both sweeps: for `6 n²` bins with `n` even, one class per square of a
    /// face's quarter up to its diagonal, `(n/2)(n/2 + 1)/2` (3 for Max's 96 bins). Breaking a
    /// chord's tie on a cube edge by rounding once gave mirror images different shares, and 12
    /// to 29 classes, each with its own coefficients per cell.
    #[test]
    fn images_of_a_piece_share_one_class() {
        for n in [4, 8] {
            let bins = DirectionBins::cube(n).unwrap();
            let pieces = pieces_of(&bins, false, true);
            let expected = (n / 2) * (n / 2 + 1) / 2;
            for face_coupling in [true, false] {
                let (_, reps) = piece_classes(&pieces, face_coupling);
                assert_eq!(
                    reps.len(),
                    expected,
                    "n = {n}, face coupling {face_coupling}"
                );
            }
        }
    }
}
