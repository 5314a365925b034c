//! Heartbeat (CiA 301 §7.2.8.3.2.2): a producer sends its NMT state on 0x700 + node id every
//! producer period (object 0x1017); a consumer (object 0x1016) declares a node lost when no
//! heartbeat arrived within its consumer time.

use super::nmt::NmtState;
use super::{cob, frame, std_id, NodeId};
use crate::CanFrame;
use std::time::Duration;

/// The boot-up message of `node` (a heartbeat carrying state 0).
pub fn boot_up(node: NodeId) -> CanFrame {
    frame(node.cob(cob::HEARTBEAT), &[NmtState::BootUp.code()])
}

/// Decode a heartbeat (or boot-up) frame: the sender and its state.
pub fn decode(f: &CanFrame) -> Option<(NodeId, NmtState)> {
    let id = std_id(f)?;
    if !(cob::HEARTBEAT + 1..=cob::HEARTBEAT + 127).contains(&id) || f.is_remote() || f.len() != 1 {
        return None;
    }
    let node = NodeId::new(u32::from(id - cob::HEARTBEAT)).ok()?;
    Some((node, NmtState::from_code(f.data()[0])?))
}

/// Sends a node's heartbeat every period (a zero period disables it, as 0x1017 = 0 does).
#[derive(Clone, Debug)]
pub struct HeartbeatProducer {
    node: NodeId,
    period: Duration,
    next: Option<Duration>,
}

impl HeartbeatProducer {
    /// A producer for `node` with the given period; the first heartbeat is due at once.
    pub fn new(node: NodeId, period: Duration) -> Self {
        Self {
            node,
            period,
            next: None,
        }
    }

    /// The producer period.
    pub fn period(&self) -> Duration {
        self.period
    }

    /// Change the period (a write to 0x1017); the next heartbeat is due at once.
    pub fn set_period(&mut self, period: Duration) {
        self.period = period;
        self.next = None;
    }

    /// The heartbeat to send at `now`, if one is due.
    pub fn poll(&mut self, now: Duration, state: NmtState) -> Option<CanFrame> {
        if self.period.is_zero() {
            return None;
        }
        match self.next {
            Some(next) if now < next => None,
            _ => {
                // Keep the cadence; after a long pause restart it from now.
                let base = self.next.filter(|n| now < *n + self.period).unwrap_or(now);
                self.next = Some(base + self.period);
                Some(frame(self.node.cob(cob::HEARTBEAT), &[state.code()]))
            }
        }
    }
}

/// What the consumer knows of one monitored node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Monitored {
    /// No heartbeat yet (the timer starts with the first one, as CiA 301 specifies).
    Waiting,
    /// Heard within the consumer time; its last reported state.
    Alive(NmtState),
    /// No heartbeat within the consumer time since the last one: the node is lost.
    TimedOut,
}

/// A heartbeat timeout: the node and how long it had been silent when detected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeartbeatTimeout {
    /// The silent node.
    pub node: NodeId,
    /// Time since its last heartbeat.
    pub silent_for: Duration,
}

#[derive(Clone, Copy, Debug)]
struct Entry {
    node: NodeId,
    timeout: Duration,
    last: Option<Duration>,
    state: Monitored,
}

/// Monitors the heartbeats of a set of nodes.
#[derive(Clone, Debug, Default)]
pub struct HeartbeatConsumer {
    entries: Vec<Entry>,
}

impl HeartbeatConsumer {
    /// An empty consumer.
    pub fn new() -> Self {
        Self::default()
    }

    /// Monitor `node` with the given consumer time (replaces an earlier entry for it).
    pub fn watch(&mut self, node: NodeId, timeout: Duration) {
        self.entries.retain(|e| e.node != node);
        self.entries.push(Entry {
            node,
            timeout,
            last: None,
            state: Monitored::Waiting,
        });
    }

