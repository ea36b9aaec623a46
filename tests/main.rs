//! Integration tests of `onsager`: one test binary, one module per area.

mod action;
mod area;
mod baselines;
mod cli;
mod closure;
mod continuous;
mod estimators;
mod experiment;
mod fuzz;
mod golden;
mod limits;
mod models;
mod path;
mod shard;
mod support;
mod trust;
