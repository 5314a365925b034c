//! estimate (under construction).
