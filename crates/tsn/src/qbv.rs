//! IEEE 802.1Qbv time-aware shaping at one bridge egress port: the gate control list that
//! opens a window for the EtherCAT traffic class once per cycle and gives the rest of the cycle
//! to best-effort traffic (gPTP included), as the paper's Network template does with its
//! 30-in-100 gate.
//!
//! A schedule is given as windows (open and close, ns after the start of each gate cycle, in
//! the bridge's own clock) and compiled into the standard's form, a cyclic list of
//! `SetGateStates` entries (gate states, time interval). The port then answers when a frame of
//! a class that is ready at some local time may start: at once if its gate is open and the
//! frame ends before the gate closes (802.1Qbv's transmission-overrun rule, 8.6.8.4), else at
//! the next opening it fits in. Best-effort frames also stop a guard band before an EtherCAT
//! window so that the window starts on an idle wire.
//!
//! Sans-IO and allocation-free after construction: the bridge simulation converts its own
//! clock to and from true time.

use core::fmt;

/// Traffic classes the port schedules.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum TrafficClass {
    /// EtherCAT frames (ethertype 0x88A4): a time-triggered queue open only in the windows.
    EtherCat,
    /// Everything else (best effort, gPTP): open outside the windows.
    BestEffort,
}

/// Gate state bits of a [`GateControlEntry`] (one bit per traffic class queue).
pub mod gate {
    /// The EtherCAT queue's gate.
    pub const ETHERCAT: u8 = 0b10;
    /// The best-effort queue's gate.
    pub const BEST_EFFORT: u8 = 0b01;
}

/// One EtherCAT window of a gate cycle, ns after the cycle's start (bridge clock).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    /// The EtherCAT gate opens, ns after the cycle start.
    pub open_ns: u64,
    /// It closes, ns after the cycle start (after `open_ns`, at most the cycle).
    pub close_ns: u64,
}

/// One entry of the compiled gate control list (802.1Qbv `SetGateStates`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct GateControlEntry {
    /// Gates open during this entry ([`gate`] bits).
    pub gate_states: u8,
    /// How long the entry lasts, ns.
    pub interval_ns: u64,
}

/// Why a schedule is refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ScheduleError {
    /// The cycle time is zero.
    ZeroCycle,
    /// No window at all: EtherCAT frames would wait forever.
    Empty,
    /// A window that closes at or before it opens.
    EmptyWindow {
        /// Index in the list as given.
        index: usize,
        /// Its bounds.
        window: Window,
    },
    /// A window longer than the cycle.
    LongerThanCycle {
        /// Index in the list as given.
        index: usize,
        /// Its bounds.
        window: Window,
        /// The cycle, ns.
        cycle_ns: u64,
    },
    /// A window that opens or closes outside the cycle.
    OutsideCycle {
        /// Index in the list as given.
        index: usize,
        /// Its bounds.
        window: Window,
        /// The cycle, ns.
        cycle_ns: u64,
    },
    /// Two windows overlap.
    Overlap {
        /// Indices in the list as given.
        first: usize,
        /// The other.
        second: usize,
        /// The overlap, ns after the cycle start.
        from_ns: u64,
        /// Its end.
        to_ns: u64,
    },
    /// The largest frame does not fit into any window.
    FrameDoesNotFit {
        /// Its wire time, ns.
        frame_ns: u64,
        /// The longest window, ns.
        longest_ns: u64,
    },
}

impl fmt::Display for ScheduleError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ScheduleError::ZeroCycle => write!(
                f,
                "the gate cycle is 0 ns; give the cycle of the schedule (the EtherCAT cycle, e.g. 1000000)"
            ),
            ScheduleError::Empty => write!(
                f,
                "the gate control list is empty: EtherCAT frames would never be forwarded; give at least one window (open_ns, close_ns)"
            ),
            ScheduleError::EmptyWindow { index, window } => write!(
                f,
                "window {index} opens at {} ns and closes at {} ns: it must close after it opens",
                window.open_ns, window.close_ns
            ),
            ScheduleError::LongerThanCycle {
                index,
                window,
                cycle_ns,
            } => write!(
                f,
                "window {index} ({}..{} ns) is {} ns long, longer than the gate cycle of {cycle_ns} ns; shorten it (a gate open for the whole cycle is 0..{cycle_ns})",
                window.open_ns,
                window.close_ns,
                window.close_ns - window.open_ns
            ),
            ScheduleError::OutsideCycle {
                index,
                window,
                cycle_ns,
            } => write!(
                f,
                "window {index} ({}..{} ns) ends after the gate cycle of {cycle_ns} ns; windows lie within 0..{cycle_ns} (split one that wraps into two)",
                window.open_ns, window.close_ns
            ),
            ScheduleError::Overlap {
                first,
                second,
                from_ns,
                to_ns,
            } => write!(
                f,
                "windows {first} and {second} overlap from {from_ns} to {to_ns} ns; merge them or move one"
            ),
            ScheduleError::FrameDoesNotFit {
                frame_ns,
                longest_ns,
            } => write!(
                f,
                "the largest EtherCAT frame needs {frame_ns} ns on the wire but the longest window is {longest_ns} ns; it could never be sent"
            ),
        }
    }
}

