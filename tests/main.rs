//! Integration tests of `onsager`: one test binary, one module per area.

mod action;
mod baselines;
mod cli;
mod closure;
mod experiment;
mod golden;
mod path;
