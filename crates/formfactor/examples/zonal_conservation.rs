//! Does the exact zonal operator keep energy? For every cell, the fraction of its emission
//! the operator deposits in the grid (the column sum of `F`) against the same fraction traced
//! through the grid by random rays, split into the near field (within four cells, the ray
//! stencil) and the far field (the far estimate). σt-weighted means over the cells.
//!
//! ```sh
//! cargo run --release -p formfactor --example zonal_conservation -- \
//!     tests/data/cloud24-isotropic/cloud24.f32 24,24,18 1.0 20000
//! ```
//! Arguments: a raw little-endian f32 σt file (x fastest), its dims, the cell size, the
//! rays traced per cell (default 20,000) and a factor on σt (default 1). The hierarchical
//! operator's column sums are compared too (its default options; `VOLRAD_TOLERANCE` and
//! `VOLRAD_MAX_OPENING` override its tolerance and largest opening). docs/validation.md,
//! "The zonal far field", quotes it.
use formfactor::zonal::{ExactOptions, FormFactorMatrix};
use formfactor::{HierarchicalOperator, HierarchicalOptions};
use glam::DVec3;
use medium::{traversal::Ray, Grid, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use rayon::prelude::*;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let path = &args[1];
    let dims: Vec<usize> = args[2].split(',').map(|v| v.parse().unwrap()).collect();
    let h: f64 = args[3].parse().unwrap();
    let rays: usize = args.get(4).map(|v| v.parse().unwrap()).unwrap_or(20000);
    let scale: f32 = args.get(5).map(|v| v.parse().unwrap()).unwrap_or(1.0);
    let bytes = std::fs::read(path).unwrap();
    let sigma: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|c| scale * f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    let grid = Grid::new([dims[0], dims[1], dims[2]], h).unwrap();
    let medium = Medium::grey(grid, sigma.clone(), 0.99, PhaseFunction::Isotropic).unwrap();
    let start = std::time::Instant::now();
    let f = FormFactorMatrix::build(&medium, 0, &ExactOptions::default(), None).unwrap();
    println!("operator built in {:.3} s", start.elapsed().as_secs_f64());
    let cols = f.column_sums();
    let hierarchy = HierarchicalOperator::build(&medium, 0, &hierarchy_options()).unwrap();
    let hierarchy_cols = hierarchy.column_sums();
    println!(
        "hierarchy: {} links, {} near entries, built in {:.2} s",
        hierarchy.link_count(),
        hierarchy.near_entries(),
        hierarchy.report().seconds
    );
    let active: Vec<usize> = (0..sigma.len()).filter(|&i| sigma[i] > 0.0).collect();
    let r = 4i64;
    // near / far parts of each column from the matrix
    let mut near = vec![0.0; sigma.len()];
    let m = f.matrix();
    for (i, row) in m.outer_iterator().enumerate() {
        let ci = grid.coords(i).map(|c| c as i64);
        for (j, &v) in row.iter() {
            let cj = grid.coords(j).map(|c| c as i64);
            let cheb = (0..3).map(|a| (ci[a] - cj[a]).abs()).max().unwrap();
            if cheb <= r {
                near[j] += v;
            }
        }
    }
    let traced: Vec<(f64, f64)> = active
        .par_iter()
        .map(|&j| {
            let mut rng = rand_pcg::Pcg64::seed_from_u64(j as u64);
            let c0 = grid.coords(j).map(|c| c as i64);
            let lo = grid.cell_center(j) - DVec3::splat(0.5 * h);
            let (mut tot, mut nr) = (0.0, 0.0);
            for _ in 0..rays {
                let p = lo
                    + DVec3::new(
                        rng.random::<f64>(),
                        rng.random::<f64>(),
                        rng.random::<f64>(),
                    ) * h;
                let z: f64 = 1.0 - 2.0 * rng.random::<f64>();
                let phi = 2.0 * std::f64::consts::PI * rng.random::<f64>();
                let s = (1.0 - z * z).sqrt();
                let d = DVec3::new(s * phi.cos(), s * phi.sin(), z);
                let mut t = 1.0f64;
                for seg in grid.traverse(&Ray::new(p, d), 0.0, f64::INFINITY) {
                    let sg = sigma[seg.cell] as f64;
                    if sg > 0.0 {
                        let e = (-sg * seg.length()).exp();
                        let dep = t * (1.0 - e);
                        let cc = grid.coords(seg.cell).map(|c| c as i64);
                        let cheb = (0..3).map(|a| (cc[a] - c0[a]).abs()).max().unwrap();
                        tot += dep;
                        if cheb <= r {
                            nr += dep;
                        }
                        t *= e;
                    }
                }
            }
            (tot / rays as f64, nr / rays as f64)
        })
        .collect();
    let (mut w, mut dt, mut dn, mut df, mut st, mut sabs) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let mut dh = 0.0;
    for (k, &j) in active.iter().enumerate() {
        let wt = sigma[j] as f64;
        let (tt, tn) = traced[k];
        w += wt;
        st += wt * tt;
        dt += wt * (cols[j] - tt);
        dh += wt * (hierarchy_cols[j] - tt);
        sabs += wt * (cols[j] - tt).abs();
        dn += wt * (near[j] - tn);
        df += wt * ((cols[j] - near[j]) - (tt - tn));
    }
    println!(
        "{} cells; traced extinction {:.5}; operator − traced: total {:+.5} (mean |·| {:.5}), \
         near field {:+.5}, far field {:+.5}; the hierarchy − traced: total {:+.5}",
        active.len(),
        st / w,
        dt / w,
        sabs / w,
        dn / w,
        df / w,
        dh / w,
    );
}

/// The hierarchy's default options, `VOLRAD_TOLERANCE` and `VOLRAD_MAX_OPENING` overriding.
fn hierarchy_options() -> HierarchicalOptions {
    let mut options = HierarchicalOptions::default();
    if let Ok(v) = std::env::var("VOLRAD_TOLERANCE") {
        options.tolerance = v.parse().unwrap();
    }
    if let Ok(v) = std::env::var("VOLRAD_MAX_OPENING") {
        options.max_opening = v.parse().unwrap();
    }
    options
}
