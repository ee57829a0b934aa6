//! The cyclic phase: one frame per cycle carrying the reference's system time (FRMW of 0x0910,
//! preceded for bus shift by the master's time written to the reference), the process data
//! (LRW) and the system time difference of the slaves (BRD of 0x092C, as the letter reads it),
//! and a [`MasterSync`] method deciding when the next cycle starts.
//!
//! Sans-IO and allocation-free per cycle: the driver asks [`CyclicEngine::scheduled_start_ns`]
//! when to wake, timestamps right before sending, takes the frame from
//! [`CyclicEngine::frame_to_send`], and hands the reply (or its loss) to
//! [`CyclicEngine::complete`]. The same engine runs against the virtual segment and on a raw
//! socket.

use crate::io::MASTER_MAC;
use ecsync_dc::sync::{
    ControllerLog, CycleInput, CycleOutput, MasterSync, ReferenceWrite, extend_reference_time,
};
use ecsync_wire::dc_time::{decode_time_difference, diff_u64};
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DATAGRAM_HEADER_LEN, DatagramAddress, FrameBuilder, WireError};

/// How the cyclic frame is laid out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CyclicConfig {
    /// Cycle time and SYNC0 period, ns.
    pub period_ns: u32,
    /// Station address of the reference clock.
    pub reference_station: u16,
    /// Bytes of process data (LRW at logical address 0); 0 for none.
    pub pdi_len: u32,
    /// Frames averaged at the start for the measurement offset `h_mr` of the letter's M-rS
    /// error (eq. 5-7); the methods keep their own.
    pub measure_init_frames: u64,
    /// The System Time Offset (0x0920) the bring-up wrote to the reference: a method that
    /// adjusts the offset ([`ReferenceWrite::OffsetAdjust`]) writes this plus its adjustment.
    pub reference_offset_ns: u64,
}

/// Everything one cycle produced.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct CycleRecord {
    /// Cycle index.
    pub cycle: u64,
    /// `t_mt`: scheduled start, master time, ns.
    pub scheduled_ns: u64,
    /// `t_ms`: send timestamp, master time, ns.
    pub send_ns: u64,
    /// Reply arrival, master time, ns (`None`: lost).
    pub receive_ns: Option<u64>,
    /// `t_ra`: the reference's system time from the FRMW, 64-bit.
    pub ref_time_ns: Option<u64>,
    /// The BRD of 0x092C as returned (the OR of every slave's register).
    pub brd_092c_raw: Option<u32>,
    /// Its magnitude (bits 30:0), ns: the letter's rS-IS error.
    pub rs_is_ns: Option<u32>,
    /// LRW working counter.
    pub lrw_wkc: Option<u16>,
    /// The letter's M-rS error, ns: φ (eq. 10) for master shift once `h_mr` is known,
    /// `t_ra - t_ms` for bus shift.
    pub m_rs_ns: Option<i64>,
    /// The method's decision.
    pub output: CycleOutput,
    /// The method's log after it decided (methods that keep one, DCM).
    pub log: Option<ControllerLog>,
}

/// The cyclic engine.
#[derive(Debug, Clone)]
pub struct CyclicEngine<S> {
    sync: S,
    cfg: CyclicConfig,
    template: Vec<u8>,
    frame: Vec<u8>,
    bus_write_at: Option<usize>,
    frmw_data_at: usize,
    lrw_wkc_at: Option<usize>,
    brd_data_at: usize,
    cycle: u64,
    first_start_ns: u64,
    scheduled_ns: u64,
    last_ref_ns: Option<u64>,
    h_sum: i128,
    h_n: u64,
    h_mr: f64,
}

