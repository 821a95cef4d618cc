//! `medium`: everything volrad knows about the participating medium itself, and nothing
//! about how light transport is solved.
//!
//! The core types:
//! - [`Grid`]: the `nx × ny × nz` lattice of cubic cells, x-fastest flat indexing
//!   (`i + nx * (j + ny * k)`), world space `[0, n h]` per axis.
//! - [`Medium`]: a grid with per-cell optical properties ([`ChannelMedium`]: σt, albedo,
//!   emission; one channel for grey scenes, three for RGB) and a [`PhaseFunction`].
//! - [`Light`]: directional, point and spot lights; [`light_pass`] propagates them through
//!   the grid (the first pass of Kajiya & Von Herzen), which is the source term `E` of
//!   every multiple-scattering solve. [`Environment`]: light from every direction at
//!   infinity (a uniform sky), with its uncollided radiance inside the grid. [`ground`]: a
//!   Lambertian plane under the volume ([`ground::Ground`]) and the light it reflects
//!   ([`ground::GroundRadiance`], per patch, as a solve leaves it).
//! - [`coarsening`]: a coarser transport grid over the data grid ([`coarsening::Coarsening`]:
//!   the medium and light pass carried to blocks of `s³` cells), where large volumes solve
//!   their multiple scattering.
//! - [`traversal`]: exact 3D-DDA traversal of a ray through the grid (Amanatides & Woo),
//!   the basis of every per-cell analytic integral in volrad.
//! - [`atomic_file`]: the one atomic file writer (temp file beside the target, sync, rename)
//!   that every file volrad writes goes through, so no half-written file is ever left.
//! - [`regular_file`]: the one way volrad opens a file a user named (volume, scene,
//!   solution): FIFOs, devices and directories are refused, naming what they are.
//!
//! ```
//! use medium::{Grid, traversal::Ray};
//! use glam::DVec3;
//! let grid = Grid::new([4, 4, 4], 1.0).unwrap();
//! let ray = Ray::new(DVec3::new(-1.0, 0.5, 0.5), DVec3::X);
//! let cells: Vec<usize> = grid.traverse(&ray, 0.0, f64::INFINITY).map(|s| s.cell).collect();
//! assert_eq!(cells, vec![0, 1, 2, 3]);
//! ```

pub mod atomic_file;
pub mod blackbody;
pub mod coarsening;
pub mod emitter_pass;
pub mod environment;
pub mod environment_map;
pub mod error;
pub mod fma;
pub mod generators;
pub mod grid;
pub mod ground;
pub mod light;
pub mod light_pass;
pub mod nifti;
pub mod optical;
pub mod phase;
pub mod regular_file;
pub mod resources;
pub mod transfer;
pub mod traversal;
pub mod vdb;
pub mod volume_io;

pub use environment::Environment;
pub use error::MediumError;
pub use grid::Grid;
pub use light::Light;
pub use optical::{CellValues, ChannelMedium, Interpolation, Medium};
pub use phase::PhaseFunction;
