//! What `[solve]` says: the multiple-scattering method and the settings of its solve. The
//! linear iteration is the solver's own [`solver::Method`], spelled as its [`FromStr`] reads
//! it, so scenes, the command line and the albedo bench accept the same names.

use std::fmt;
use std::str::FromStr;

use medium::PhaseFunction;

/// A phase function as a scene file writes it (`medium.phase`), for messages and `volrad info`.
pub fn phase_spelling(phase: &PhaseFunction) -> String {
    match *phase {
        PhaseFunction::Isotropic => "isotropic".into(),
        PhaseFunction::HenyeyGreenstein { g } => {
            format!("{{ kind = \"henyey-greenstein\", g = {g} }}")
        }
        PhaseFunction::LambertianSphere => "lambertian-sphere".into(),
        PhaseFunction::TwoLobe { r, g1, g2 } => {
            format!("{{ kind = \"two-lobe\", r = {r}, g1 = {g1}, g2 = {g2} }}")
        }
    }
}
use serde::{Deserialize, Serialize};

/// The multiple-scattering method of `[solve] method`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SolveMethod {
    DiscreteOrdinates,
    Zonal,
    ZonalHierarchical,
    SingleScatter,
    /// Blasi & Wuethrich's Monte Carlo two-pass method (photons from the lights deposited in
    /// the grid with their directions; the render adds the exact first bounce).
    TwoPass,
    None,
}

impl SolveMethod {
    /// Every method, in the order messages list them.
    pub const ALL: [SolveMethod; 6] = [
        SolveMethod::DiscreteOrdinates,
        SolveMethod::Zonal,
        SolveMethod::ZonalHierarchical,
        SolveMethod::SingleScatter,
        SolveMethod::TwoPass,
        SolveMethod::None,
    ];

    /// The scene file's spelling.
    pub fn name(self) -> &'static str {
        match self {
            SolveMethod::DiscreteOrdinates => "discrete-ordinates",
            SolveMethod::Zonal => "zonal",
            SolveMethod::ZonalHierarchical => "zonal-hierarchical",
            SolveMethod::SingleScatter => "single-scatter",
            SolveMethod::TwoPass => "two-pass",
            SolveMethod::None => "none",
        }
    }

    /// The contract's "method that suits the medium": the hierarchical zonal method for an
    /// isotropic phase function, discrete ordinates otherwise.
    pub fn default_for(phase: &PhaseFunction) -> SolveMethod {
        if phase.is_isotropic() {
            SolveMethod::ZonalHierarchical
        } else {
            SolveMethod::DiscreteOrdinates
        }
    }

    /// Whether the method solves the grid's linear system — the zonal methods and discrete
    /// ordinates: the methods that iterate, solve on a transport grid, and take the emitters'
    /// uncollided light (the emitter pass) as their first-collision source. The others build
    /// no system (`none`, `single-scatter`) or trace photons (`two-pass`).
    pub fn solves_linear_system(self) -> bool {
        matches!(
            self,
            SolveMethod::Zonal | SolveMethod::ZonalHierarchical | SolveMethod::DiscreteOrdinates
        )
    }

    /// The fastest robust iteration for a method (`volrad bench albedo`, docs/albedo.md):
    /// diffusion-synthetic CG for the hierarchical zonal system (6 iterations where Jacobi
    /// needs 69 and CG 14 on the sample cloud at albedo 0.999, and the fastest from albedo
    /// 0.5 to 1), conjugate gradients for the exact zonal system (symmetrisable by
    /// reciprocity, but without the diffusion approximation DSA needs), Gauss–Seidel for
    /// discrete ordinates (not symmetric, and Krylov vectors of cells × bins would cost
    /// gigabytes).
    pub fn default_iteration(self) -> solver::Method {
        match self {
            SolveMethod::ZonalHierarchical => solver::Method::DsaCg,
            SolveMethod::Zonal => solver::Method::ConjugateGradient,
            _ => solver::Method::GaussSeidel,
        }
    }
}

impl fmt::Display for SolveMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// A `[solve] method` (or `--method`) that names no method.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("unknown method `{0}` (expected one of: {names})", names = solve_method_names())]
pub struct UnknownSolveMethod(pub String);

/// The methods' spellings, comma-separated, for messages and help.
fn solve_method_names() -> String {
    SolveMethod::ALL.map(SolveMethod::name).join(", ")
}

impl FromStr for SolveMethod {
    type Err = UnknownSolveMethod;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        SolveMethod::ALL
            .into_iter()
            .find(|m| m.name() == name)
            .ok_or_else(|| UnknownSolveMethod(name.to_string()))
    }
}

