//! `formfactor`: builds the linear transport operators (zonal form factors, discrete ordinates).
//!
//! - [`zonal`]: the exact zonal operator ([`FormFactorMatrix`], sparse CSR). Its source term
//!   is the light pass's (`medium::light_pass::LightPass::zonal_source`).
//! - [`hierarchical`]: the clustered zonal operator ([`HierarchicalOperator`]) for real sizes.

pub mod hierarchical;
pub mod ordinates;
pub mod zonal;

pub use hierarchical::{HierarchicalOperator, HierarchicalOptions};
pub use zonal::{BuildReport, ExactOptions, FormFactorError, FormFactorMatrix, NearQuadrature};
