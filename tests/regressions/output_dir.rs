//! Regressions: output_dir.
