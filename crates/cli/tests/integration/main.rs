//! Integration tests: one binary, driving the real `svbrdf` executable.

mod bad_input;
mod synth;
mod util;
