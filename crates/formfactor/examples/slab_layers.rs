//! Where a thick slab's discrete-ordinates error sits, layer by layer: the higher orders'
//! source (the final gather's, orders ≥ 2) of each of the top layers against a solve with
//! every layer split `SLAB_FINE` times, the fine solve's profile inside the layer (its top
//! and bottom sub-layers over the layer's mean), and the source's slope inside the layer three ways —
//! the fine solve's own (the linear fit that keeps the layer's first moment), the
//! neighbours' differences the sweep uses (one-sided in the top layer), and Fick's law from
//! the layer's own net flux (`∇φ = −3 σtr F`).
//!
//! Slopes are relative half-changes across the layer, upper face less lower over the mean
//! (`r = 6 (x̄ − ½)`, `x̄` the source's mean height in the layer, 0 at its bottom).
//!
//! Settings from the environment: `SLAB_TAU` (64), `SLAB_ALBEDO` (0.9), `SLAB_G` (0),
//! `SLAB_MU0` (1), `SLAB_LAYERS` (64), `SLAB_FINE` (16), `SLAB_N` (6: 216 bins), `SLAB_SHOW`
//! (8 layers).
//!
//! `cargo run --release -p formfactor --example slab_layers`

#[path = "../tests/support/slab.rs"]
#[allow(dead_code)]
mod slab;

use formfactor::ordinates::OrdinatesOptions;

fn setting<T: std::str::FromStr>(key: &str, default: T) -> T
where
    T::Err: std::fmt::Debug,
{
    std::env::var(key).map_or(default, |v| v.parse().unwrap())
}

/// Per layer from the top: the mean higher-order source over the bins, and the scalar flux
/// and net upward flux of the solved radiance.
struct Layers {
    source: Vec<f64>,
    fluence: Vec<f64>,
    net_up: Vec<f64>,
    r: f64,
}

fn solve((tau, albedo, g, mu0): (f64, f64, f64, f64), nz: usize, n: usize) -> Layers {
    let res = slab::solve_slab_with(tau, albedo, g, mu0, nz, n, OrdinatesOptions::default());
    let (op, x) = (&res.op, &res.radiance);
    let m = op.bins().len();
    let (up, omega): (Vec<f64>, &[f64]) = (
        op.bins()
            .centres()
            .iter()
            .map(|d| d.normalize().z)
            .collect(),
        op.bins().solid_angles(),
    );
    let cell = |k: usize| nz - 1 - k;
    let source = (0..nz)
        .map(|k| {
            let c = cell(k);
            res.gathered[c * m..(c + 1) * m].iter().sum::<f64>() / m as f64
        })
        .collect();
    let moment = |k: usize, w: &dyn Fn(usize) -> f64| {
        let c = cell(k);
        (0..m).map(|l| x[c * m + l] * omega[l] * w(l)).sum::<f64>()
    };
    Layers {
        source,
        fluence: (0..nz).map(|k| moment(k, &|_| 1.0)).collect(),
        net_up: (0..nz).map(|k| moment(k, &|l| up[l])).collect(),
        r: res.r,
    }
}

fn main() {
    let tau: f64 = setting("SLAB_TAU", 64.0);
    let albedo: f64 = setting("SLAB_ALBEDO", 0.9);
    let g: f64 = setting("SLAB_G", 0.0);
    let mu0: f64 = setting("SLAB_MU0", 1.0);
    let layers: usize = setting("SLAB_LAYERS", 64);
    let split: usize = setting("SLAB_FINE", 16);
    let n: usize = setting("SLAB_N", 6);
    let show: usize = setting("SLAB_SHOW", 8usize).min(layers - 1);
    let case = (tau, albedo, g, mu0);
    let coarse = solve(case, layers, n);
    let fine = solve(case, layers * split, n);
    println!(
        "τ {tau}, albedo {albedo}, g {g}, μ0 {mu0}, {} bins: R {:.5} in {layers} layers, \
         {:.5} in {} ({:+.2} %)",
        6 * n * n,
        coarse.r,
        fine.r,
        layers * split,
        100.0 * (coarse.r / fine.r - 1.0)
    );
    println!(
        "| layer | source / top layer's | source vs fine | fine: top / bottom sub-layer | \
         slope: fine | differences | Fick |"
    );
    println!("|---|---|---|---|---|---|---|");
    // Both solves use unit cubes, so the fine layers' σs (and the density σs·Σ p I Ω) are
    // `split` times smaller for the same radiance.
    let scale = split as f64;
    let tau_tr = tau / layers as f64 * (1.0 - albedo * g);
    for k in 0..show {
        let sub = &fine.source[k * split..(k + 1) * split];
        let mean = sub.iter().sum::<f64>() / split as f64;
        // Height of each fine layer's centre in the coarse layer (1 at its top).
        let height = |i: usize| 1.0 - (i as f64 + 0.5) / split as f64;
        let mean_height = sub
            .iter()
            .enumerate()
            .map(|(i, s)| s * height(i))
            .sum::<f64>()
            / (mean * split as f64);
        let s = &coarse.source;
        let differences = if k == 0 {
            0.5 * (s[0] - s[1]) / s[0]
        } else {
            0.25 * (s[k - 1] - s[k + 1]) / s[k]
        };
        let fick = -1.5 * tau_tr * coarse.net_up[k] / coarse.fluence[k];
        println!(
            "| {k} | {:.1e} | {:+.2} % | {:.2} / {:.2} | {:+.3} | {:+.3} | {:+.3} |",
            s[k] / s[0],
            100.0 * (s[k] / (scale * mean) - 1.0),
            sub[0] / mean,
            sub[split - 1] / mean,
            6.0 * (mean_height - 0.5),
            differences,
            fick
        );
    }
}
