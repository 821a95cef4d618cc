//! `formfactor`: builds the linear transport operators (zonal form factors, discrete ordinates).
//!
//! - [`zonal`]: the exact zonal operator ([`FormFactorMatrix`], sparse CSR) and the source term.
//! - [`hierarchical`]: the clustered zonal operator ([`HierarchicalOperator`]) for real sizes.

pub mod hierarchical;
pub mod ordinates;
pub mod zonal;

pub use hierarchical::{HierarchicalOperator, HierarchicalOptions};
pub use zonal::{
    zonal_source, BuildReport, ExactOptions, FormFactorError, FormFactorMatrix, NearQuadrature,
};
