//! A transport grid over a medium's grid, coarser or finer than the data's, for solving the
//! multiple scattering of volumes too large to solve cell by cell, or too thick per cell.
//!
//! The multiply scattered light is smooth: it can be solved on cells of `s × s × s` data
//! cells while the first bounce stays exact at the data's resolution (the render's single
//! scattering from the full-resolution light pass). Where cells are optically thick the
//! opposite holds: a source uniform over a cell of optical depth τ ≫ 1 carries light too
//! deep, so each data cell is split into `r × r × r` transport cells. A [`Coarsening`] maps
//! the data grid onto such a transport grid and carries what the solve needs across:
//! - the medium ([`Coarsening::medium`]): per transport cell the block's total extinction,
//!   scattering and emission over its volume, so each is conserved (a split cell's parts
//!   take its values);
//! - the light pass ([`Coarsening::light_pass`]): per transport cell the irradiance weighted
//!   by the data cells' σs, so the first-collision scattered power `σs V E` of every block is
//!   the data grid's exactly; on a split grid the pass is traced again on the finer cells,
//!   so the light's fall-off inside a thick data cell reaches the solve.
//!
//! The transport grid starts at the data grid's origin; where the data dims are not a
//! multiple of `s` its last cells reach past the data, and that part counts as empty.

use crate::light_pass::{LightEnergy, LightField, LightPass};
use crate::optical::{CellValues, ChannelMedium, Medium};
use crate::{Grid, MediumError};

/// The largest transport scale accepted (a block of 16³ data cells).
pub const MAX_TRANSPORT_SCALE: usize = 16;

/// The largest split accepted (each data cell into 4³ transport cells).
pub const MAX_TRANSPORT_SPLIT: usize = 4;

/// A data grid and its transport grid: blocks of `scale³` of its cells, or each cell split
/// into `split³`.
///
/// # Invariants
/// `1 ≤ scale ≤ MAX_TRANSPORT_SCALE`, `1 ≤ split ≤ MAX_TRANSPORT_SPLIT`, not both above 1;
/// `transport.dims = ceil(fine.dims / scale) · split` and `transport.cell_size =
/// fine.cell_size · scale / split`. Checked by [`Coarsening::new`] and [`Coarsening::split`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coarsening {
    fine: Grid,
    transport: Grid,
    scale: usize,
    split: usize,
}

impl Coarsening {
    /// The transport grid of blocks of `scale³` data cells (1: the data grid itself).
    pub fn new(fine: &Grid, scale: usize) -> Result<Coarsening, MediumError> {
        if !(1..=MAX_TRANSPORT_SCALE).contains(&scale) {
            return Err(MediumError::invalid(
                "transport scale",
                format!("{scale}: must be 1..={MAX_TRANSPORT_SCALE}"),
            ));
        }
        let transport = Grid::new(
            fine.dims.map(|d| d.div_ceil(scale)),
            fine.cell_size * scale as f64,
        )?;
        Ok(Coarsening {
            fine: *fine,
            transport,
            scale,
            split: 1,
        })
    }

    /// The transport grid that splits each data cell into `split³` cells (1: the data grid).
    pub fn split(fine: &Grid, split: usize) -> Result<Coarsening, MediumError> {
        if !(1..=MAX_TRANSPORT_SPLIT).contains(&split) {
            return Err(MediumError::invalid(
                "transport split",
                format!("{split}: must be 1..={MAX_TRANSPORT_SPLIT}"),
            ));
        }
        let transport = Grid::new(fine.dims.map(|d| d * split), fine.cell_size / split as f64)?;
        Ok(Coarsening {
            fine: *fine,
            transport,
            scale: 1,
            split,
        })
    }

    /// The transport grid's cell count for `fine` at `scale`, without building anything.
    pub fn cell_count_of(fine: &Grid, scale: usize) -> usize {
        fine.dims
            .iter()
            .map(|&d| d.div_ceil(scale.max(1)))
            .product()
    }

