//! The workload of `ecsync bench` and the criterion benches: the paper-2024 segment brought up
//! to OP, and the letter's cyclic frame (FRMW of the reference's system time, 204 bytes of LRW
//! process data, BRD of 0x092C) passed through it once per simulated 1 ms cycle.

use crate::bringup::{BringupConfig, Stage, bringup};
use crate::io::{Engine, MASTER_MAC};
use crate::sim::SimTransport;
use ecsync_esc::{Segment, preset};
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};

/// A segment in OP and the cyclic frame to run through it.
#[derive(Debug, Clone)]
pub struct CycleBench {
    /// The segment, in OP with DC locked.
    pub segment: Segment,
    /// The cyclic frame as the master sends it.
    pub frame: Vec<u8>,
    /// Real time of the first cycle, ps.
    pub start_ps: u64,
    /// Cycle time, ps.
    pub cycle_ps: u64,
    /// Offset of the LRW's working counter in the frame.
    pub lrw_wkc_at: usize,
    /// The LRW working counter every cycle must return (3 per drive in OP).
    pub expected_lrw_wkc: u16,
}

impl CycleBench {
    /// Brings paper-2024 up (with a short static drift compensation) and builds the frame.
    pub fn paper_2024() -> Self {
        let seg = Segment::new(&preset::paper_2024()).expect("preset");
        let mut sim = SimTransport::new(seg);
        let cfg = BringupConfig {
            until: Stage::Op,
            static_drift_frames: 2_000,
            lock_hold_checks: 100,
            monitor_cycles: 10,
            ..BringupConfig::default()
        };
        let mut engine = Engine::new(move |link| bringup(link, cfg));
        let net = sim
            .run_procedure(&mut engine, |_, _, _| {})
            .expect("bring-up of the preset");
        let ref_station = net.slaves[usize::from(net.reference)].station;
        let mut buf = vec![0u8; 1514];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC).expect("buffer");
        b.push_zeroed(
            Command::Frmw,
            0,
            DatagramAddress::Configured {
                adp: ref_station,
                ado: reg::DC_SYSTEM_TIME,
            },
            8,
        )
        .expect("fits");
        let lrw_at = b
            .push_zeroed(
                Command::Lrw,
                1,
                DatagramAddress::Logical(0),
                net.pdi_len as usize,
            )
            .expect("fits");
        b.push_zeroed(
            Command::Brd,
            2,
            DatagramAddress::Position {
                adp: 0,
                ado: reg::DC_SYSTEM_TIME_DIFF,
            },
            4,
        )
        .expect("fits");
        let n = b.finish();
        buf.truncate(n);
        let cycle_ps = 1_000_000_000;
        CycleBench {
            start_ps: (sim.now_ps() / cycle_ps + 1) * cycle_ps,
            segment: sim.into_segment(),
            frame: buf,
            cycle_ps,
            lrw_wkc_at: lrw_at + ecsync_wire::DATAGRAM_HEADER_LEN + net.pdi_len as usize,
            expected_lrw_wkc: net.expected_lrw_wkc,
        }
    }

    /// A frame holding only datagram `which` of the cyclic frame (0 FRMW, 1 LRW, 2 BRD), or a
    /// 4-byte NOP for `which` = 3: to time the parts.
    pub fn single_datagram_frame(&self, which: usize) -> Vec<u8> {
        let f = ecsync_wire::EcatFrame::new_checked(&self.frame[..]).expect("valid");
        let mut buf = vec![0u8; 1514];
        let mut b = FrameBuilder::new(&mut buf, [0xff; 6], MASTER_MAC).expect("buffer");
        if let Some(Ok(d)) = f.datagrams().nth(which) {
            b.push(
                d.command().expect("valid"),
                d.index(),
                DatagramAddress::Logical(d.address_raw()),
                d.data(),
            )
            .expect("fits");
        } else {
            b.push_zeroed(Command::Nop, 0, DatagramAddress::Logical(0), 4)
                .expect("fits");
        }
        let n = b.finish();
        buf.truncate(n);
        buf
    }

    /// Number of slaves (slave-cycles per cycle).
    pub fn slaves(&self) -> usize {
        self.segment.len()
    }

    /// Runs `cycles` cycles; returns the working counter of the last LRW as a check.
    pub fn run(&mut self, cycles: u64, work: &mut [u8]) -> u16 {
        let n = self.frame.len();
        let mut wkc = 0;
        for i in 0..cycles {
            work[..n].copy_from_slice(&self.frame);
            let t = self.start_ps + i * self.cycle_ps;
            let out = self.segment.process(&mut work[..n], t);
            debug_assert!(out.returned_sof_ps.is_some());
            let at = self.lrw_wkc_at;
            if at + 1 < n {
                wkc = u16::from_le_bytes([work[at], work[at + 1]]);
            }
        }
        self.start_ps += cycles * self.cycle_ps;
        wkc
    }
}
