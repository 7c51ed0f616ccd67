//! Regressions: mesh_input.