impl std::error::Error for ScheduleError {}

/// The schedule of one egress port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PortSchedule {
    cycle_ns: u64,
    base_ns: u64,
    /// Windows sorted by opening, disjoint, within the cycle.
    windows: Vec<Window>,
    /// The gate's open spans over three consecutive cycles, as phases from the first cycle's
    /// start: windows that touch (also across a cycle's end) are one span, since the gate stays
    /// open and a frame may run from one into the next.
    spans: Vec<(u64, u64)>,
    /// The windows cover the whole cycle: the gate never closes.
    always_open: bool,
    /// The longest open span (`u64::MAX` when the gate never closes).
    longest_open_ns: u64,
    /// Best-effort guard band before each window, ns (the longest best-effort frame).
    guard_ns: u64,
}

impl PortSchedule {
    /// A schedule of `windows` in a gate cycle of `cycle_ns` starting at local times
    /// `base_ns + k * cycle_ns`, checked: the list not empty, every window within the cycle and
    /// not longer than it, no two overlapping. `guard_ns` is the best-effort guard band.
    pub fn new(
        cycle_ns: u64,
        base_ns: u64,
        windows: &[Window],
        guard_ns: u64,
    ) -> Result<Self, ScheduleError> {
        if cycle_ns == 0 {
            return Err(ScheduleError::ZeroCycle);
        }
        if windows.is_empty() {
            return Err(ScheduleError::Empty);
        }
        for (index, &window) in windows.iter().enumerate() {
            if window.close_ns <= window.open_ns {
                return Err(ScheduleError::EmptyWindow { index, window });
            }
            if window.close_ns - window.open_ns > cycle_ns {
                return Err(ScheduleError::LongerThanCycle {
                    index,
                    window,
                    cycle_ns,
                });
            }
            if window.close_ns > cycle_ns {
                return Err(ScheduleError::OutsideCycle {
                    index,
                    window,
                    cycle_ns,
                });
            }
        }
        let mut order: Vec<usize> = (0..windows.len()).collect();
        order.sort_by_key(|&i| (windows[i].open_ns, i));
        for pair in order.windows(2) {
            let (a, b) = (windows[pair[0]], windows[pair[1]]);
            if b.open_ns < a.close_ns {
                let (first, second) = (pair[0].min(pair[1]), pair[0].max(pair[1]));
                return Err(ScheduleError::Overlap {
                    first,
                    second,
                    from_ns: b.open_ns,
                    to_ns: a.close_ns.min(b.close_ns),
                });
            }
        }
        let windows: Vec<Window> = order.iter().map(|&i| windows[i]).collect();
        let open_ns: u64 = windows.iter().map(|w| w.close_ns - w.open_ns).sum();
        let always_open = open_ns == cycle_ns;
        let mut spans: Vec<(u64, u64)> = Vec::with_capacity(3 * windows.len());
        for k in 0..3 {
            for w in &windows {
                let (o, c) = (k * cycle_ns + w.open_ns, k * cycle_ns + w.close_ns);
                match spans.last_mut() {
                    Some(last) if last.1 == o => last.1 = c,
                    _ => spans.push((o, c)),
                }
            }
        }
        // Every distinct span starts once in the middle cycle, and ends within the third (a
        // span is shorter than the cycle unless the gate never closes).
        let longest_open_ns = if always_open {
            u64::MAX
        } else {
            spans
                .iter()
                .filter(|(o, _)| (cycle_ns..2 * cycle_ns).contains(o))
                .map(|(o, c)| c - o)
                .max()
                .unwrap_or(0)
        };
        Ok(PortSchedule {
            cycle_ns,
            base_ns,
            windows,
            spans,
            always_open,
            longest_open_ns,
            guard_ns,
        })
    }

    /// Refuses the schedule if a frame of `frame_ns` on the wire fits into no window.
    pub fn check_fits(&self, frame_ns: u64) -> Result<(), ScheduleError> {
        let longest = self.longest_open_ns;
        if frame_ns > longest {
            return Err(ScheduleError::FrameDoesNotFit {
                frame_ns,
                longest_ns: longest,
            });
        }
        Ok(())
    }

