//! The judge's small streaming pieces, allocation-free once made: which SYNC0 pulse a frame
//! was meant for ([`Tracker`]), the usual working counter ([`WkcWatch`]), percentile bands
//! over blocks of frames for the plots ([`BandBlocks`]) and a least-squares line ([`Slope`]).

use crate::run::Band;

/// Recent values a [`Tracker`] takes its typical value from.
const RING: usize = 16;

/// Which SYNC0 pulse a frame was meant for, for a master ecsync does not know: the pulse
/// whose offset from the frame is nearest the typical offset of recent frames (the median of
/// the last [`RING`]). The typical offset is kept in [-cycle, 0): a master that aims its frames
/// just after a pulse is taken to mean the next one.
#[derive(Debug, Clone)]
pub(crate) struct Tracker {
    ring: [f64; RING],
    len: usize,
    at: usize,
    typical: f64,
    calls: u32,
    /// The whole periods the typical offset was moved by to keep it in [-p, 0), taken back:
    /// [`Tracker::unwrapped`].
    turns: f64,
    unwrapped: f64,
}

impl Default for Tracker {
    fn default() -> Self {
        Tracker {
            ring: [0.0; RING],
            len: 0,
            at: 0,
            typical: 0.0,
            calls: 0,
            turns: 0.0,
            unwrapped: 0.0,
        }
    }
}

impl Tracker {
    /// Forgets the frames so far (the grid changed: a new start time, a power cycle).
    pub(crate) fn reset(&mut self) {
        self.len = 0;
        self.at = 0;
    }

    /// Takes `v` (in [-p, 0)) as the typical offset from now on, forgetting the frames so far.
    pub(crate) fn reanchor(&mut self, v: f64, p: f64) {
        let v = if v < -p { v + p } else { v };
        self.turns -= ((v - self.typical) / p).round() * p;
        self.ring[0] = v;
        self.len = 1;
        self.at = 1;
        self.typical = v;
    }

    /// The value [`Tracker::place`] returned last, on one continuous scale: the whole periods
    /// the typical offset was moved by before it was placed taken back. A master drifting over the
    /// grid has its frames placed on a sawtooth (each passes a pulse and is then meant for the
    /// next); unwrapped, they lie on the line it drifts along. Taken from the typical's moves,
    /// not from the steps between frames: a jittery master's frames step by up to a cycle
    /// without drifting.
    pub(crate) fn unwrapped(&self) -> f64 {
        self.unwrapped
    }

    /// The last 4 offsets (the newest included) rise steadily: every step forward, the largest
    /// at most 3 times the smallest. A master drifting over the grid marches so; one whose
    /// frames jitter around their usual instant and are late now and then does not (its step
    /// into lateness is far larger than the steps before).
    pub(crate) fn marching(&self) -> bool {
        if self.len < 4 {
            return false;
        }
        let at = |back: usize| self.ring[(self.at + RING - 1 - back) % RING];
        let steps = [at(0) - at(1), at(1) - at(2), at(2) - at(3)];
        let (lo, hi) = steps.iter().fold((f64::INFINITY, 0.0f64), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
        lo > 0.0 && hi <= 3.0 * lo
    }

    /// `x` in [0, `p`): a time after the last pulse before it, ns. Returns the time after the
    /// pulse the frame was meant for (negative: before it), and takes it into the typical.
    pub(crate) fn place(&mut self, x: f64, p: f64) -> f64 {
        if self.len == 0 {
            self.typical = x - p;
        }
        let c = self.typical;
        let v = x + ((c - x) / p).round() * p;
        self.unwrapped = v + self.turns;
        self.ring[self.at] = v;
        self.at = (self.at + 1) % RING;
        self.len = (self.len + 1).min(RING);
        // The typical offset moves slowly: its median is taken anew every 4th frame once the
        // ring is full (a large network's drives each have one).
        self.calls = self.calls.wrapping_add(1);
        if self.len == RING && !self.calls.is_multiple_of(4) {
            return v;
        }
        let mut s = [0.0f64; RING];
        s[..self.len].copy_from_slice(&self.ring[..self.len]);
        let s = &mut s[..self.len];
        let mid = s.len() / 2;
        let (_, m, _) = s.select_nth_unstable_by(mid, f64::total_cmp);
        let mut t = *m;
        // Kept in [-p, 0): the ring moves with it so the next median is of the same grid.
        let shift = if t >= 0.0 {
            -p
        } else if t < -p {
            p
        } else {
            0.0
        };
        if shift != 0.0 {
            self.turns -= shift;
            t += shift;
            for r in &mut self.ring[..self.len] {
                *r += shift;
            }
        }
        self.typical = t;
        v
    }
}

/// The usual working counter of the frames with process data: the majority value of the run
/// (Boyer-Moore's streaming vote), taken as usual once it has been seen [`WkcWatch::SETTLE`]
/// times in a row.
#[derive(Debug, Clone, Default)]
pub(crate) struct WkcWatch {
    cand: u32,
    votes: u32,
    run: u32,
    pub(crate) usual: Option<u32>,
    /// Frames whose working counter differed from the usual (once known), or was 0.
    pub(crate) changed: u64,
    /// Of those, frames with 0.
    pub(crate) zero: u64,
}

impl WkcWatch {
    const SETTLE: u32 = 8;