    /// Feed a received frame; returns the sender and state when it was a heartbeat of a
    /// monitored node.
    pub fn on_frame(&mut self, f: &CanFrame, now: Duration) -> Option<(NodeId, NmtState)> {
        let (node, state) = decode(f)?;
        let e = self.entries.iter_mut().find(|e| e.node == node)?;
        e.last = Some(now);
        e.state = Monitored::Alive(state);
        Some((node, state))
    }

    /// Check the timers at `now`; the first node found newly timed out. A timed-out node
    /// stays timed out until its next heartbeat.
    pub fn check(&mut self, now: Duration) -> Option<HeartbeatTimeout> {
        for e in &mut self.entries {
            if let (Some(last), Monitored::Alive(_)) = (e.last, e.state) {
                let silent = now.saturating_sub(last);
                if silent > e.timeout {
                    e.state = Monitored::TimedOut;
                    return Some(HeartbeatTimeout {
                        node: e.node,
                        silent_for: silent,
                    });
                }
            }
        }
        None
    }

    /// What is known of `node` (`None` when it is not monitored).
    pub fn status(&self, node: NodeId) -> Option<Monitored> {
        self.entries
            .iter()
            .find(|e| e.node == node)
            .map(|e| e.state)
    }

    /// `true` when every monitored node has been heard and none is timed out.
    pub fn all_alive(&self) -> bool {
        self.entries
            .iter()
            .all(|e| matches!(e.state, Monitored::Alive(_)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ms(v: u64) -> Duration {
        Duration::from_millis(v)
    }

    #[test]
    fn producer_keeps_its_period() {
        let n = NodeId::new(9).unwrap();
        let mut p = HeartbeatProducer::new(n, ms(100));
        let f = p.poll(ms(0), NmtState::PreOperational).unwrap();
        assert_eq!(std_id(&f), Some(0x709));
        assert_eq!(f.data(), &[0x7F]);
        assert!(p.poll(ms(99), NmtState::Operational).is_none());
        let f = p.poll(ms(105), NmtState::Operational).unwrap();
        assert_eq!(decode(&f), Some((n, NmtState::Operational)));
        // The cadence is kept (due at 200, not 205).
        assert!(p.poll(ms(199), NmtState::Operational).is_none());
        assert!(p.poll(ms(200), NmtState::Operational).is_some());
        p.set_period(Duration::ZERO);
        assert!(p.poll(ms(1000), NmtState::Operational).is_none());
        assert_eq!(decode(&boot_up(n)), Some((n, NmtState::BootUp)));
    }

    #[test]
    fn consumer_detects_a_silent_node() {
        let a = NodeId::new(1).unwrap();
        let b = NodeId::new(2).unwrap();
        let mut c = HeartbeatConsumer::new();
        c.watch(a, ms(150));
        c.watch(b, ms(150));
        assert!(!c.all_alive());
        assert_eq!(
            c.check(ms(1000)),
            None,
            "no timer before the first heartbeat"
        );
        let hb = |n: NodeId| frame(n.cob(cob::HEARTBEAT), &[0x05]);
        c.on_frame(&hb(a), ms(0));
        c.on_frame(&hb(b), ms(0));
        assert!(c.all_alive());
        c.on_frame(&hb(a), ms(100));
        assert_eq!(c.check(ms(150)), None);
        let t = c.check(ms(151)).unwrap();
        assert_eq!(t.node, b);
        assert_eq!(t.silent_for, ms(151));
        assert_eq!(c.status(b), Some(Monitored::TimedOut));
        assert!(!c.all_alive());
        assert_eq!(c.check(ms(152)), None, "reported once");
        let t = c.check(ms(251)).unwrap();
        assert_eq!(t.node, a);
        c.on_frame(&hb(b), ms(300));
        assert_eq!(c.status(b), Some(Monitored::Alive(NmtState::Operational)));
        // Frames that are not heartbeats of watched nodes are ignored.
        assert_eq!(c.on_frame(&frame(0x703, &[0x05]), ms(300)), None);
        assert_eq!(c.on_frame(&frame(0x181, &[0x05]), ms(300)), None);
    }
}
