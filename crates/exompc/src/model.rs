//! Planar serial chains.
