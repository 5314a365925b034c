//! The in-process virtual bus: several endpoints and simulated devices on one classic-CAN bus,
//! with the bus's frame timing (bit rate, stuff bits, arbitration by identifier), injectable
//! frame loss, error frames and controller error states, for tests and hardware-free demos.
//!
//! Time is either the OS clock ([`TimeBase::Real`]) or a simulated clock that moves only when
//! someone waits on the bus ([`TimeBase::Simulated`]: [`VirtualEndpoint::recv`] and
//! sleeping on a [`VirtualClock`] advance it), so a closed loop over the bus runs as fast as it
//! computes and gives the same result every time. Either way the bus is a discrete-event
//! simulation: a frame queued at time `t` starts when the bus is idle (the lowest identifier
//! among the frames waiting wins arbitration), occupies it for [`frame_time`], and reaches
//! every other endpoint and device when it ends. With the real clock the events are processed
//! lazily (whenever an endpoint sends, receives or waits) at their own timestamps, so the
//! result is the same as with the simulated clock.

use crate::bus::{BusCounters, BusError, BusState, CanBus};
use crate::frame::CanFrame;
use crate::timing::{frame_time, Stuffing, ERROR_FRAME_BITS};
use std::collections::VecDeque;
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::{Duration, Instant};

/// Settings of a [`VirtualBus`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VirtualBusSettings {
    /// Bit rate (bit/s); 1 Mbit/s by default.
    pub bitrate: u32,
    /// How stuff bits count in a frame's time on the bus (worst case by default).
    pub stuffing: Stuffing,
    /// Probability that a transmitted frame reaches no receiver (counted in every receiving
    /// endpoint's [`BusCounters::dropped`]); 0..=1.
    pub loss: f64,
    /// Probability that a transmission is destroyed by an error frame (counted in every
    /// endpoint's [`BusCounters::error_frames`]); the sender retransmits it, as a CAN
    /// controller does. 0..=1.
    pub error_frames: f64,
    /// Seed of the fault injection's pseudo-random numbers.
    pub seed: u64,
    /// Frames an endpoint's receive queue holds; more are dropped (an overrun).
    pub queue_capacity: usize,
}

impl Default for VirtualBusSettings {
    fn default() -> Self {
        VirtualBusSettings {
            bitrate: 1_000_000,
            stuffing: Stuffing::WorstCase,
            loss: 0.0,
            error_frames: 0.0,
            seed: 1,
            queue_capacity: 1024,
        }
    }
}

/// The clock of a [`VirtualBus`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimeBase {
    /// The OS monotonic clock; epoch when the bus is made.
    Real,
    /// A simulated clock starting at 0 that moves only when an endpoint waits in
    /// [`VirtualEndpoint::recv`] or a [`VirtualClock`] sleeps.
    Simulated,
}

/// Frames a [`VirtualNode`] sends in answer to a frame or a wake-up.
#[derive(Debug, Default)]
pub struct NodeTx {
    frames: Vec<(Duration, CanFrame)>,
}

impl NodeTx {
    /// Queue `frame` for sending at bus time `at` (not earlier than the current event).
    pub fn send_at(&mut self, at: Duration, frame: CanFrame) {
        self.frames.push((at, frame));
    }
}

/// A device simulated on a [`VirtualBus`] (a motor, a drive, a sensor node). The bus calls it
/// at the bus time of each event, with its own lock held: a node must not call back into the
/// bus.
pub trait VirtualNode: Send {
    /// A frame from another endpoint or node finished on the bus at `now`.
    fn on_frame(&mut self, now: Duration, frame: &CanFrame, tx: &mut NodeTx);

    /// When the node next wants [`VirtualNode::on_wakeup`] (a periodic sample, a heartbeat, a
    /// plant step); `None`: never. After a wake-up at `t` it must return a time after `t`.
    fn next_wakeup(&self) -> Option<Duration> {
        None
    }

    /// The wake-up asked for by [`VirtualNode::next_wakeup`], at bus time `now`.
    fn on_wakeup(&mut self, _now: Duration, _tx: &mut NodeTx) {}
}

/// Time the bus was busy (frames and error frames) since it was made.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BusLoad {
    /// Bus time elapsed.
    pub elapsed: Duration,
    /// Time the bus carried frames or error frames.
    pub busy: Duration,
    /// Frames transmitted (delivered or lost).
    pub frames: u64,
    /// Transmissions destroyed by an error frame.
    pub error_frames: u64,
}

