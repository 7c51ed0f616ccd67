//! Regressions: messages_outputs.
