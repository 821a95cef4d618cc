//! `Medium::new`, the one check of a medium's optical properties that everything downstream
//! (the light pass, the operators, the renders) relies on instead of checking again.

use medium::{Grid, Medium, PhaseFunction};

/// `Medium::new` of one channel of σt `sigma_t` on `grid` (albedo 0.9, no emission).
fn grey(grid: Grid, sigma_t: Vec<f32>) -> Result<Medium, medium::MediumError> {
    Medium::grey(grid, sigma_t, 0.9, PhaseFunction::Isotropic)
}

#[test]
fn medium_new_refuses_bad_sigma_t() {
    let grid = Grid::new([2, 2, 2], 1.0).unwrap();
    assert!(grey(grid, vec![1.0; 8]).is_ok());
    assert!(grey(grid, vec![0.0; 8]).is_ok());
    // One value short of the grid's cells.
    assert!(grey(grid, vec![1.0; 7]).is_err());
    // Not finite, or negative.
    for bad in [f32::NAN, f32::INFINITY, -1.0] {
        let mut sigma_t = vec![1.0; 8];
        sigma_t[3] = bad;
        assert!(grey(grid, sigma_t).is_err(), "σt = {bad}");
    }
}
