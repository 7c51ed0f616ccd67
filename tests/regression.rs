//! Regression tests: one named test per defect fixed, each commented with what broke.
//! Grouped by area in `tests/regression/`; the test name says the defect.

mod file_outputs;
mod geo;
mod mesh_input;
mod messages_outputs;
mod output_dir;
mod point_input;
mod strips;