    /// The gate cycle, ns.
    pub fn cycle_ns(&self) -> u64 {
        self.cycle_ns
    }

    /// The windows, sorted.
    pub fn windows(&self) -> &[Window] {
        &self.windows
    }

    /// The longest time the EtherCAT gate stays open: windows that touch count as one
    /// (`u64::MAX` if it never closes).
    pub fn longest_open_ns(&self) -> u64 {
        self.longest_open_ns
    }

    /// Share of the cycle the EtherCAT gate is open.
    pub fn open_fraction(&self) -> f64 {
        let open: u64 = self.windows.iter().map(|w| w.close_ns - w.open_ns).sum();
        open as f64 / self.cycle_ns as f64
    }

    /// The compiled gate control list: the EtherCAT gate open in the windows, the best-effort
    /// gate open elsewhere (802.1Qbv `SetGateStates` operations, one cycle).
    pub fn control_list(&self) -> Vec<GateControlEntry> {
        let mut out = Vec::new();
        let mut t = 0;
        let mut push = |states: u8, len: u64| {
            if len > 0 {
                out.push(GateControlEntry {
                    gate_states: states,
                    interval_ns: len,
                });
            }
        };
        for w in &self.windows {
            push(gate::BEST_EFFORT, w.open_ns - t);
            push(gate::ETHERCAT, w.close_ns - w.open_ns);
            t = w.close_ns;
        }
        push(gate::BEST_EFFORT, self.cycle_ns - t);
        out
    }

    /// Start of the gate cycle that holds local time `t_ns`, and the phase within it.
    fn cycle_of(&self, t_ns: u64) -> (u64, u64) {
        // Times before the base read as if the cycles went on backwards.
        let rel = t_ns.wrapping_sub(self.base_ns) as i64;
        let k = rel.div_euclid(self.cycle_ns as i64);
        let phase = rel.rem_euclid(self.cycle_ns as i64) as u64;
        (
            self.base_ns.wrapping_add((k * self.cycle_ns as i64) as u64),
            phase,
        )
    }

    /// Whether the EtherCAT gate is open at local time `t_ns`.
    pub fn ethercat_open_at(&self, t_ns: u64) -> bool {
        let (_, phase) = self.cycle_of(t_ns);
        self.windows
            .iter()
            .any(|w| w.open_ns <= phase && phase < w.close_ns)
    }

    /// The earliest local time at or after `ready_ns` at which an EtherCAT frame lasting
    /// `frame_ns` on the wire may start: while the gate is open, and ending before it closes
    /// (the transmission-overrun rule; windows that touch, also across the cycle's end, keep the
    /// gate open). `None` if it fits into no open span.
    pub fn ethercat_start(&self, ready_ns: u64, frame_ns: u64) -> Option<u64> {
        if self.always_open {
            return Some(ready_ns);
        }
        if frame_ns > self.longest_open_ns {
            return None;
        }
        let (start, phase) = self.cycle_of(ready_ns);
        // A span open before `phase` (in this cycle or, across the cycle's start, in the last)
        // still counts from `phase` on; the first span of the first cycle may be the tail of
        // one that began in the cycle before, and its close is right.
        self.spans.iter().find_map(|&(open, close)| {
            let s = phase.max(open);
            (s + frame_ns <= close).then(|| start.wrapping_add(s))
        })
    }