    /// One frame's working counter (the sum of its process data datagrams'); whether it is
    /// the usual one.
    pub(crate) fn add(&mut self, w: u32, last: Option<u32>) -> bool {
        if self.votes == 0 {
            self.cand = w;
        }
        if self.cand == w {
            self.votes += 1;
        } else {
            self.votes -= 1;
        }
        self.run = if last == Some(w) { self.run + 1 } else { 1 };
        if self.usual.is_none() && self.run >= Self::SETTLE && w != 0 {
            self.usual = Some(w);
        } else if self.usual.is_some() && self.votes >= 64 && self.cand != 0 {
            // A new majority (the master added a drive, a drive came back for good).
            self.usual = Some(self.cand);
        }
        let ok = w != 0 && self.usual.is_none_or(|u| u == w);
        if !ok {
            self.changed += 1;
            self.zero += u64::from(w == 0);
        }
        ok
    }

    /// The last frame's working counter was `before` and is `after` (a ring's two copies
    /// merged): it is counted as `after` would have been.
    pub(crate) fn amend(&mut self, before: u32, after: u32) {
        let bad = |w: u32| w == 0 || self.usual.is_some_and(|u| u != w);
        if bad(before) && !bad(after) {
            self.changed -= 1;
            self.zero -= u64::from(before == 0);
        }
    }
}

/// Blocks of frames kept.
const BLOCKS_CAP: usize = 1024;

/// Percentile bands of one quantity over blocks of `block` frames. Past [`BLOCKS_CAP`] blocks
/// neighbours are merged (extremes and outer percentiles the wider, medians averaged) and the
/// block doubles: the series stays the same size however long the master runs.
#[derive(Debug, Clone)]
pub(crate) struct BandBlocks {
    block: u64,
    start: u64,
    buf: Vec<f32>,
    out: Vec<Band>,
}

impl BandBlocks {
    pub(crate) fn new(block: u64) -> Self {
        BandBlocks {
            block: block.max(1),
            start: 0,
            buf: Vec::with_capacity(block.max(1) as usize),
            out: Vec::with_capacity(BLOCKS_CAP),
        }
    }

    /// The value of frame `k` (frames in order).
    pub(crate) fn add(&mut self, k: u64, x: f64) {
        if k >= self.start + self.block || self.buf.len() >= self.buf.capacity() {
            self.flush();
            self.start = k / self.block * self.block;
        }
        self.buf.push(x as f32);
    }

    fn flush(&mut self) {
        if let Some(b) = band_of(self.start, &mut self.buf) {
            if self.out.len() == BLOCKS_CAP {
                self.coarsen();
            }
            self.out.push(b);
        }
        self.buf.clear();
    }

