//! Regressions: point_input.
