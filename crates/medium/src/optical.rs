//! Per-cell optical properties: σt, albedo and emission, per colour channel.

use serde::{Deserialize, Serialize};

use crate::{Grid, MediumError, PhaseFunction};

/// A per-cell quantity that is often constant: stored once when it is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub enum CellValues {
    Uniform(f32),
    PerCell(Vec<f32>),
}

impl CellValues {
    #[inline]
    pub fn get(&self, cell: usize) -> f32 {
        match self {
            CellValues::Uniform(v) => *v,
            CellValues::PerCell(v) => v[cell],
        }
    }

    pub fn max(&self) -> f32 {
        match self {
            CellValues::Uniform(v) => *v,
            CellValues::PerCell(v) => v.iter().copied().fold(0.0, f32::max),
        }
    }

    pub fn is_zero(&self) -> bool {
        match self {
            CellValues::Uniform(v) => *v == 0.0,
            CellValues::PerCell(v) => v.iter().all(|&x| x == 0.0),
        }
    }

    /// Checks length against the grid and that every value lies in `[lo, hi]` and is finite.
    fn check(&self, what: &'static str, cells: usize, lo: f32, hi: f32) -> Result<(), MediumError> {
        match self {
            CellValues::Uniform(v) if !in_range(*v, lo, hi) => Err(MediumError::invalid(
                what,
                format!("{v} is outside [{lo}, {hi}]"),
            )),
            CellValues::PerCell(v) => check_cells(v, what, cells, lo, hi),
            _ => Ok(()),
        }
    }
}

fn in_range(v: f32, lo: f32, hi: f32) -> bool {
    v.is_finite() && v >= lo && v <= hi
}

/// [`CellValues::check`] of per-cell values where they are (a copy of a large grid's σt
/// would cost its size in fresh memory).
fn check_cells(
    values: &[f32],
    what: &'static str,
    cells: usize,
    lo: f32,
    hi: f32,
) -> Result<(), MediumError> {
    if values.len() != cells {
        return Err(MediumError::invalid(
            what,
            format!("{} values for {cells} cells", values.len()),
        ));
    }
    match values.iter().position(|&x| !in_range(x, lo, hi)) {
        Some(i) => Err(MediumError::invalid(
            what,
            format!("cell {i} has {} outside [{lo}, {hi}]", values[i]),
        )),
        None => Ok(()),
    }
}

/// The optical properties of one colour channel. Transport in volrad is per channel: a grey
/// scene has one, an RGB scene three, each solved and rendered independently.
///
/// # Invariants
/// `sigma_t.len()` equals the grid's cell count; `σt ≥ 0`, `albedo ∈ [0, 1]`, `emission ≥ 0`,
/// all finite. Checked by [`Medium::new`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ChannelMedium {
    /// Extinction coefficient per cell (1/length).
    pub sigma_t: Vec<f32>,
    /// Single-scattering albedo per cell.
    pub albedo: CellValues,
    /// Emitted radiance per unit length per cell (Max's "glow" source).
    pub emission: CellValues,
}

impl ChannelMedium {
    #[inline]
    pub fn sigma_s(&self, cell: usize) -> f32 {
        self.sigma_t[cell] * self.albedo.get(cell)
    }

    pub fn max_sigma_t(&self) -> f32 {
        self.sigma_t.iter().copied().fold(0.0, f32::max)
    }
}

/// How renders reconstruct the medium between cell centres. Solvers (and the path tracer)
/// always use the piecewise-constant (`Nearest`) medium; `Trilinear`, the default, draws σt,
/// emission and the solved sources smoothly between cell centres, so a render shows no cell
/// edges where the data is smooth.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Interpolation {
    /// Piecewise constant per cell: the medium the solvers discretise, integrated exactly.
    Nearest,
    /// Cell-centred trilinear reconstruction (render look only).
    #[default]
    Trilinear,
}

/// A grid with its optical properties and phase function.
///
/// # Invariants
/// One or three channels; every channel's arrays match the grid's cell count with
/// `σt ≥ 0`, `albedo ∈ [0, 1]`, `emission ≥ 0`, all finite; the phase function is valid; the
/// data values, if kept, match the cell count. [`Medium::new`] checks them, the fields are
/// private and the `with_*` methods rebuild through it, so a `Medium` that exists is valid
/// and code that receives one need not check it again. (A [`ChannelMedium`] on its own has no
/// such guarantee; inside a `Medium` it is only handed out by shared reference.)
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Medium {
    grid: Grid,
    /// One entry for grey scenes, three (R, G, B) for colour.
    channels: Vec<ChannelMedium>,
    phase: PhaseFunction,
    interpolation: Interpolation,
    /// The raw data values the optical properties were mapped from, kept for gradient
    /// shading (Max eq. 11). `None` when the medium was given directly.
    data: Option<Vec<f32>>,
}

impl Medium {
    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// One entry for grey scenes, three (R, G, B) for colour.
    pub fn channels(&self) -> &[ChannelMedium] {
        &self.channels
    }

    pub fn phase(&self) -> PhaseFunction {
        self.phase
    }

    pub fn interpolation(&self) -> Interpolation {
        self.interpolation
    }

    /// The raw data values the optical properties were mapped from (for gradient shading,
    /// Max eq. 11); `None` when the medium was given directly.
    pub fn data(&self) -> Option<&[f32]> {
        self.data.as_deref()
    }

    /// The parts, for building a changed medium through [`Medium::new`].
    pub fn into_parts(
        self,
    ) -> (
        Grid,
        Vec<ChannelMedium>,
        PhaseFunction,
        Interpolation,
        Option<Vec<f32>>,
    ) {
        (
            self.grid,
            self.channels,
            self.phase,
            self.interpolation,
            self.data,
        )
    }