impl BusLoad {
    /// Busy time over elapsed time (0..=1).
    pub fn fraction(&self) -> f64 {
        if self.elapsed.is_zero() {
            0.0
        } else {
            self.busy.as_secs_f64() / self.elapsed.as_secs_f64()
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Source {
    Endpoint(usize),
    Node(usize),
}

#[derive(Clone, Copy, Debug)]
struct Pending {
    ready: Duration,
    seq: u64,
    frame: CanFrame,
    from: Source,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Outcome {
    Deliver,
    Lost,
    Error,
}

struct Endpoint {
    queue: VecDeque<CanFrame>,
    counters: BusCounters,
    state: BusState,
    open: bool,
}

struct Engine {
    s: VirtualBusSettings,
    epoch: Option<Instant>,
    cursor: Duration,
    pending: Vec<Pending>,
    in_flight: Option<(Duration, Pending, Outcome)>,
    bus_free: Duration,
    endpoints: Vec<Endpoint>,
    nodes: Vec<Arc<Mutex<dyn VirtualNode>>>,
    rng: fastrand::Rng,
    seq: u64,
    load: BusLoad,
    tx: NodeTx,
}

/// Arbitration key: the 11-bit base identifier first, then standard before extended (IDE
/// recessive), then the extension bits.
fn arbitration_key(f: &CanFrame) -> (u32, u8, u32) {
    let id = f.id();
    if id.is_extended() {
        (id.raw() >> 18, 1, id.raw() & 0x3FFFF)
    } else {
        (id.raw(), 0, 0)
    }
}

impl Engine {
    fn real_now(&self) -> Option<Duration> {
        self.epoch.map(|e| e.elapsed())
    }

    /// The time of the next event (a transmission ending or starting, a node wake-up).
    fn next_event(&self) -> Option<Duration> {
        let tx = match &self.in_flight {
            Some((end, _, _)) => Some(*end),
            None => self
                .pending
                .iter()
                .map(|p| p.ready)
                .min()
                .map(|r| r.max(self.bus_free)),
        };
        let node = self.next_wakeup().map(|(_, t)| t);
        match (tx, node) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    fn next_wakeup(&self) -> Option<(usize, Duration)> {
        let mut best: Option<(usize, Duration)> = None;
        for (i, n) in self.nodes.iter().enumerate() {
            let w = n.lock().unwrap_or_else(|e| e.into_inner()).next_wakeup();
            if let Some(w) = w {
                if best.is_none_or(|(_, b)| w < b) {
                    best = Some((i, w));
                }
            }
        }
        best
    }

    fn queue(&mut self, ready: Duration, frame: CanFrame, from: Source) {
        self.seq += 1;
        self.pending.push(Pending {
            ready,
            seq: self.seq,
            frame,
            from,
        });
    }

    fn flush_node_tx(&mut self, from: usize, now: Duration) {
        let mut tx = std::mem::take(&mut self.tx);
        for (at, f) in tx.frames.drain(..) {
            self.queue(at.max(now), f, Source::Node(from));
        }
        self.tx = tx;
    }

    /// Process every event up to `t`; with `stop_for = Some(e)`, stop right after a delivery
    /// that queued a frame for endpoint `e`. Returns the time reached.
    fn advance(&mut self, t: Duration, stop_for: Option<usize>) -> Duration {
        loop {
            if let Some(e) = stop_for {
                if !self.endpoints[e].queue.is_empty() {
                    return self.cursor;
                }
            }
            if self.in_flight.is_none() && !self.pending.is_empty() {
                let ready = self.pending.iter().map(|p| p.ready).min().unwrap_or(t);
                let start = ready.max(self.bus_free);
                if start <= t {
                    // Arbitration among the frames waiting when the bus becomes idle.
                    let mut idx = 0;
                    let mut key = None;
                    for (i, p) in self.pending.iter().enumerate() {
                        if p.ready <= start {
                            let k = (arbitration_key(&p.frame), p.seq);
                            if key.is_none_or(|b| k < b) {
                                key = Some(k);
                                idx = i;
                            }
                        }
                    }
                    let p = self.pending.swap_remove(idx);
                    let mut dur = frame_time(&p.frame, self.s.bitrate, self.s.stuffing);
                    let outcome =
                        if self.s.error_frames > 0.0 && self.rng.f64() < self.s.error_frames {
                            dur += Duration::from_nanos(
                                u64::from(ERROR_FRAME_BITS) * 1_000_000_000
                                    / u64::from(self.s.bitrate.max(1)),
                            );
                            Outcome::Error
                        } else if self.s.loss > 0.0 && self.rng.f64() < self.s.loss {
                            Outcome::Lost
                        } else {
                            Outcome::Deliver
                        };
                    self.load.busy += dur;
                    self.in_flight = Some((start + dur, p, outcome));
                    continue;
                }
            }
            let tx_end = self.in_flight.as_ref().map(|(end, _, _)| *end);
            let wake = self.next_wakeup();
            let tx_first = match (tx_end, wake) {
                (Some(a), Some((_, b))) => a <= b,
                (Some(_), None) => true,
                _ => false,
            };
            if tx_first {
                let end = tx_end.unwrap_or(t);
                if end > t {
                    break;
                }
                self.cursor = self.cursor.max(end);
                self.bus_free = end;
                if let Some((_, p, outcome)) = self.in_flight.take() {
                    self.finish(end, p, outcome);
                }
            } else if let Some((i, w)) = wake {
                if w > t {
                    break;
                }
                self.cursor = self.cursor.max(w);
                let node = self.nodes[i].clone();
                node.lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .on_wakeup(w, &mut self.tx);
                self.flush_node_tx(i, w);
            } else {
                break;
            }
        }
        self.cursor = self.cursor.max(t);
        self.cursor
    }

    fn finish(&mut self, end: Duration, p: Pending, outcome: Outcome) {
        match outcome {
            Outcome::Error => {
                self.load.error_frames += 1;
                for e in &mut self.endpoints {
                    e.counters.error_frames += 1;
                }
                // Automatic retransmission.
                self.pending.push(Pending { ready: end, ..p });
            }
            Outcome::Lost => {
                self.load.frames += 1;
                for (i, e) in self.endpoints.iter_mut().enumerate() {
                    if e.open && p.from != Source::Endpoint(i) {
                        e.counters.dropped += 1;
                    }
                }
            }
            Outcome::Deliver => {
                self.load.frames += 1;
                let cap = self.s.queue_capacity;
                for (i, e) in self.endpoints.iter_mut().enumerate() {
                    if !e.open || p.from == Source::Endpoint(i) || e.state == BusState::BusOff {
                        continue;
                    }
                    if e.queue.len() >= cap {
                        e.counters.dropped += 1;
                    } else {
                        e.queue.push_back(p.frame);
                        e.counters.received += 1;
                    }
                }
                for i in 0..self.nodes.len() {
                    if p.from == Source::Node(i) {
                        continue;
                    }
                    let node = self.nodes[i].clone();
                    node.lock().unwrap_or_else(|e| e.into_inner()).on_frame(
                        end,
                        &p.frame,
                        &mut self.tx,
                    );
                    self.flush_node_tx(i, end);
                }
            }
        }
    }

    fn now(&self) -> Duration {
        self.real_now().unwrap_or(self.cursor).max(self.cursor)
    }
}

struct Shared {
    engine: Mutex<Engine>,
    cond: Condvar,
}

impl Shared {
    fn lock(&self) -> MutexGuard<'_, Engine> {
        self.engine.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// One classic-CAN bus in this process: [`VirtualEndpoint`]s (each a [`CanBus`]) and
/// [`VirtualNode`]s (simulated devices) attached to it. Cloning gives another handle to the
/// same bus.
#[derive(Clone)]
pub struct VirtualBus {
    shared: Arc<Shared>,
}

impl VirtualBus {
    /// A bus with `settings` on the clock `time`.
    pub fn new(settings: VirtualBusSettings, time: TimeBase) -> Self {
        let engine = Engine {
            s: settings,
            epoch: (time == TimeBase::Real).then(Instant::now),
            cursor: Duration::ZERO,
            pending: Vec::new(),
            in_flight: None,
            bus_free: Duration::ZERO,
            endpoints: Vec::new(),
            nodes: Vec::new(),
            rng: fastrand::Rng::with_seed(settings.seed),
            seq: 0,
            load: BusLoad::default(),
            tx: NodeTx::default(),
        };
        VirtualBus {
            shared: Arc::new(Shared {
                engine: Mutex::new(engine),
                cond: Condvar::new(),
            }),
        }
    }

    /// A new endpoint on the bus (it receives the frames finished from now on).
    pub fn endpoint(&self) -> VirtualEndpoint {
        let mut g = self.shared.lock();
        g.endpoints.push(Endpoint {
            queue: VecDeque::new(),
            counters: BusCounters::default(),
            state: BusState::ErrorActive,
            open: true,
        });
        VirtualEndpoint {
            bus: self.clone(),
            index: g.endpoints.len() - 1,
        }
    }

    /// Attach a simulated device; the caller may keep its own handle to inspect it (never
    /// while calling into the bus).
    pub fn attach(&self, node: Arc<Mutex<dyn VirtualNode>>) {
        self.shared.lock().nodes.push(node);
        self.shared.cond.notify_all();
    }

    /// Put endpoint `index` (see [`VirtualEndpoint::index`]) into an error state, as its
    /// controller would after errors (a test's fault injection): error-passive keeps it
    /// working, bus-off makes its sends fail with [`BusError::BusOff`] and it receives nothing.
    pub fn set_state(&self, index: usize, state: BusState) {
        if let Some(e) = self.shared.lock().endpoints.get_mut(index) {
            e.state = state;
        }
        self.shared.cond.notify_all();
    }

    /// Bus time now.
    pub fn now(&self) -> Duration {
        self.shared.lock().now()
    }

    /// Process every event up to bus time `t` (with the simulated clock, moving it to `t`).
    pub fn advance_to(&self, t: Duration) {
        let mut g = self.shared.lock();
        let t = match g.real_now() {
            Some(now) => now.min(t),
            None => t,
        };
        g.advance(t, None);
        drop(g);
        self.shared.cond.notify_all();
    }

    /// Bus busy time and frames so far (events processed up to now).
    pub fn load(&self) -> BusLoad {
        let mut g = self.shared.lock();
        let now = g.now();
        g.advance(now, None);
        BusLoad {
            elapsed: g.cursor,
            ..g.load
        }
    }

    /// A [`Clock`](exompc::runtime::Clock) on the bus's time, for a loop that runs over the
    /// bus (with the simulated clock, sleeping moves bus time).
    pub fn clock(&self) -> VirtualClock {
        VirtualClock { bus: self.clone() }
    }
}

/// One endpoint of a [`VirtualBus`]: a [`CanBus`].
pub struct VirtualEndpoint {
    bus: VirtualBus,
    index: usize,
}

impl VirtualEndpoint {
    /// This endpoint's index on its bus (for [`VirtualBus::set_state`]).
    pub fn index(&self) -> usize {
        self.index
    }

    /// The bus it is on.
    pub fn bus(&self) -> &VirtualBus {
        &self.bus
    }
}

impl CanBus for VirtualEndpoint {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let sh = &self.bus.shared;
        let mut g = sh.lock();
        let now = g.now();
        g.advance(now, None);
        if g.endpoints[self.index].state == BusState::BusOff {
            g.endpoints[self.index].counters.send_errors += 1;
            return Err(BusError::BusOff);
        }
        g.queue(now, *frame, Source::Endpoint(self.index));
        g.endpoints[self.index].counters.sent += 1;
        drop(g);
        sh.cond.notify_all();
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let sh = &self.bus.shared;
        let mut g = sh.lock();
        let start = g.now();
        let deadline = start + timeout;
        loop {
            let now = g.now();
            match g.real_now() {
                Some(real) => {
                    g.advance(real, None);
                }
                None => {
                    g.advance(deadline, Some(self.index));
                }
            }
            let ep = &mut g.endpoints[self.index];
            if ep.state == BusState::BusOff {
                return Err(BusError::BusOff);
            }
            if let Some(f) = ep.queue.pop_front() {
                return Ok(Some(f));
            }
            if g.real_now().is_none() || now >= deadline {
                return Ok(None);
            }
            let wake = g.next_event().unwrap_or(deadline).min(deadline);
            let wait = wake.saturating_sub(now).max(Duration::from_micros(1));
            g = sh
                .cond
                .wait_timeout(g, wait)
                .unwrap_or_else(|e| e.into_inner())
                .0;
        }
    }

    fn counters(&self) -> BusCounters {
        self.bus.shared.lock().endpoints[self.index].counters
    }

    fn state(&self) -> BusState {
        self.bus.shared.lock().endpoints[self.index].state
    }
}

impl Drop for VirtualEndpoint {
    fn drop(&mut self) {
        let mut g = self.bus.shared.lock();
        let ep = &mut g.endpoints[self.index];
        ep.open = false;
        ep.queue.clear();
    }
}

/// The clock of a [`VirtualBus`] as an [`exompc::runtime::Clock`]: with the simulated clock,
/// sleeping processes the bus's events up to the wake-up time; with the real clock it sleeps.
#[derive(Clone)]
pub struct VirtualClock {
    bus: VirtualBus,
}

impl exompc::runtime::Clock for VirtualClock {
    fn now(&self) -> Duration {
        self.bus.now()
    }

    fn sleep_until(&mut self, t: Duration) {
        let real = self.bus.shared.lock().epoch;
        match real {
            Some(epoch) => {
                let target = epoch + t;
                let now = Instant::now();
                if target > now {
                    std::thread::sleep(target - now);
                }
                self.bus.advance_to(t);
            }
            None => self.bus.advance_to(t),
        }
    }
}