    /// The earliest local time at or after `ready_ns` at which a best-effort frame lasting
    /// `frame_ns` may start: outside the windows, ending a guard band before the next one.
    /// (A frame longer than every gap would never go: it starts at the first gap's start.)
    pub fn best_effort_start(&self, ready_ns: u64, frame_ns: u64) -> u64 {
        let (start, phase) = self.cycle_of(ready_ns);
        let need = frame_ns + self.guard_ns;
        // Gaps of this cycle and the next, as (from, to) phases relative to `start`.
        let mut gaps = [(0u64, 0u64); 64];
        let mut n = 0;
        for c in 0..2u64 {
            let off = c * self.cycle_ns;
            let mut t = 0;
            for w in &self.windows {
                if n < gaps.len() && w.open_ns > t {
                    gaps[n] = (off + t, off + w.open_ns);
                    n += 1;
                }
                t = w.close_ns;
            }
            if n < gaps.len() && self.cycle_ns > t {
                // The gap at the cycle's end runs on into the next cycle's first gap.
                let next_open = self.windows.first().map_or(0, |w| w.open_ns);
                gaps[n] = (off + t, off + self.cycle_ns + next_open);
                n += 1;
            }
        }
        for &(from, to) in &gaps[..n] {
            let s = phase.max(from);
            if s + need <= to {
                return start.wrapping_add(s);
            }
        }
        // No gap is long enough: the first gap after `ready`.
        gaps[..n]
            .iter()
            .find(|g| g.1 > phase)
            .map_or(ready_ns, |g| start.wrapping_add(phase.max(g.0)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn w(open_ns: u64, close_ns: u64) -> Window {
        Window { open_ns, close_ns }
    }

    /// The paper's gate: 30 open in a cycle of 100 (here in microseconds: 300 of 1000).
    fn paper() -> PortSchedule {
        PortSchedule::new(1_000_000, 0, &[w(0, 300_000)], 12_500).unwrap()
    }

    #[test]
    fn the_papers_gate_compiles_to_two_entries() {
        let s = paper();
        assert_eq!(
            s.control_list(),
            vec![
                GateControlEntry {
                    gate_states: gate::ETHERCAT,
                    interval_ns: 300_000
                },
                GateControlEntry {
                    gate_states: gate::BEST_EFFORT,
                    interval_ns: 700_000
                },
            ]
        );
        assert!((s.open_fraction() - 0.3).abs() < 1e-12);
    }

    #[test]
    fn ethercat_frames_pass_in_the_window_and_wait_outside_it() {
        let s = paper();
        let f = 20_000; // a 250-byte frame at 100 Mbit/s
        // Inside: at once.
        assert_eq!(s.ethercat_start(5_000_000 + 1_000, f), Some(5_001_000));
        // Would overrun the close at 300 us: the next cycle's opening.
        assert_eq!(s.ethercat_start(5_000_000 + 290_000, f), Some(6_000_000));
        // Exactly fits.
        assert_eq!(s.ethercat_start(5_000_000 + 280_000, f), Some(5_280_000));
        // Closed part.
        assert_eq!(s.ethercat_start(5_000_000 + 700_000, f), Some(6_000_000));
        assert!(s.ethercat_open_at(7_299_999));
        assert!(!s.ethercat_open_at(7_300_000));
        // A frame longer than the window never goes.
        assert_eq!(s.ethercat_start(0, 300_001), None);
    }

    #[test]
    fn the_base_time_shifts_the_cycle_and_times_before_it_work() {
        let s = PortSchedule::new(1_000, 250, &[w(100, 200)], 0).unwrap();
        assert_eq!(s.ethercat_start(250, 10), Some(350));
        // Local time 0 lies in the cycle that started at -750, past its window.
        assert_eq!(s.ethercat_start(0, 10), Some(350));
        assert_eq!(s.ethercat_start(1_260, 10), Some(1_350));
        assert_eq!(s.ethercat_start(1_345, 10), Some(1_350));
        assert_eq!(s.ethercat_start(120, 10), Some(350));
    }

    #[test]
    fn best_effort_keeps_a_guard_band_before_each_window() {
        let s = paper();
        // In the window: waits for its end.
        assert_eq!(s.best_effort_start(100_000, 10_000), 300_000);
        // Just before the next window: would overrun the guard band, so after that window.
        assert_eq!(s.best_effort_start(980_000, 10_000), 1_300_000);
        // Well clear of it: at once.
        assert_eq!(s.best_effort_start(500_000, 10_000), 500_000);
    }

    #[test]
    fn bad_schedules_are_refused_with_a_reason() {
        let e = PortSchedule::new(1_000_000, 0, &[], 0).unwrap_err();
        assert_eq!(e, ScheduleError::Empty);
        assert!(e.to_string().contains("empty"));

        let e = PortSchedule::new(1_000_000, 0, &[w(0, 1_500_000)], 0).unwrap_err();
        assert!(matches!(e, ScheduleError::LongerThanCycle { index: 0, .. }));
        assert!(e.to_string().contains("longer than the gate cycle"), "{e}");

        let e = PortSchedule::new(
            1_000_000,
            0,
            &[w(0, 300_000), w(600_000, 900_000), w(250_000, 400_000)],
            0,
        )
        .unwrap_err();
        assert_eq!(
            e,
            ScheduleError::Overlap {
                first: 0,
                second: 2,
                from_ns: 250_000,
                to_ns: 300_000
            }
        );
        assert!(
            e.to_string().contains("overlap from 250000 to 300000"),
            "{e}"
        );

        let e = PortSchedule::new(1_000_000, 0, &[w(900_000, 1_100_000)], 0).unwrap_err();
        assert!(matches!(e, ScheduleError::OutsideCycle { .. }), "{e}");
        let e = PortSchedule::new(1_000_000, 0, &[w(5, 5)], 0).unwrap_err();
        assert!(matches!(e, ScheduleError::EmptyWindow { .. }), "{e}");
        assert_eq!(
            PortSchedule::new(0, 0, &[w(0, 1)], 0).unwrap_err(),
            ScheduleError::ZeroCycle
        );
        let s = PortSchedule::new(1_000_000, 0, &[w(0, 10_000)], 0).unwrap();
        assert!(matches!(
            s.check_fits(20_000),
            Err(ScheduleError::FrameDoesNotFit { .. })
        ));
        // Touching windows are fine.
        assert!(PortSchedule::new(1_000, 0, &[w(0, 100), w(100, 200)], 0).is_ok());
    }

    #[test]
    fn frames_run_on_through_touching_windows_and_across_the_cycle_end() {
        // The proptest's find: one window covering the whole cycle, the gate never closes.
        let s = PortSchedule::new(89, 153, &[w(0, 89)], 0).unwrap();
        assert_eq!(s.ethercat_start(1_520, 58), Some(1_520));
        assert_eq!(s.longest_open_ns(), u64::MAX);
        assert!(s.check_fits(1_000_000).is_ok());
        // Two touching windows are one open span of 200 ns.
        let s = PortSchedule::new(1_000, 0, &[w(0, 100), w(100, 200)], 0).unwrap();
        assert_eq!(s.ethercat_start(50, 120), Some(50));
        assert_eq!(s.longest_open_ns(), 200);
        // A window at the cycle's end and one at its start: open from 900 to 1_100.
        let s = PortSchedule::new(1_000, 0, &[w(0, 100), w(900, 1_000)], 0).unwrap();
        assert_eq!(s.longest_open_ns(), 200);
        assert_eq!(s.ethercat_start(950, 120), Some(950));
        assert_eq!(s.ethercat_start(2_050, 40), Some(2_050));
        assert_eq!(s.ethercat_start(2_050, 60), Some(2_900));
        assert_eq!(s.ethercat_start(0, 201), None);
        assert!(matches!(
            s.check_fits(201),
            Err(ScheduleError::FrameDoesNotFit {
                longest_ns: 200,
                ..
            })
        ));
    }

    /// Windows from sorted cut points of a small cycle: disjoint, possibly touching.
    fn windows_strategy() -> impl proptest::strategy::Strategy<Value = (u64, Vec<Window>)> {
        use proptest::prelude::*;
        (20u64..200, proptest::collection::vec(0u64..1000, 2..8)).prop_map(|(cycle, cuts)| {
            let mut c: Vec<u64> = cuts.iter().map(|x| x % (cycle + 1)).collect();
            c.sort_unstable();
            c.dedup();
            let ws: Vec<Window> = c
                .chunks(2)
                .filter(|p| p.len() == 2 && p[1] > p[0])
                .map(|p| w(p[0], p[1]))
                .collect();
            (cycle, ws)
        })
    }

    proptest::proptest! {
        /// Against brute force: the start is the first nanosecond at or after `ready` at which
        /// the gate is open and stays open for the whole frame.
        #[test]
        fn ethercat_start_is_the_first_instant_that_fits(
            (cycle, ws) in windows_strategy(),
            base in 0u64..1000,
            ready in 0u64..5000,
            frame in 1u64..60,
        ) {
            proptest::prop_assume!(!ws.is_empty());
            let s = PortSchedule::new(cycle, base, &ws, 0).unwrap();
            let fits = |t: u64| (t..t + frame).all(|x| s.ethercat_open_at(x));
            let brute = (ready..ready + 3 * cycle).find(|&t| fits(t));
            proptest::prop_assert_eq!(s.ethercat_start(ready, frame), brute);
        }

        /// Best effort never overlaps a window (nor the guard band before one) when a gap
        /// is long enough.
        #[test]
        fn best_effort_stays_out_of_the_windows(
            (cycle, ws) in windows_strategy(),
            ready in 0u64..5000,
            frame in 1u64..20,
            guard in 0u64..10,
        ) {
            proptest::prop_assume!(!ws.is_empty());
            let s = PortSchedule::new(cycle, 0, &ws, guard).unwrap();
            let t = s.best_effort_start(ready, frame);
            proptest::prop_assert!(t >= ready);
            let clear = |t: u64| (t..t + frame + guard).all(|x| !s.ethercat_open_at(x));
            if (ready..ready + 3 * cycle).any(clear) {
                proptest::prop_assert!(clear(t), "start {} not clear", t);
                let first = (ready..ready + 3 * cycle).find(|&x| clear(x)).unwrap_or(t);
                proptest::prop_assert_eq!(t, first);
            }
        }
    }
}
