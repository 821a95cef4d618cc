//! `solver`: iterative solution of the transport system `g = E + K g` on an abstract
//! [`TransportOperator`]. It knows nothing of grids, cells or directions: the operator may be a
//! sparse form-factor matrix, a hierarchical link set or a discrete-ordinates sweep.

pub mod operator;

pub use operator::{RowAccess, TransportOperator};
