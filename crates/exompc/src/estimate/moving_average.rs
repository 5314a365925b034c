//! The moving-average filter of the most recent samples (paper §4.1, MODEL.md §5): the
//! simulated sensors' filter and the runtime loop's.

use alloc::{vec, vec::Vec};
use nalgebra::SVector;

/// Mean of the `window` most recent samples (fewer at start-up), allocation-free after `new`.
#[derive(Clone, Debug)]
pub struct MovingAverage<const N: usize> {
    buf: Vec<SVector<f64, N>>,
    next: usize,
    len: usize,
}

impl<const N: usize> MovingAverage<N> {
    /// A filter over `window ≥ 1` samples.
    pub fn new(window: usize) -> Self {
        MovingAverage {
            buf: vec![SVector::zeros(); window.max(1)],
            next: 0,
            len: 0,
        }
    }

    /// Push a sample and return the current mean.
    pub fn push(&mut self, x: SVector<f64, N>) -> SVector<f64, N> {
        let w = self.buf.len();
        self.buf[self.next] = x;
        self.next = (self.next + 1) % w;
        self.len = (self.len + 1).min(w);
        self.mean()
    }

    /// Mean of the samples held (zero before the first sample).
    pub fn mean(&self) -> SVector<f64, N> {
        if self.len == 0 {
            return SVector::zeros();
        }
        let w = self.buf.len();
        let mut s = SVector::zeros();
        for i in 0..self.len {
            s += self.buf[(self.next + w - 1 - i) % w];
        }
        s / self.len as f64
    }

    /// Forget all samples.
    pub fn reset(&mut self) {
        self.len = 0;
        self.next = 0;
    }
}