/// A scene's `[solve]` section.
#[derive(Clone, Debug, PartialEq)]
pub struct SolveSettings {
    pub method: SolveMethod,
    /// Direction bins (discrete ordinates only): chosen from the medium, or one of
    /// [`VALID_BINS`](formfactor::ordinates::VALID_BINS) (96 is Max's set).
    pub bins: BinCount,
    /// The linear iteration; [`SolveMethod::default_iteration`] unless the scene names one.
    pub iteration: solver::Method,
    /// Relative residual `‖g − E − aFg‖ / ‖E‖` at which to stop.
    pub tolerance: f64,
    pub max_iterations: usize,
    /// Zonal and discrete-ordinates methods: the multiple scattering is solved on each data
    /// cell split into `r × r × r` transport cells (`r` in
    /// 1..=[`MAX_TRANSPORT_SPLIT`](medium::coarsening::MAX_TRANSPORT_SPLIT)), so a source
    /// uniform over an optically thick cell does not carry light too deep; the unknowns grow
    /// `r³` times. Not with a `transport_scale` above 1.
    pub transport_refinement: TransportRefinement,
    /// Discrete ordinates only: half-angle in degrees of the forward-peak cone truncated
    /// by δ-M ([`OrdinatesOptions::forward_truncation_degrees`](formfactor::ordinates::OrdinatesOptions));
    /// `None`: the default, one bin's cone for Henyey–Greenstein with `g > 0`
    /// ([`default_forward_truncation_degrees`](formfactor::ordinates::default_forward_truncation_degrees));
    /// `Some(0.0)`: none.
    pub forward_peak_cone: Option<f64>,
    /// Two-pass only: photons per light of the energetization pass (its noise falls like
    /// `1/√photons`; bounds [`PHOTON_RANGE`](montecarlo::two_pass::PHOTON_RANGE)).
    pub photons: u64,
    /// Zonal and discrete-ordinates methods: the multiple scattering is solved on blocks of
    /// `s³` data cells ([`medium::coarsening::Coarsening`]); the first bounce stays exact at
    /// the data's resolution.
    pub transport_scale: TransportScale,
}

/// `[solve] bins`: how many direction bins discrete ordinates sweep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum BinCount {
    /// Chosen from the medium: by the phase function's forward peak, as many as a cap on
    /// the sweeps' work (about transport cells × bins) allows
    /// ([`formfactor::ordinates::auto_bin_count`]).
    #[default]
    Auto,
    /// One of [`VALID_BINS`](formfactor::ordinates::VALID_BINS).
    Fixed(usize),
}

impl BinCount {
    /// The bins a solve of a medium with `phase`, swept on `transport_cells` cells, uses.
    pub fn count(self, phase: &PhaseFunction, transport_cells: usize) -> usize {
        match self {
            BinCount::Fixed(n) => n,
            BinCount::Auto => {
                formfactor::ordinates::auto_bin_count(phase.mean_cosine(), transport_cells)
            }
        }
    }
}

impl std::fmt::Display for BinCount {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BinCount::Auto => f.write_str("auto"),
            BinCount::Fixed(n) => write!(f, "{n}"),
        }
    }
}

/// `[solve] transport_refinement`: how many transport cells per side one data cell is split
/// into.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TransportRefinement {
    /// Chosen by the solve from the cells' optical depth, within the size class of transport
    /// grid that `transport_scale = "auto"` keeps.
    #[default]
    Auto,
    /// `r` per side, 1..=[`MAX_TRANSPORT_SPLIT`](medium::coarsening::MAX_TRANSPORT_SPLIT).
    Fixed(usize),
}

impl std::fmt::Display for TransportRefinement {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TransportRefinement::Auto => f.write_str("auto"),
            TransportRefinement::Fixed(r) => write!(f, "{r}"),
        }
    }
}

/// `[solve] transport_scale`: how many data cells per side one transport cell spans.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum TransportScale {
    /// Chosen by the solve: 1 (the data grid itself) up to a size class of transport grid,
    /// coarser beyond it or where memory is short.
    #[default]
    Auto,
    /// `s` data cells per side, 1..=[`MAX_TRANSPORT_SCALE`](medium::coarsening::MAX_TRANSPORT_SCALE).
    Fixed(usize),
}

impl std::str::FromStr for TransportScale {
    type Err = String;

    /// `auto` or a whole number 1..=[`MAX_TRANSPORT_SCALE`](medium::coarsening::MAX_TRANSPORT_SCALE).
    fn from_str(text: &str) -> Result<Self, String> {
        let max = medium::coarsening::MAX_TRANSPORT_SCALE;
        if text == "auto" {
            return Ok(TransportScale::Auto);
        }
        match text.parse::<usize>() {
            Ok(s) if (1..=max).contains(&s) => Ok(TransportScale::Fixed(s)),
            _ => Err(format!(
                "`{text}`: expected auto or a whole number from 1 to {max} (data cells per side \
                 of a transport cell)"
            )),
        }
    }
}

impl std::fmt::Display for TransportScale {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            TransportScale::Auto => f.write_str("auto"),
            TransportScale::Fixed(s) => write!(f, "{s}"),
        }
    }
}

impl SolveSettings {
    /// Why these settings ask for a transport grid both coarser and finer than the data
    /// (a fixed `transport_scale` and a fixed `transport_refinement` above 1), if they do.
    pub fn transport_conflict(&self) -> Option<String> {
        match (self.transport_scale, self.transport_refinement) {
            (TransportScale::Fixed(scale @ 2..), TransportRefinement::Fixed(refinement @ 2..)) => {
                Some(format!(
                    "{refinement} with transport_scale = {scale}: a transport grid is either \
                     coarser than the data (transport_scale) or finer (transport_refinement), \
                     not both"
                ))
            }
            _ => None,
        }
    }

    /// `[solve]` absent: the method for `phase`, its default iteration, tolerance 1e-5, 2000
    /// iterations, bins chosen from the medium, no refinement, the two-pass method's default photon count.
    pub fn default_for(phase: &PhaseFunction) -> SolveSettings {
        let method = SolveMethod::default_for(phase);
        SolveSettings {
            method,
            bins: BinCount::Auto,
            iteration: method.default_iteration(),
            tolerance: 1e-5,
            max_iterations: 2000,
            transport_refinement: TransportRefinement::Auto,
            forward_peak_cone: None,
            photons: montecarlo::two_pass::DEFAULT_PHOTONS,
            transport_scale: TransportScale::Auto,
        }
    }
}
