//! Visibility scheduler (not yet implemented; planned after the out-of-core path).
