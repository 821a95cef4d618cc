//! Solution files: solved source terms plus everything a render needs, so one solve serves
//! many views. The byte layout lives in [`container`] alone.

pub mod container;

pub use container::{write_atomic, Container, ContainerError};
