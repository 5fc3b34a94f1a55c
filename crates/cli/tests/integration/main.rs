//! Integration tests: one binary, driving the real `svbrdf` executable.
#![allow(clippy::unwrap_used, clippy::needless_range_loop)]

mod align;
mod bad_input;
mod consistency;
mod eval;
mod exposure;
mod fit;
mod formats;
mod hostile;
mod photos;
mod run;
mod synth;
mod ties;
mod two_camera;
mod util;
