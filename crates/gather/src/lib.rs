//! `gather`: the view-dependent pass — cameras, ray integration with front-to-back
//! compositing through the grid, and image files.
//!
//! - [`Camera`] ([`camera`]): perspective and orthographic, built from a scene's
//!   [`CameraSpec`].
//! - [`render`](render::render) / [`render_image`] ([`render`]): Max's optical models along
//!   exact per-cell segments (`nearest`) or fixed steps (`trilinear`), parallel over tiles.
//! - [`InScattering`] ([`scattering`]): the scattered source `Q_s`, plugged in from outside.
//! - [`Image`] ([`image_io`]): PNG, PFM and EXR output by extension; [`read_pfm`].

// `!(x > 0.0)` is deliberate in validation: it refuses NaN as well.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod camera;
mod empty_space;
pub mod error;
mod exponential;
pub mod exposure;
mod extinction_bound;
pub mod image_io;
pub mod light_depth;
pub mod render;
pub mod scattering;
pub mod single_scatter;

pub use camera::{Camera, CameraProjection, CameraSpec, Projection};
pub use error::GatherError;
pub use exposure::auto_exposure;
pub use image_io::{read_pfm, Image, ImageFormat, PngCompression, ToneMap};
pub use render::{
    render, render_image, render_image_indexed, render_indexed, ImageChannel, OpticalModel,
    RayIntegrator, RenderIndex, RenderOptions, RenderSettings, Trilinear, MAX_SPP,
    OPTICAL_MODEL_NAMES,
};
pub use scattering::{
    each_step, segment_weight, InScattering, RayCarry, ScatteringSum, StepSample, UniformSource,
    ViewSegment,
};
