//! Raw structs: mirror the TOML; serde refuses unknown keys and reports missing ones. Values
//! stay `toml::Value` so that validation can name the exact key of a bad value.

use serde::Deserialize;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawScene {
    // Required sections are optional here so that problems are reported in file order
    // (an unknown key in [volume] before a missing [[camera]]).
    pub(crate) volume: Option<toml::Value>,
    pub(crate) medium: Option<toml::Value>,
    pub(crate) light: Option<toml::Value>,
    pub(crate) background: Option<toml::Value>,
    pub(crate) ground: Option<toml::Value>,
    pub(crate) solve: Option<toml::Value>,
    pub(crate) render: Option<toml::Value>,
    pub(crate) camera: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawVolume {
    pub(crate) file: Option<toml::Value>,
    pub(crate) generator: Option<toml::Value>,
    pub(crate) dims: Option<toml::Value>,
    pub(crate) sigma_t_scale: Option<toml::Value>,
    pub(crate) sigma_t: Option<toml::Value>,
    pub(crate) cell_size: Option<toml::Value>,
    pub(crate) interpolation: Option<toml::Value>,
    pub(crate) grid: Option<toml::Value>,
    pub(crate) coordinates: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawMedium {
    pub(crate) albedo: toml::Value,
    pub(crate) phase: Option<toml::Value>,
    pub(crate) emission: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawBackground {
    pub(crate) radiance: toml::Value,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawGround {
    pub(crate) height: Option<toml::Value>,
    pub(crate) albedo: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawSolve {
    pub(crate) method: Option<toml::Value>,
    pub(crate) bins: Option<toml::Value>,
    pub(crate) iteration: Option<toml::Value>,
    pub(crate) tolerance: Option<toml::Value>,
    pub(crate) max_iterations: Option<toml::Value>,
    pub(crate) transport_refinement: Option<toml::Value>,
    pub(crate) forward_peak_cone: Option<toml::Value>,
    pub(crate) photons: Option<toml::Value>,
    pub(crate) transport_scale: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawRender {
    pub(crate) model: Option<toml::Value>,
    pub(crate) exposure: Option<toml::Value>,
    pub(crate) spp: Option<toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RawCamera {
    pub(crate) name: toml::Value,
    pub(crate) eye: toml::Value,
    pub(crate) target: toml::Value,
    pub(crate) up: toml::Value,
    pub(crate) projection: Option<toml::Value>,
    pub(crate) fov_y: Option<toml::Value>,
    pub(crate) ortho_height: Option<toml::Value>,
    pub(crate) width: toml::Value,
    pub(crate) height: toml::Value,
}
