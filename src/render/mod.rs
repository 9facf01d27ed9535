//! The paper's method: surface caps, power coefficients PF_i, gridding, detector chain.

pub mod closed_form;
