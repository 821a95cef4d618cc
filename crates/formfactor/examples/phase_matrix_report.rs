//! The phase matrix's errors for Henyey–Greenstein phase functions over bin counts: mean
//! cosine before and after the asymmetry tilt, worst single-scatter error, energy.
//!
//! `cargo run --release -p formfactor --example phase_matrix_report`

use formfactor::ordinates::phase_matrix::phase_matrix_error;
use formfactor::ordinates::{DirectionBins, PhaseMatrix};
use medium::PhaseFunction;

fn main() {
    for n in [2, 4, 6] {
        let bins = DirectionBins::cube(n).unwrap();
        for g in [0.0, 0.6, 0.85] {
            let phase = PhaseFunction::HenyeyGreenstein { g };
            let mut pm = PhaseMatrix::with_default_quadrature(&bins, &phase);
            let raw = phase_matrix_error(&bins, &pm, &phase);
            pm.match_asymmetry(&bins, g);
            let tilted = phase_matrix_error(&bins, &pm, &phase);
            println!(
                "M {:3} g {g:.2}: mean cosine raw {:.4} tilted {:.4}; single-scatter max rel raw {:.3} tilted {:.3}; energy {:.1e}",
                bins.len(),
                raw.mean_cosine,
                tilted.mean_cosine,
                raw.single_scatter_max_rel,
                tilted.single_scatter_max_rel,
                tilted.energy
            );
        }
    }
}
