//! The `scene` crate's integration tests: one test binary, a module per area.

mod nifti_scene;
mod ordinates_scene;
mod scene_parse;
mod scene_samples;
mod special_files;
mod vdb_scene;
