//! Regression tests: one named test per defect fixed, each commented with what broke.
//! Grouped by area in `tests/regressions/`; the test name says the defect.

#[allow(unused)]
mod common;

#[path = "regressions/geo.rs"]
mod geo;
#[path = "regressions/mesh_input.rs"]
mod mesh_input;
#[path = "regressions/messages_outputs.rs"]
mod messages_outputs;
#[path = "regressions/output_dir.rs"]
mod output_dir;
#[path = "regressions/point_input.rs"]
mod point_input;
