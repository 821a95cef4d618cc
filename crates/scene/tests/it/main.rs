//! The `scene` crate's integration tests: one test binary, a module per area.

mod ordinates_scene;
mod scene_parse;
mod scene_samples;
mod vdb_scene;
