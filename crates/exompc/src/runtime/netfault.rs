//! Network faults injected into a stream of frames (one direction of a link): packet loss,
//! delay spikes, duplication, reordering and a disconnection, deterministic for a seed.

use serde::Serialize;

/// What to inject. Times are link times (s since the run start).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct NetFaultSettings {
    /// Probability of dropping each frame (0-1).
    pub loss: f64,
    /// Probability of sending each frame twice (0-1).
    pub duplicate: f64,
    /// Probability of holding a frame back and releasing it just after the next one (0-1).
    pub reorder: f64,
    /// Extra delay of the frames of a delay spike (s).
    pub delay_s: f64,
    /// A delay spike starts every this many seconds (0: no spikes).
    pub delay_every_s: f64,
    /// Length of each delay spike (s): frames submitted within it are delayed.
    pub delay_width_s: f64,
    /// Start of the disconnection (s), `None` for none.
    pub disconnect_at_s: Option<f64>,
    /// Length of the disconnection (s): every frame is dropped.
    pub disconnect_s: f64,
    /// Seed of the fault draws.
    pub seed: u64,
}

impl NetFaultSettings {
    /// True when nothing is injected.
    pub fn is_none(&self) -> bool {
        self.loss <= 0.0
            && self.duplicate <= 0.0
            && self.reorder <= 0.0
            && (self.delay_every_s <= 0.0 || self.delay_s <= 0.0)
            && self.disconnect_at_s.is_none()
    }

    /// Check ranges; the error names the setting and its allowed range.
    pub fn validate(&self) -> Result<(), String> {
        for (name, v) in [
            ("loss", self.loss),
            ("duplicate", self.duplicate),
            ("reorder", self.reorder),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("{name} = {v}: allowed 0 to 1"));
            }
        }
        for (name, v) in [
            ("delay", self.delay_s),
            ("delay_every", self.delay_every_s),
            ("delay_width", self.delay_width_s),
            ("disconnect_for", self.disconnect_s),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} = {v}: allowed finite, ≥ 0"));
            }
        }
        if let Some(a) = self.disconnect_at_s {
            if !(a.is_finite() && a >= 0.0) {
                return Err(format!("disconnect_at = {a}: allowed finite, ≥ 0"));
            }
        }
        Ok(())
    }
}

/// Frames affected, per fault.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct NetFaultCounts {
    /// Frames submitted.
    pub submitted: u64,
    /// Frames dropped by random loss.
    pub lost: u64,
    /// Frames dropped during the disconnection.
    pub disconnected: u64,
    /// Frames delayed by a spike.
    pub delayed: u64,
    /// Frames sent twice.
    pub duplicated: u64,
    /// Frames held back behind the next one.
    pub reordered: u64,
}

/// SplitMix64: a small deterministic generator for the fault draws (not cryptographic).
#[derive(Clone, Copy, Debug)]
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// One direction of a faulty link: frames go in with [`NetFaults::submit`] and come out, when
/// due, from [`NetFaults::pop_due`]. Each frame carries a tag `A` (e.g. its sender's address:
/// [`NetFaults::submit_tagged`], [`NetFaults::pop_due_tagged`]).
#[derive(Clone, Debug)]
pub struct NetFaults<A: Copy = ()> {
    s: NetFaultSettings,
    rng: SplitMix,
    queue: Vec<(f64, u64, A, Vec<u8>)>,
    held: Option<(A, Vec<u8>)>,
    order: u64,
    counts: NetFaultCounts,
}

impl NetFaults<()> {
    /// A link direction with faults `s` (untagged frames).
    pub fn new(s: NetFaultSettings) -> Self {
        Self::tagged(s)
    }

    /// Submit a frame at link time `now`.
    pub fn submit(&mut self, now: f64, bytes: &[u8]) {
        self.submit_tagged(now, (), bytes);
    }

    /// The next frame due at `now` (in submission order among those due), if any.
    pub fn pop_due(&mut self, now: f64) -> Option<Vec<u8>> {
        self.pop_due_tagged(now).map(|x| x.1)
    }
}

impl<A: Copy> NetFaults<A> {
    /// A link direction with faults `s` whose frames carry a tag of type `A`.
    pub fn tagged(s: NetFaultSettings) -> Self {
        NetFaults {
            rng: SplitMix(s.seed ^ 0x005E_ED0F_FA17),
            s,
            queue: Vec::with_capacity(16),
            held: None,
            order: 0,
            counts: NetFaultCounts::default(),
        }
    }

    /// Counters so far.
    pub fn counts(&self) -> &NetFaultCounts {
        &self.counts
    }

    /// True during the disconnection.
    pub fn disconnected(&self, now: f64) -> bool {
        self.s
            .disconnect_at_s
            .is_some_and(|a| now >= a && now < a + self.s.disconnect_s)
    }

    fn in_spike(&self, now: f64) -> bool {
        self.s.delay_every_s > 0.0
            && self.s.delay_s > 0.0
            && now >= self.s.delay_every_s
            && now % self.s.delay_every_s < self.s.delay_width_s
    }

    fn enqueue(&mut self, at: f64, tag: A, bytes: Vec<u8>) {
        self.order += 1;
        self.queue.push((at, self.order, tag, bytes));
    }

    /// Submit a frame tagged `tag` at link time `now`.
    pub fn submit_tagged(&mut self, now: f64, tag: A, bytes: &[u8]) {
        self.counts.submitted += 1;
        if self.disconnected(now) {
            self.counts.disconnected += 1;
            return;
        }
        // Draw every decision for every frame so one fault's setting does not shift the
        // others' draws.
        let (l, d, r) = (
            self.rng.next_f64(),
            self.rng.next_f64(),
            self.rng.next_f64(),
        );
        if l < self.s.loss {
            self.counts.lost += 1;
            return;
        }
        let mut at = now;
        if self.in_spike(now) {
            self.counts.delayed += 1;
            at += self.s.delay_s;
        }
        if r < self.s.reorder && self.held.is_none() {
            self.counts.reordered += 1;
            self.held = Some((tag, bytes.to_vec()));
            return;
        }
        self.enqueue(at, tag, bytes.to_vec());
        if d < self.s.duplicate {
            self.counts.duplicated += 1;
            self.enqueue(at, tag, bytes.to_vec());
        }
        if let Some((ht, h)) = self.held.take() {
            self.enqueue(at, ht, h);
        }
    }

    /// The next frame due at `now` (in submission order among those due) with its tag.
    pub fn pop_due_tagged(&mut self, now: f64) -> Option<(A, Vec<u8>)> {
        let i = self
            .queue
            .iter()
            .enumerate()
            .filter(|(_, q)| q.0 <= now)
            .min_by_key(|(_, q)| q.1)
            .map(|(i, _)| i)?;
        let q = self.queue.swap_remove(i);
        Some((q.2, q.3))
    }

    /// Time the next queued frame is due, if any.
    pub fn next_due(&self) -> Option<f64> {
        self.queue.iter().map(|q| q.0).min_by(f64::total_cmp)
    }
}