    fn coarsen(&mut self) {
        let n = self.out.len() / 2;
        for i in 0..n {
            let (a, b) = (self.out[2 * i], self.out[2 * i + 1]);
            self.out[i] = Band {
                cycle: a.cycle,
                n: a.n + b.n,
                min: a.min.min(b.min),
                p01: a.p01.min(b.p01),
                p50: (a.p50 + b.p50) / 2.0,
                p99: a.p99.max(b.p99),
                max: a.max.max(b.max),
            };
        }
        let odd = self.out.len() % 2 == 1;
        if odd {
            self.out[n] = self.out[self.out.len() - 1];
        }
        self.out.truncate(n + usize::from(odd));
        self.block *= 2;
    }

    /// Frames per block.
    pub(crate) fn block(&self) -> u64 {
        self.block
    }

    /// The bands so far, the open block's included.
    pub(crate) fn bands(&self) -> Vec<Band> {
        let mut v = self.out.clone();
        let mut buf = self.buf.clone();
        v.extend(band_of(self.start, &mut buf));
        v
    }
}

fn band_of(start: u64, b: &mut [f32]) -> Option<Band> {
    let n = b.len();
    if n == 0 {
        return None;
    }
    let at = |q: f64| ((q * n as f64).ceil() as usize).clamp(1, n) - 1;
    b.sort_unstable_by(f32::total_cmp);
    Some(Band {
        cycle: start,
        n: n as u32,
        min: b[0],
        p01: b[at(0.01)],
        p50: b[at(0.5)],
        p99: b[at(0.99)],
        max: b[n - 1],
    })
}

/// Least-squares slope of y over x, on centred sums (x from the first point).
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Slope {
    x0: Option<f64>,
    n: f64,
    mx: f64,
    my: f64,
    cxx: f64,
    cxy: f64,
}

impl Slope {
    pub(crate) fn add(&mut self, x: f64, y: f64) {
        let x = x - *self.x0.get_or_insert(x);
        self.n += 1.0;
        let dx = x - self.mx;
        self.mx += dx / self.n;
        self.my += (y - self.my) / self.n;
        self.cxx += dx * (x - self.mx);
        self.cxy += dx * (y - self.my);
    }

    pub(crate) fn slope(&self) -> Option<f64> {
        (self.n >= 2.0 && self.cxx > 0.0).then(|| self.cxy / self.cxx)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tracker_follows_the_typical_pulse() {
        let p = 1000.0;
        let mut t = Tracker::default();
        // Frames 300 before each pulse: 700 after the previous one.
        for _ in 0..20 {
            assert_eq!(t.place(700.0, p), -300.0);
        }
        // One 10 after the pulse it was meant for: late.
        assert_eq!(t.place(10.0, p), 10.0);
        assert_eq!(t.place(700.0, p), -300.0);
        // Frames just after a pulse from the start: meant for the next one.
        let mut t = Tracker::default();
        assert_eq!(t.place(5.0, p), -995.0);
    }

    #[test]
    fn slope_and_wkc() {
        let mut s = Slope::default();
        for i in 0..10 {
            s.add(100.0 + f64::from(i), 3.0 * f64::from(i) + 1.0);
        }
        assert!((s.slope().unwrap() - 3.0).abs() < 1e-12);
        let mut w = WkcWatch::default();
        let mut last = None;
        for _ in 0..20 {
            w.add(18, last);
            last = Some(18);
        }
        assert_eq!(w.usual, Some(18));
        assert!(!w.add(12, last));
        assert!(!w.add(0, Some(12)));
        assert_eq!((w.changed, w.zero), (2, 1));
    }

    #[test]
    fn bands_coarsen_past_the_cap() {
        let mut b = BandBlocks::new(2);
        for k in 0..(2 * BLOCKS_CAP as u64 + 10) {
            b.add(k, k as f64);
        }
        let v = b.bands();
        assert!(v.len() <= BLOCKS_CAP + 1);
        assert_eq!(v[0].min, 0.0);
        assert_eq!(b.block(), 4);
    }
}