    pub fn fine(&self) -> &Grid {
        &self.fine
    }

    /// The grid the multiple scattering is solved on.
    pub fn transport(&self) -> &Grid {
        &self.transport
    }

    /// Data cells per side of a transport cell (1 on a split grid).
    pub fn scale(&self) -> usize {
        self.scale
    }

    /// Transport cells per side of a data cell (1 on a coarser grid).
    pub fn split_factor(&self) -> usize {
        self.split
    }

    /// Whether the transport grid is the data grid itself.
    pub fn is_data_grid(&self) -> bool {
        self.scale == 1 && self.split == 1
    }

    /// The transport cell holding data cell `fine_cell` (on a split grid: the one at the data
    /// cell's lowest corner).
    #[inline]
    pub fn coarse_cell_of(&self, fine_cell: usize) -> usize {
        let [i, j, k] = self.fine.coords(fine_cell);
        let (s, r) = (self.scale, self.split);
        self.transport.index(i / s * r, j / s * r, k / s * r)
    }

    /// `Σ_{data cells in block} value(cell)` per transport cell, for `N` quantities at once:
    /// one pass over the data grid, rows mapped to blocks without a division per cell.
    fn block_sums<const N: usize>(&self, value: impl Fn(usize) -> [f64; N]) -> Vec<[f64; N]> {
        let mut sums = vec![[0.0f64; N]; self.transport.cell_count()];
        let [nx, ny, nz] = self.fine.dims;
        let s = self.scale;
        let mut cell = 0;
        for k in 0..nz {
            for j in 0..ny {
                let row = self.transport.index(0, j / s, k / s);
                for i in 0..nx {
                    let v = value(cell);
                    let sum = &mut sums[row + i / s];
                    for (a, b) in sum.iter_mut().zip(v) {
                        *a += b;
                    }
                    cell += 1;
                }
            }
        }
        sums
    }

    /// The medium on the transport grid: per transport cell the block's mean σt, σs and
    /// emission over the whole transport cell (data cells outside the grid count as empty),
    /// so total extinction, scattering and emission are conserved. A uniform albedo or
    /// emission stays uniform. The data values are not kept (they only shade renders).
    pub fn medium(&self, medium: &Medium) -> Result<Medium, MediumError> {
        if *medium.grid() != self.fine {
            return Err(MediumError::invalid(
                "transport grid",
                "the medium is not on the grid this coarsening was made for",
            ));
        }
        if self.split > 1 {
            return self.split_medium(medium);
        }
        let per_block = 1.0 / (self.scale * self.scale * self.scale) as f64;
        let channels = medium
            .channels()
            .iter()
            .map(|ch| {
                // Per block: Σσt, Σσs, Σe.
                let sums = self.block_sums(|i| {
                    [
                        ch.sigma_t[i] as f64,
                        ch.sigma_s(i) as f64,
                        ch.emission.get(i) as f64,
                    ]
                });
                let albedo = match &ch.albedo {
                    CellValues::Uniform(a) => CellValues::Uniform(*a),
                    CellValues::PerCell(_) => CellValues::PerCell(
                        sums.iter()
                            .map(|&[t, s, _]| {
                                if t > 0.0 {
                                    (s / t).clamp(0.0, 1.0) as f32
                                } else {
                                    0.0
                                }
                            })
                            .collect(),
                    ),
                };
                let emission = match &ch.emission {
                    CellValues::Uniform(e) => CellValues::Uniform(*e),
                    CellValues::PerCell(_) => CellValues::PerCell(
                        sums.iter().map(|v| (v[2] * per_block) as f32).collect(),
                    ),
                };
                ChannelMedium {
                    sigma_t: sums.iter().map(|v| (v[0] * per_block) as f32).collect(),
                    albedo,
                    emission,
                }
            })
            .collect();
        Medium::new(
            self.transport,
            channels,
            medium.phase(),
            medium.interpolation(),
            None,
        )
    }