impl<S: MasterSync> CyclicEngine<S> {
    /// An engine whose first cycle starts at master time `first_start_ns`.
    pub fn new(sync: S, cfg: CyclicConfig, first_start_ns: u64) -> Result<Self, WireError> {
        let mut buf = vec![0u8; ecsync_wire::MAX_FRAME_LEN];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC)?;
        let system_time = DatagramAddress::Configured {
            adp: cfg.reference_station,
            ado: reg::DC_SYSTEM_TIME,
        };
        // A bus-shift method's write to the reference goes first, so that the same frame's
        // FRMW already reads (and distributes) the reference's time it set.
        let bus_register = match sync.reference_write_kind() {
            ReferenceWrite::None => None,
            ReferenceWrite::SystemTime => Some(reg::DC_SYSTEM_TIME),
            ReferenceWrite::OffsetAdjust => Some(reg::DC_SYSTEM_TIME_OFFSET),
        };
        let bus_write_at = match bus_register {
            None => None,
            Some(ado) => {
                let at = DatagramAddress::Configured {
                    adp: cfg.reference_station,
                    ado,
                };
                Some(b.push_zeroed(Command::Fpwr, 0, at, 8)? + DATAGRAM_HEADER_LEN)
            }
        };
        let frmw_data_at = b.push_zeroed(Command::Frmw, 1, system_time, 8)? + DATAGRAM_HEADER_LEN;
        let lrw_wkc_at = if cfg.pdi_len > 0 {
            let at = b.push_zeroed(
                Command::Lrw,
                2,
                DatagramAddress::Logical(0),
                cfg.pdi_len as usize,
            )?;
            Some(at + DATAGRAM_HEADER_LEN + cfg.pdi_len as usize)
        } else {
            None
        };
        let brd_data_at = b.push_zeroed(
            Command::Brd,
            3,
            DatagramAddress::Position {
                adp: 0,
                ado: reg::DC_SYSTEM_TIME_DIFF,
            },
            4,
        )? + DATAGRAM_HEADER_LEN;
        let n = b.finish();
        buf.truncate(n);
        Ok(CyclicEngine {
            sync,
            cfg,
            frame: buf.clone(),
            template: buf,
            bus_write_at,
            frmw_data_at,
            lrw_wkc_at,
            brd_data_at,
            cycle: 0,
            first_start_ns,
            scheduled_ns: first_start_ns,
            last_ref_ns: None,
            h_sum: 0,
            h_n: 0,
            h_mr: 0.0,
        })
    }

    /// The method.
    pub fn sync(&self) -> &S {
        &self.sync
    }

    /// The configuration.
    pub fn config(&self) -> &CyclicConfig {
        &self.cfg
    }

    /// When the current cycle is scheduled to start (wake the task then), master time, ns.
    pub fn scheduled_start_ns(&self) -> u64 {
        self.scheduled_ns
    }

    /// The cycle about to run.
    pub fn cycle(&self) -> u64 {
        self.cycle
    }

    /// Length of the cyclic frame, bytes.
    pub fn frame_len(&self) -> usize {
        self.template.len()
    }

    /// The frame as last handed out by [`CyclicEngine::frame_to_send`] (what a reply must
    /// answer).
    pub fn frame(&self) -> &[u8] {
        &self.frame
    }

    /// Skips `cycles` whole cycles without a frame: the task woke so late that their slots had
    /// passed (a host stall). The schedule moves on by whole periods, so every method keeps its
    /// phase to the grid; sending the missed frames back to back instead would put several
    /// frames into one SYNC0 period and feed the method instants it never chose.
    pub fn skip_cycles(&mut self, cycles: u64) {
        let span = cycles.wrapping_mul(u64::from(self.cfg.period_ns));
        self.cycle = self.cycle.wrapping_add(cycles);
        self.scheduled_ns = self.scheduled_ns.wrapping_add(span);
        // The reference time expected next, for extending a 32-bit reference, moves on too.
        self.last_ref_ns = self.last_ref_ns.map(|t| t.wrapping_add(span));
    }

    /// The frame to send now; `send_ns` is the timestamp taken right before sending (bus shift
    /// writes it to the reference).
    pub fn frame_to_send(&mut self, send_ns: u64) -> &mut [u8] {
        self.frame.copy_from_slice(&self.template);
        if let (Some(at), Some(v)) = (self.bus_write_at, self.sync.reference_write(send_ns)) {
            let v = match self.sync.reference_write_kind() {
                ReferenceWrite::OffsetAdjust => self.cfg.reference_offset_ns.wrapping_add(v),
                _ => v,
            };
            self.frame[at..at + 8].copy_from_slice(&v.to_le_bytes());
        }
        &mut self.frame
    }

    /// Completes the cycle with its reply (`None` if the frame was lost): reads the reference
    /// time, the system time difference and the working counter, runs the method and schedules
    /// the next cycle.
    pub fn complete(&mut self, reply: Option<&[u8]>, send_ns: u64, receive_ns: u64) -> CycleRecord {
        let n = self.template.len();
        let reply = reply.filter(|r| r.len() >= n);
        let mut rec = CycleRecord {
            cycle: self.cycle,
            scheduled_ns: self.scheduled_ns,
            send_ns,
            receive_ns: reply.map(|_| receive_ns),
            ..CycleRecord::default()
        };
        if let Some(r) = reply {
            let at = self.frmw_data_at;
            let frmw_wkc = u16::from_le_bytes([r[at + 8], r[at + 9]]);
            if frmw_wkc > 0 {
                let raw = u64::from_le_bytes(r[at..at + 8].try_into().unwrap_or([0; 8]));
                // A 32-bit reference reads 0 in the upper half: extend next to the expectation.
                let t = match self.last_ref_ns {
                    Some(prev) if raw >> 32 == 0 => extend_reference_time(
                        prev.wrapping_add(u64::from(self.cfg.period_ns)),
                        raw as u32,
                    ),
                    _ => raw,
                };
                rec.ref_time_ns = Some(t);
                self.last_ref_ns = Some(t);
            }
            let b = self.brd_data_at;
            let raw = u32::from_le_bytes(r[b..b + 4].try_into().unwrap_or([0; 4]));
            rec.brd_092c_raw = Some(raw);
            rec.rs_is_ns = Some(raw & 0x7fff_ffff);
            rec.lrw_wkc = self
                .lrw_wkc_at
                .map(|w| u16::from_le_bytes([r[w], r[w + 1]]));
        }
        let nominal = self
            .first_start_ns
            .wrapping_add(self.cycle.wrapping_mul(u64::from(self.cfg.period_ns)));
        let input = CycleInput {
            cycle: self.cycle,
            period_ns: self.cfg.period_ns,
            nominal_start_ns: nominal,
            scheduled_start_ns: self.scheduled_ns,
            send_ns,
            receive_ns,
            ref_time_ns: rec.ref_time_ns,
        };
        rec.output = self.sync.update(&input);
        rec.log = self.sync.controller_log();
        // The letter's M-rS error.
        if let Some(t_ra) = rec.ref_time_ns {
            if self.sync.is_master_shift() {
                if self.cycle < self.cfg.measure_init_frames {
                    self.h_sum += i128::from(diff_u64(send_ns, t_ra));
                    self.h_n += 1;
                    self.h_mr = self.h_sum as f64 / self.h_n as f64;
                } else {
                    // φ = t_ra + h_mr - (t_ms + δ̂), δ̂ = nominal - scheduled: the correction
                    // applied to this cycle. A phase error is one modulo P: a method that
                    // drops or doubles a cycle (ethercrab's snap when a frame reaches the
                    // reference just before its grid point) moves δ̂ by whole periods, which
                    // are not an error of the phase, so φ is wrapped into [-P/2, P/2).
                    let delta_hat = diff_u64(nominal, self.scheduled_ns) as f64;
                    let phi = diff_u64(t_ra, send_ns) as f64 + self.h_mr - delta_hat;
                    let p = f64::from(self.cfg.period_ns.max(1));
                    let wrapped = if phi.abs() < p / 2.0 {
                        phi
                    } else {
                        phi - p * ((phi + p / 2.0) / p).floor()
                    };
                    rec.m_rs_ns = Some(ecsync_dc::offset::round_ns(wrapped));
                }
            } else {
                rec.m_rs_ns = Some(diff_u64(t_ra, send_ns));
            }
        }
        self.scheduled_ns = rec.output.next_start_ns;
        self.cycle += 1;
        rec
    }

    /// Completes the cycle whose frame was processed in place in the buffer
    /// [`CyclicEngine::frame_to_send`] returned (`returned`: it came back).
    pub fn complete_in_place(
        &mut self,
        returned: bool,
        send_ns: u64,
        receive_ns: u64,
    ) -> CycleRecord {
        let frame = std::mem::take(&mut self.frame);
        let rec = self.complete(returned.then_some(&frame[..]), send_ns, receive_ns);
        self.frame = frame;
        rec
    }

    /// Decodes a 0x092C register value (for callers that read it per slave).
    pub fn decode_092c(raw: u32) -> i32 {
        decode_time_difference(raw)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use ecsync_dc::{BusShift, MedianSync};

    #[test]
    fn frame_layout_and_bus_shift_write() {
        let cfg = CyclicConfig {
            period_ns: 1_000_000,
            reference_station: 0x1000,
            pdi_len: 204,
            measure_init_frames: 10,
            reference_offset_ns: 0,
        };
        let mut e = CyclicEngine::new(BusShift::default(), cfg, 0).unwrap();
        let f = e.frame_to_send(0x1122_3344_5566_7788).to_vec();
        let fr = ecsync_wire::EcatFrame::new_checked(&f[..]).unwrap();
        let cmds: Vec<_> = fr
            .datagrams()
            .map(|d| d.unwrap().command().unwrap())
            .collect();
        assert_eq!(
            cmds,
            [Command::Fpwr, Command::Frmw, Command::Lrw, Command::Brd]
        );
        let d0 = fr.datagrams().next().unwrap().unwrap();
        assert_eq!(d0.data(), &0x1122_3344_5566_7788u64.to_le_bytes());
        let m = CyclicEngine::new(MedianSync::default(), cfg, 0).unwrap();
        assert_eq!(m.template.len(), f.len() - 20, "no FPWR for master shift");
    }

    /// Starts every cycle one period late from cycle 3 on (a dropped cycle, as a snap does when
    /// a frame reaches the reference just before its grid point).
    struct DropsACycle;

    impl MasterSync for DropsACycle {
        fn name(&self) -> &'static str {
            "drops-a-cycle"
        }
        fn update(&mut self, input: &CycleInput) -> CycleOutput {
            let p = u64::from(input.period_ns);
            let next = input.nominal_start_ns + p + if input.cycle >= 2 { p } else { 0 };
            CycleOutput {
                next_start_ns: next,
                ..CycleOutput::default()
            }
        }
    }

    #[test]
    fn a_dropped_cycle_is_no_phase_error() {
        let p = 1_000_000u64;
        let cfg = CyclicConfig {
            period_ns: p as u32,
            reference_station: 0x1000,
            pdi_len: 0,
            measure_init_frames: 2,
            reference_offset_ns: 0,
        };
        let mut e = CyclicEngine::new(DropsACycle, cfg, 10 * p).unwrap();
        let mut m_rs = Vec::new();
        for _ in 0..6 {
            // The frame leaves 20 us after the scheduled start and reaches the reference 7 us
            // later on its grid (reference time = master time + 3 ns).
            let send = e.scheduled_start_ns() + 20_000;
            let mut f = e.frame_to_send(send).to_vec();
            let at = e.frmw_data_at;
            f[at..at + 8].copy_from_slice(&(send + 7_003).to_le_bytes());
            f[at + 8..at + 10].copy_from_slice(&1u16.to_le_bytes());
            m_rs.push(e.complete(Some(&f), send, send + 50_000).m_rs_ns);
        }
        // Cycles 0-1 average h_mr; from cycle 3 on every start is a period later than the
        // nominal grid: still the same phase of the reference's grid, so φ stays 0.
        assert_eq!(m_rs, [None, None, Some(0), Some(0), Some(0), Some(0)]);
    }

    /// A host stall of 3 s: the engine skips the 3000 slots, the median method keeps its phase
    /// (φ stays at the frames' 3 ns), and a 32-bit reference is still extended right although
    /// its time moved on by more than half its 4.3 s range between two replies.
    #[test]
    fn skipped_cycles_keep_the_phase_and_the_reference_time() {
        let p = 1_000_000u64;
        let cfg = CyclicConfig {
            period_ns: p as u32,
            reference_station: 0x1000,
            pdi_len: 0,
            measure_init_frames: 2,
            reference_offset_ns: 0,
        };
        let median = MedianSync::new(11, 0.01, 2);
        // The reference's 32-bit time wraps during the stall.
        let first = (1u64 << 32) * 7 - 6 * p;
        let mut e = CyclicEngine::new(median, cfg, first).unwrap();
        let mut seen = Vec::new();
        for i in 0..8 {
            if i == 5 {
                e.skip_cycles(3000);
                assert_eq!(e.cycle(), 3005);
                assert_eq!(e.scheduled_start_ns(), first + 3005 * p);
            }
            let send = e.scheduled_start_ns() + 20_000;
            let mut f = e.frame_to_send(send).to_vec();
            let at = e.frmw_data_at;
            let t_ra = send + 7_003;
            // The first reply has the full time; a 32-bit reference's later ones only the low half.
            let raw = if i == 0 { t_ra } else { u64::from(t_ra as u32) };
            f[at..at + 8].copy_from_slice(&raw.to_le_bytes());
            f[at + 8..at + 10].copy_from_slice(&1u16.to_le_bytes());
            let r = e.complete(Some(&f), send, send + 50_000);
            seen.push((r.cycle, r.ref_time_ns == Some(t_ra), r.m_rs_ns));
        }
        let cycles: Vec<u64> = seen.iter().map(|s| s.0).collect();
        assert_eq!(cycles, [0, 1, 2, 3, 4, 3005, 3006, 3007]);
        assert!(seen.iter().all(|s| s.1), "{seen:?}");
        assert!(
            seen[2..].iter().all(|s| s.2.is_some_and(|m| m.abs() <= 3)),
            "{seen:?}"
        );
    }
}
