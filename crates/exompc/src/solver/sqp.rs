//! SQP (placeholder).
#![allow(missing_docs)]
pub trait LeastSquares {}
pub struct Constraints;
pub struct Sqp;
pub struct SqpInfo;
pub struct SqpSettings;
pub enum SqpStatus {}
