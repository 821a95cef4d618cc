//! Where the gap between discrete ordinates and the zonal method comes from: angular (bins
//! `6 n²`, `ZONAL_N=4,6,8`) or spatial (both methods on grids refined `r`×, `ZONAL_R=1,2,3`,
//! `ZONAL_ZR`; the 7³ zonal solution is the reference). `ZONAL_REFINE=r` sweeps `r³`
//! sub-cells per cell, `ZONAL_MAX_SHARES=1` uses Max's fixed face shares instead of the
//! face-coupled sweep, `ZONAL_EXACT_T=1` (with Max's shares) the exact chord transmission,
//! `ZONAL_FLAT=1` a scattered source uniform in each cell (not linear).
//!
//! `cargo run --release -p formfactor --example ordinates_zonal_gap`

#[path = "../tests/support/blob.rs"]
mod blob;

use blob::{rms_against, scattered_ordinates, scattered_zonal};

fn main() {
    explore_ordinates_zonal_gap();
}

/// Where the ordinates–zonal gap comes from: angular (bins `6 n²`, `ZONAL_N=4,6,8`) or
/// spatial (both methods on grids refined `r`×, `ZONAL_R=1,2,3`; the 7³ zonal solution is the
/// reference). `cargo run --release -p formfactor --example ordinates_zonal_gap`
fn explore_ordinates_zonal_gap() {
    let list = |key: &str, default: &str| -> Vec<usize> {
        std::env::var(key)
            .unwrap_or(default.into())
            .split(',')
            .map(|v| v.parse().unwrap())
            .collect()
    };
    let reference = scattered_zonal(1);
    for r in list("ZONAL_ZR", "1").into_iter().filter(|&r| r > 1) {
        let (rms, mean) = rms_against(&reference, &scattered_zonal(r));
        println!("zonal refined {r}x: RMS {rms:.4} mean {mean:+.4} vs zonal 7³");
    }
    for r in list("ZONAL_R", "1") {
        for n in list("ZONAL_N", "4") {
            let (rms, mean) = rms_against(&reference, &scattered_ordinates(r, n));
            println!(
                "ordinates refined {r}x, {} bins: RMS {rms:.4} mean {mean:+.4} vs zonal 7³",
                6 * n * n
            );
        }
    }
}
