//! `gather`: the view-dependent pass.
