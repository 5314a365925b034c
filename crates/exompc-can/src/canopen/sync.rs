//! The SYNC producer (CiA 301 §7.2.5): an empty frame (or one carrying a 1..=240 counter,
//! object 0x1019) on COB-ID 0x080 every communication cycle period (0x1006), here the control
//! period.

use super::{cob, frame};
use crate::CanFrame;
use std::time::Duration;

/// Emits SYNC at a fixed period.
#[derive(Clone, Debug)]
pub struct SyncProducer {
    period: Duration,
    next: Option<Duration>,
    overflow: u8,
    counter: u8,
}

impl SyncProducer {
    /// A producer with the given period; `overflow` = 0 sends empty SYNCs, 2..=240 adds a
    /// counter running 1..=overflow (0x1019).
    pub fn new(period: Duration, overflow: u8) -> Self {
        Self {
            period,
            next: None,
            overflow: if (2..=240).contains(&overflow) {
                overflow
            } else {
                0
            },
            counter: 0,
        }
    }

    /// The SYNC frame now, regardless of the schedule (the control loop sends one per cycle).
    pub fn emit(&mut self) -> CanFrame {
        if self.overflow == 0 {
            frame(cob::SYNC, &[])
        } else {
            self.counter = if self.counter >= self.overflow {
                1
            } else {
                self.counter + 1
            };
            frame(cob::SYNC, &[self.counter])
        }
    }

    /// The SYNC due at `now`, if any (first at once, then every period on a fixed grid).
    pub fn poll(&mut self, now: Duration) -> Option<CanFrame> {
        if self.period.is_zero() {
            return None;
        }
        match self.next {
            Some(next) if now < next => None,
            _ => {
                let base = self.next.filter(|n| now < *n + self.period).unwrap_or(now);
                self.next = Some(base + self.period);
                Some(self.emit())
            }
        }
    }
}

/// `true` for a SYNC frame.
pub fn is_sync(f: &CanFrame) -> bool {
    super::std_id(f) == Some(cob::SYNC) && !f.is_remote() && f.len() <= 1
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sync_runs_on_a_fixed_grid_with_a_counter() {
        let ms = Duration::from_millis;
        let mut s = SyncProducer::new(ms(10), 0);
        let f = s.poll(ms(0)).unwrap();
        assert!(is_sync(&f) && f.is_empty());
        assert!(s.poll(ms(9)).is_none());
        assert!(s.poll(ms(11)).is_some());
        assert!(s.poll(ms(19)).is_none());
        assert!(s.poll(ms(20)).is_some());
        let mut c = SyncProducer::new(ms(10), 3);
        let counts: Vec<u8> = (0..5).map(|_| c.emit().data()[0]).collect();
        assert_eq!(counts, [1, 2, 3, 1, 2]);
        assert!(!is_sync(&frame(0x081, &[])));
    }
}
