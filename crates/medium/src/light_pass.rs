//! The light pass (Kajiya & Von Herzen's first pass): transmittance from each light to the
//! grid. (Being written.)
