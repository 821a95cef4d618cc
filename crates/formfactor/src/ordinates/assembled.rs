//! The discrete-ordinates operator as an explicit sparse matrix (cells × bins), for small
//! grids: the reference the matrix-free sweep must agree with.
//!
//! Built column by column: for each piece of each bin and each source cell, a unit source is
//! propagated through the downstream box of that cell only (not a whole-grid sweep), giving
//! the transport "form factors" `F_{c l, c' l}`; the matrix is then
//! `K[(c,l), (c',j)] = F_{c l, c' l} σs_{c'} P_lj Ω_j`, over the operator's state cells
//! (those with medium, [`OrdinatesOperator::state_cells`]). Vacuum sides only. With a linear
//! source the unit source's slopes reach its neighbours, so the box starts one cell upstream.

use solver::operator::{RowAccess, TransportOperator};
use sprs::{CsMat, TriMat};

use super::sweep::OrdinatesOperator;
use super::OrdinatesError;

/// Largest `cells × bins` accepted (the matrix has up to `(N M)·N·M / 8` entries).
pub const MAX_ASSEMBLED_UNKNOWNS: usize = 20_000;

/// The explicit operator `K` in CSR form.
pub struct AssembledOrdinates {
    matrix: CsMat<f64>,
}

impl AssembledOrdinates {
    /// Assembles the operator of `op` (same medium, bins, phase matrix and scheme).
    pub fn from_operator(op: &OrdinatesOperator) -> Result<Self, OrdinatesError> {
        let grid = *op.grid();
        let [nx, ny, nz] = grid.dims;
        let n = grid.cell_count();
        let m = op.bins().len();
        let unknowns = op.len();
        if unknowns > MAX_ASSEMBLED_UNKNOWNS {
            return Err(OrdinatesError::Length {
                what: "assembled unknowns (cells × bins)",
                got: unknowns,
                expected: MAX_ASSEMBLED_UNKNOWNS,
            });
        }
        if op.options().transport_refinement != 1 {
            return Err(OrdinatesError::Option(
                "the assembled operator supports transport_refinement = 1 only".into(),
            ));
        }
        if op.options().periodic_xy {
            return Err(OrdinatesError::Medium(
                "the assembled operator supports vacuum sides only".into(),
            ));
        }
        let sigma_s = op.sigma_s();
        let matrix = op.phase_matrix();
        let omega = op.bins().solid_angles();
        let mut tri = TriMat::new((unknowns, unknowns));
        // Each cell's outflow through its downstream x, y and z faces (each face's moments),
        // and its response.
        let mut out = vec![[[0.0f64; 3]; 3]; n];
        let mut response = vec![0.0f64; n];
        // One bin's source densities: a unit one in the source cell (a linear source's
        // slopes reach its neighbours).
        let mut density = vec![0.0f64; n];
        let reach = usize::from(op.linear_source());
        for (p, piece) in op.pieces().iter().enumerate() {
            let l = piece.bin;
            for (src, &sigma_s_src) in sigma_s.iter().enumerate() {
                if sigma_s_src == 0.0 {
                    continue;
                }
                let [ci, cj, ck] = grid.coords(src);
                let src_row = op.state_row(src).expect("a scattering cell carries state");
                // The box's upstream corner: the source cell, or with a linear source its
                // upstream neighbours, whose slopes it changes.
                let first = |v: usize, len: usize, fwd: bool| {
                    if fwd {
                        v.saturating_sub(reach)
                    } else {
                        (v + reach).min(len - 1)
                    }
                };
                let (si, sj, sk) = (
                    first(ci, nx, piece.forward[0]),
                    first(cj, ny, piece.forward[1]),
                    first(ck, nz, piece.forward[2]),
                );
                // A unit density, as the sweep reads it (the source function with a linear
                // source).
                density[src] = op.source_function_of_unit_density(src);
                // Downstream box of the source cell, walked in downwind order.
                let range = |start: usize, len: usize, fwd: bool| -> Vec<usize> {
                    if fwd {
                        (start..len).collect()
                    } else {
                        (0..=start).rev().collect()
                    }
                };
                let (xs, ys, zs) = (
                    range(si, nx, piece.forward[0]),
                    range(sj, ny, piece.forward[1]),
                    range(sk, nz, piece.forward[2]),
                );
                let up = |v: usize, fwd: bool, first: usize| -> Option<usize> {
                    if v == first {
                        None
                    } else if fwd {
                        Some(v - 1)
                    } else {
                        Some(v + 1)
                    }
                };
                for &k in &zs {
                    for &j in &ys {
                        for &i in &xs {
                            let c = grid.index(i, j, k);
                            let mut inflow = [[0.0; 3]; 3];
                            if let Some(u) = up(i, piece.forward[0], si) {
                                inflow[0] = out[grid.index(u, j, k)][0];
                            }
                            if let Some(u) = up(j, piece.forward[1], sj) {
                                inflow[1] = out[grid.index(i, u, k)][1];
                            }
                            if let Some(u) = up(k, piece.forward[2], sk) {
                                inflow[2] = out[grid.index(i, j, u)][2];
                            }
                            (out[c], response[c]) =
                                op.cell_response(p, c, [i, j, k], inflow, &density);
                        }
                    }
                }
                for &k in &zs {
                    for &j in &ys {
                        for &i in &xs {
                            let c = grid.index(i, j, k);
                            let f = piece.weight * response[c];
                            if let (Some(row), true) = (op.state_row(c), f != 0.0) {
                                for (jb, &omega_jb) in omega.iter().enumerate() {
                                    let v = f * sigma_s_src * matrix.get(l, jb) * omega_jb;
                                    tri.add_triplet(row * m + l, src_row * m + jb, v);
                                }
                            }
                            out[c] = [[0.0; 3]; 3];
                            response[c] = 0.0;
                        }
                    }
                }
                density[src] = 0.0;
            }
        }
        Ok(AssembledOrdinates {
            matrix: tri.to_csr(),
        })
    }

    pub fn matrix(&self) -> &CsMat<f64> {
        &self.matrix
    }

    pub fn nnz(&self) -> usize {
        self.matrix.nnz()
    }
}

impl RowAccess for AssembledOrdinates {
    fn row_dot(&self, row: usize, x: &[f64]) -> f64 {
        self.matrix
            .outer_view(row)
            .map_or(0.0, |r| r.iter().map(|(j, v)| v * x[j]).sum())
    }
}

impl TransportOperator for AssembledOrdinates {
    fn len(&self) -> usize {
        self.matrix.rows()
    }

    fn apply(&self, x: &[f64], y: &mut [f64]) {
        for (row, yr) in y.iter_mut().enumerate() {
            *yr = self.row_dot(row, x);
        }
    }

    fn rows(&self) -> Option<&dyn RowAccess> {
        Some(self)
    }
}
