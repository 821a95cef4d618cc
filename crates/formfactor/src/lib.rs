//! `formfactor`: builds the linear transport operators (zonal form factors, discrete ordinates).

pub mod ordinates;