    /// The same medium reconstructed between cell centres by `interpolation`.
    pub fn with_interpolation(mut self, interpolation: Interpolation) -> Medium {
        self.interpolation = interpolation;
        self
    }

    /// The same medium in three colour channels: a grey medium's one channel repeated (for
    /// coloured light, such as a sky); a coloured medium unchanged.
    pub fn in_colour(self) -> Medium {
        if self.channels.len() == 3 {
            return self;
        }
        let mut medium = self;
        let grey = medium.channels[0].clone();
        medium.channels = vec![grey.clone(), grey.clone(), grey];
        medium
    }

    /// The same medium with channel `c` replaced, checked as [`Medium::new`] checks.
    pub fn with_channel(self, c: usize, channel: ChannelMedium) -> Result<Medium, MediumError> {
        let (grid, mut channels, phase, interpolation, data) = self.into_parts();
        let count = channels.len();
        let slot = channels.get_mut(c).ok_or_else(|| {
            MediumError::invalid(
                "channel",
                format!("channel {c} of a {count}-channel medium"),
            )
        })?;
        *slot = channel;
        Medium::new(grid, channels, phase, interpolation, data)
    }

    /// The largest optical depth `Σ σt h` along any row of cells parallel to an axis, over all
    /// channels: how opaque the medium is "across the grid".
    pub fn max_axis_optical_depth(&self) -> f64 {
        self.axis_optical_depths().into_iter().fold(0.0, f64::max)
    }

    /// The largest optical depth `Σ σt h` along a row of cells parallel to x, to y and to z,
    /// over all channels: the medium's optical size along each axis (a wide slab is thick
    /// across x and y and thin across z).
    pub fn axis_optical_depths(&self) -> [f64; 3] {
        let [nx, ny, nz] = self.grid.dims;
        let h = self.grid.cell_size;
        let mut best = [0.0f64; 3];
        for ch in &self.channels {
            let s = &ch.sigma_t;
            let mut along_x = vec![0.0f64; ny * nz];
            let mut along_y = vec![0.0f64; nx * nz];
            let mut along_z = vec![0.0f64; nx * ny];
            for k in 0..nz {
                for j in 0..ny {
                    for i in 0..nx {
                        let v = s[i + nx * (j + ny * k)] as f64;
                        along_x[j + ny * k] += v;
                        along_y[i + nx * k] += v;
                        along_z[i + nx * j] += v;
                    }
                }
            }
            for (axis, rows) in [along_x, along_y, along_z].iter().enumerate() {
                for v in rows {
                    best[axis] = best[axis].max(v * h);
                }
            }
        }
        best
    }

    /// A one-channel medium of σt per cell and one albedo, without emission, sampled
    /// `nearest`: the common case of tests and examples (checked as [`Medium::new`] checks).
    pub fn grey(
        grid: Grid,
        sigma_t: Vec<f32>,
        albedo: f32,
        phase: PhaseFunction,
    ) -> Result<Medium, MediumError> {
        Medium::new(
            grid,
            vec![ChannelMedium {
                sigma_t,
                albedo: CellValues::Uniform(albedo),
                emission: CellValues::Uniform(0.0),
            }],
            phase,
            Interpolation::Nearest,
            None,
        )
    }

    /// Builds and validates a medium.
    pub fn new(
        grid: Grid,
        channels: Vec<ChannelMedium>,
        phase: PhaseFunction,
        interpolation: Interpolation,
        data: Option<Vec<f32>>,
    ) -> Result<Self, MediumError> {
        let cells = grid.cell_count();
        if !(channels.len() == 1 || channels.len() == 3) {
            return Err(MediumError::invalid(
                "medium",
                format!("{} colour channels (expected 1 or 3)", channels.len()),
            ));
        }
        for ch in &channels {
            check_cells(&ch.sigma_t, "sigma_t", cells, 0.0, f32::MAX)?;
            ch.albedo.check("albedo", cells, 0.0, 1.0)?;
            ch.emission.check("emission", cells, 0.0, f32::MAX)?;
        }
        if let Some(d) = &data {
            if d.len() != cells {
                return Err(MediumError::invalid(
                    "data",
                    format!("{} values for {cells} cells", d.len()),
                ));
            }
        }
        phase.validate()?;
        Ok(Medium {
            grid,
            channels,
            phase,
            interpolation,
            data,
        })
    }

    /// A grey homogeneous medium, handy for tests and analytic cases.
    pub fn homogeneous(
        grid: Grid,
        sigma_t: f32,
        albedo: f32,
        emission: f32,
        phase: PhaseFunction,
    ) -> Result<Self, MediumError> {
        Medium::new(
            grid,
            vec![ChannelMedium {
                sigma_t: vec![sigma_t; grid.cell_count()],
                albedo: CellValues::Uniform(albedo),
                emission: CellValues::Uniform(emission),
            }],
            phase,
            Interpolation::Nearest,
            None,
        )
    }

    pub fn is_grey(&self) -> bool {
        self.channels.len() == 1
    }

    /// Bytes held by the per-cell arrays, for `volrad info` and memory reports.
    pub fn memory_bytes(&self) -> usize {
        let vals = |v: &CellValues| match v {
            CellValues::Uniform(_) => 0,
            CellValues::PerCell(v) => v.len() * 4,
        };
        self.channels
            .iter()
            .map(|c| c.sigma_t.len() * 4 + vals(&c.albedo) + vals(&c.emission))
            .sum::<usize>()
            + self.data.as_ref().map_or(0, |d| d.len() * 4)
    }
}
