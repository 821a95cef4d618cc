//! A coarser transport grid over a medium's grid, for solving multiple scattering of volumes
//! too large to solve cell by cell.
//!
//! The multiply scattered light is smooth: it can be solved on cells of `s × s × s` data
//! cells while the first bounce stays exact at the data's resolution (the render's single
//! scattering from the full-resolution light pass). A [`Coarsening`] maps the data grid onto
//! such a transport grid and carries what the solve needs across:
//! - the medium ([`Coarsening::medium`]): per transport cell the block's total extinction,
//!   scattering and emission over its volume, so each is conserved;
//! - the light pass ([`Coarsening::light_pass`]): per transport cell the irradiance weighted
//!   by the data cells' σs, so the first-collision scattered power `σs V E` of every block is
//!   the data grid's exactly.
//!
//! The transport grid starts at the data grid's origin; where the data dims are not a
//! multiple of `s` its last cells reach past the data, and that part counts as empty.

use crate::light_pass::{LightEnergy, LightField, LightPass};
use crate::optical::{CellValues, ChannelMedium, Medium};
use crate::{Grid, MediumError};

/// The largest transport scale accepted (a block of 16³ data cells).
pub const MAX_TRANSPORT_SCALE: usize = 16;

/// A data grid and the transport grid of blocks of `scale³` of its cells.
///
/// # Invariants
/// `1 ≤ scale ≤ MAX_TRANSPORT_SCALE`; `coarse.dims = ceil(fine.dims / scale)` and
/// `coarse.cell_size = scale · fine.cell_size`. Checked by [`Coarsening::new`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Coarsening {
    fine: Grid,
    coarse: Grid,
    scale: usize,
}

impl Coarsening {
    pub fn new(fine: &Grid, scale: usize) -> Result<Coarsening, MediumError> {
        if !(1..=MAX_TRANSPORT_SCALE).contains(&scale) {
            return Err(MediumError::invalid(
                "transport scale",
                format!("{scale}: must be 1..={MAX_TRANSPORT_SCALE}"),
            ));
        }
        let coarse = Grid::new(
            fine.dims.map(|d| d.div_ceil(scale)),
            fine.cell_size * scale as f64,
        )?;
        Ok(Coarsening {
            fine: *fine,
            coarse,
            scale,
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

    pub fn coarse(&self) -> &Grid {
        &self.coarse
    }

    pub fn scale(&self) -> usize {
        self.scale
    }

    /// The transport cell holding data cell `fine_cell`.
    #[inline]
    pub fn coarse_cell_of(&self, fine_cell: usize) -> usize {
        let [i, j, k] = self.fine.coords(fine_cell);
        let s = self.scale;
        self.coarse.index(i / s, j / s, k / s)
    }

    /// `Σ_{data cells in block} value(cell)` per transport cell, for `N` quantities at once:
    /// one pass over the data grid, rows mapped to blocks without a division per cell.
    fn block_sums<const N: usize>(&self, value: impl Fn(usize) -> [f64; N]) -> Vec<[f64; N]> {
        let mut sums = vec![[0.0f64; N]; self.coarse.cell_count()];
        let [nx, ny, nz] = self.fine.dims;
        let s = self.scale;
        let mut cell = 0;
        for k in 0..nz {
            for j in 0..ny {
                let row = self.coarse.index(0, j / s, k / s);
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
            self.coarse,
            channels,
            medium.phase(),
            medium.interpolation(),
            None,
        )
    }

    /// Channel `c`'s light pass (on the data grid, of `medium`) carried to the transport
    /// grid, for the transport medium `coarse` ([`Coarsening::medium`] of `medium`): per
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
        if *medium.grid() != self.fine || pass.grid != self.fine || *coarse.grid() != self.coarse {
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
        // Per block: Σσs, Σσt and the data cells in it.
        let weights = self.block_sums(|i| [ch.sigma_s(i) as f64, ch.sigma_t[i] as f64, 1.0]);
        let volume = self.coarse.cell_volume();
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
                let [cx, cy, cz] = self.coarse.dims;
                let [fx, fy, fz] = self.fine.dims;
                let s = self.scale;
                let mut corner_optical_depth = vec![0.0f32; self.coarse.corner_count()];
                for k in 0..=cz {
                    for j in 0..=cy {
                        for i in 0..=cx {
                            let fine = self.fine.corner_index(
                                (i * s).min(fx),
                                (j * s).min(fy),
                                (k * s).min(fz),
                            );
                            corner_optical_depth[self.coarse.corner_index(i, j, k)] =
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
                    corner_optical_depth,
                    energy: LightEnergy {
                        extinguished,
                        ..f.energy
                    },
                }
            })
            .collect();
        Ok(LightPass {
            grid: self.coarse,
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
        assert_eq!(k.coarse().dims, [4, 3, 3]);
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
        let mut per_block = vec![0.0f64; k.coarse().cell_count()];
        for i in 0..fine.grid().cell_count() {
            per_block[k.coarse_cell_of(i)] += ch.sigma_s(i) as f64
                * pass.fields[0].cell_irradiance[i] as f64
                * fine.grid().cell_volume();
        }
        let cch = &coarse.channels()[0];
        for (o, &want) in per_block.iter().enumerate() {
            let got = cch.sigma_s(o) as f64
                * carried.fields[0].cell_irradiance[o] as f64
                * k.coarse().cell_volume();
            assert!(
                (got - want).abs() <= 1e-5 * want.max(1e-9),
                "block {o}: {got} vs {want}"
            );
        }
        let fine_corner = fine.grid().corner_index(4, 2, 6);
        let coarse_corner = k.coarse().corner_index(2, 1, 3);
        assert_eq!(
            carried.fields[0].corner_optical_depth[coarse_corner],
            pass.fields[0].corner_optical_depth[fine_corner]
        );
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
