//! Integration tests of `onsager`: one test binary, one module per area.

mod cli;