    /// [`medium`](Self::medium) on a split grid: every part of a data cell takes its values.
    fn split_medium(&self, medium: &Medium) -> Result<Medium, MediumError> {
        let parent: Vec<usize> = (0..self.transport.cell_count())
            .map(|t| {
                let [i, j, k] = self.transport.coords(t);
                let r = self.split;
                self.fine.index(i / r, j / r, k / r)
            })
            .collect();
        let spread = |values: &CellValues| match values {
            CellValues::Uniform(v) => CellValues::Uniform(*v),
            CellValues::PerCell(v) => CellValues::PerCell(parent.iter().map(|&p| v[p]).collect()),
        };
        let channels = medium
            .channels()
            .iter()
            .map(|ch| ChannelMedium {
                sigma_t: parent.iter().map(|&p| ch.sigma_t[p]).collect(),
                albedo: spread(&ch.albedo),
                emission: spread(&ch.emission),
            })
            .collect();
        Medium::new(
            self.transport,
            channels,
            medium.phase(),
            medium.interpolation(),
            None,
        )
    }

    /// Channel `c`'s light pass (on the data grid, of `medium`) carried to the transport
    /// grid, for the transport medium `coarse` ([`Coarsening::medium`] of `medium`). On a
    /// split grid: the pass of the same lights traced on `coarse`. Otherwise per
    /// transport cell the irradiance weighted by the data cells' σs (by σt where nothing
    /// scatters, else by volume), so the scattered first-collision power of each block is the
    /// data grid's. Corner depths are the data grid's at the transport corners (clamped to the
    /// data grid's last corner).
    pub fn light_pass(
        &self,
        medium: &Medium,
        c: usize,
        pass: &LightPass,
        coarse: &Medium,
    ) -> Result<LightPass, MediumError> {
        if *medium.grid() != self.fine || pass.grid != self.fine || *coarse.grid() != self.transport
        {
            return Err(MediumError::invalid(
                "transport grid",
                "the medium, light pass or transport medium is on another grid",
            ));
        }
        let (Some(ch), Some(coarse_ch)) = (medium.channels().get(c), coarse.channels().get(c))
        else {
            return Err(MediumError::invalid(
                "transport grid",
                format!("channel {c} does not exist"),
            ));
        };
        if self.split > 1 {
            // Traced again on the finer cells: inside a thick data cell the light falls off,
            // which the data grid's per-cell mean cannot say.
            let lights: Vec<_> = pass.fields.iter().map(|f| f.light).collect();
            return LightPass::compute(coarse, c, &lights);
        }
        // Per block: Σσs, Σσt and the data cells in it.
        let weights = self.block_sums(|i| [ch.sigma_s(i) as f64, ch.sigma_t[i] as f64, 1.0]);
        let volume = self.transport.cell_volume();
        let fields = pass
            .fields
            .iter()
            .map(|f| {
                let e = &f.cell_irradiance;
                let weighted = self.block_sums(|i| {
                    let e = e[i] as f64;
                    [ch.sigma_s(i) as f64 * e, ch.sigma_t[i] as f64 * e, e]
                });
                let cell_irradiance: Vec<f32> = weighted
                    .iter()
                    .zip(&weights)
                    .map(|(by, &[s, t, count])| {
                        let v = if s > 0.0 {
                            by[0] / s
                        } else if t > 0.0 {
                            by[1] / t
                        } else {
                            by[2] / count
                        };
                        v as f32
                    })
                    .collect();
                let [cx, cy, cz] = self.transport.dims;
                let [fx, fy, fz] = self.fine.dims;
                let s = self.scale;
                let mut corner_optical_depth = vec![0.0f32; self.transport.corner_count()];
                for k in 0..=cz {
                    for j in 0..=cy {
                        for i in 0..=cx {
                            let fine = self.fine.corner_index(
                                (i * s).min(fx),
                                (j * s).min(fy),
                                (k * s).min(fz),
                            );
                            corner_optical_depth[self.transport.corner_index(i, j, k)] =
                                f.corner_optical_depth[fine];
                        }
                    }
                }
                let extinguished = cell_irradiance
                    .iter()
                    .zip(&coarse_ch.sigma_t)
                    .map(|(&e, &t)| e as f64 * t as f64 * volume)
                    .sum();
                LightField {
                    light: f.light,
                    cell_irradiance,
                    corner_optical_depth: std::sync::Arc::new(corner_optical_depth),
                    energy: LightEnergy {
                        extinguished,
                        ..f.energy
                    },
                }
            })
            .collect();
        Ok(LightPass {
            grid: self.transport,
            sigma_t: coarse_ch.sigma_t.clone(),
            fields,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Light, PhaseFunction};
    use glam::DVec3;

    fn blob(dims: [usize; 3]) -> Medium {
        let grid = Grid::new(dims, 0.5).unwrap();
        let n = grid.cell_count();
        let sigma_t: Vec<f32> = (0..n)
            .map(|i| {
                let p = grid.cell_center(i) - grid.center();
                (3.0 - p.length()).max(0.0) as f32
            })
            .collect();
        let albedo: Vec<f32> = (0..n).map(|i| 0.5 + 0.4 * ((i % 7) as f32 / 7.0)).collect();
        Medium::new(
            grid,
            vec![ChannelMedium {
                sigma_t,
                albedo: CellValues::PerCell(albedo),
                emission: CellValues::PerCell((0..n).map(|i| (i % 3) as f32).collect()),
            }],
            PhaseFunction::HenyeyGreenstein { g: 0.5 },
            crate::Interpolation::Nearest,
            None,
        )
        .unwrap()
    }

    /// Extinction, scattering and emission summed over the volume are the data grid's, also
    /// where the data dims are not a multiple of the scale.
    #[test]
    fn the_transport_medium_conserves_extinction_scattering_and_emission() {
        let fine = blob([11, 9, 8]);
        let k = Coarsening::new(fine.grid(), 3).unwrap();
        assert_eq!(k.transport().dims, [4, 3, 3]);
        let coarse = k.medium(&fine).unwrap();
        let total = |m: &Medium, f: &dyn Fn(&ChannelMedium, usize) -> f64| {
            let ch = &m.channels()[0];
            (0..m.grid().cell_count()).map(|i| f(ch, i)).sum::<f64>() * m.grid().cell_volume()
        };
        for (what, f) in [
            (
                "σt",
                &(|c: &ChannelMedium, i: usize| c.sigma_t[i] as f64)
                    as &dyn Fn(&ChannelMedium, usize) -> f64,
            ),
            ("σs", &|c: &ChannelMedium, i: usize| c.sigma_s(i) as f64),
            ("e", &|c: &ChannelMedium, i: usize| c.emission.get(i) as f64),
        ] {
            let (a, b) = (total(&fine, f), total(&coarse, f));
            assert!((a - b).abs() < 1e-5 * a, "{what}: {a} vs {b}");
        }
    }

    /// The carried light pass scatters the same first-collision power per block as the data
    /// grid's, and its corner depths are the data grid's at shared corners.
    #[test]
    fn the_carried_light_pass_keeps_each_blocks_scattered_power() {
        let fine = blob([10, 10, 8]);
        let light = Light::Directional {
            direction: DVec3::new(0.3, -0.2, -1.0).normalize(),
            irradiance: 2.0,
        };
        let pass = LightPass::compute(&fine, 0, &[light]).unwrap();
        let k = Coarsening::new(fine.grid(), 2).unwrap();
        let coarse = k.medium(&fine).unwrap();
        let carried = k.light_pass(&fine, 0, &pass, &coarse).unwrap();
        let ch = &fine.channels()[0];
        let mut per_block = vec![0.0f64; k.transport().cell_count()];
        for i in 0..fine.grid().cell_count() {
            per_block[k.coarse_cell_of(i)] += ch.sigma_s(i) as f64
                * pass.fields[0].cell_irradiance[i] as f64
                * fine.grid().cell_volume();
        }
        let cch = &coarse.channels()[0];
        for (o, &want) in per_block.iter().enumerate() {
            let got = cch.sigma_s(o) as f64
                * carried.fields[0].cell_irradiance[o] as f64
                * k.transport().cell_volume();
            assert!(
                (got - want).abs() <= 1e-5 * want.max(1e-9),
                "block {o}: {got} vs {want}"
            );
        }
        let fine_corner = fine.grid().corner_index(4, 2, 6);
        let coarse_corner = k.transport().corner_index(2, 1, 3);
        assert_eq!(
            carried.fields[0].corner_optical_depth[coarse_corner],
            pass.fields[0].corner_optical_depth[fine_corner]
        );
    }

    /// A split grid keeps the medium (each part takes its data cell's values, so totals are
    /// the data's) and traces the light again on its cells: inside a thick cell the parts
    /// nearer the light get more of it, and the pass's extinguished power is the data grid's
    /// to within the data grid's own per-cell approximation.
    #[test]
    fn a_split_grid_keeps_the_medium_and_resolves_the_light_inside_thick_cells() {
        let fine = blob([6, 5, 4]);
        let k = Coarsening::split(fine.grid(), 2).unwrap();
        assert_eq!(k.transport().dims, [12, 10, 8]);
        assert!(!k.is_data_grid() && k.scale() == 1 && k.split_factor() == 2);
        let split = k.medium(&fine).unwrap();
        let total = |m: &Medium| {
            let ch = &m.channels()[0];
            (0..m.grid().cell_count())
                .map(|i| ch.sigma_t[i] as f64 + ch.sigma_s(i) as f64 + ch.emission.get(i) as f64)
                .sum::<f64>()
                * m.grid().cell_volume()
        };
        assert!((total(&fine) - total(&split)).abs() < 1e-9 * total(&fine));
        let light = Light::Directional {
            direction: DVec3::new(0.0, 0.0, -1.0),
            irradiance: 1.0,
        };
        let pass = LightPass::compute(&fine, 0, &[light]).unwrap();
        let traced = k.light_pass(&fine, 0, &pass, &split).unwrap();
        assert_eq!(traced.grid, *k.transport());
        // The light comes down from +z: in each thick data cell the upper parts are brighter.
        let e = &traced.fields[0].cell_irradiance;
        let g = k.transport();
        let (mut upper, mut lower) = (0.0f64, 0.0f64);
        for kz in (0..g.dims[2]).step_by(2) {
            for j in 0..g.dims[1] {
                for i in 0..g.dims[0] {
                    lower += e[g.index(i, j, kz)] as f64;
                    upper += e[g.index(i, j, kz + 1)] as f64;
                }
            }
        }
        assert!(upper > 1.05 * lower, "upper {upper} lower {lower}");
        let (a, b) = (
            pass.fields[0].energy.extinguished,
            traced.fields[0].energy.extinguished,
        );
        assert!((a - b).abs() < 0.02 * a, "extinguished {a} vs {b}");
        assert!(Coarsening::split(fine.grid(), 0).is_err());
        assert!(Coarsening::split(fine.grid(), MAX_TRANSPORT_SPLIT + 1).is_err());
    }

    #[test]
    fn scales_outside_the_range_and_foreign_grids_are_refused() {
        let fine = blob([4, 4, 4]);
        assert!(Coarsening::new(fine.grid(), 0).is_err());
        assert!(Coarsening::new(fine.grid(), MAX_TRANSPORT_SCALE + 1).is_err());
        let other = Coarsening::new(&Grid::new([5, 4, 4], 0.5).unwrap(), 2).unwrap();
        assert!(other.medium(&fine).is_err());
        let same = Coarsening::new(fine.grid(), 1).unwrap();
        assert_eq!(
            same.medium(&fine).unwrap().channels()[0].sigma_t,
            fine.channels()[0].sigma_t
        );
        assert_eq!(Coarsening::cell_count_of(fine.grid(), 3), 8);
    }
}
