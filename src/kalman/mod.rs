//! Kalman-type estimators.

pub mod linear;
