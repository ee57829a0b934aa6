//! The workload of `ecsync bench` and the criterion benches: a segment brought up to OP, and
//! its cyclic frames passed through it once per simulated cycle. The paper-2024 workload is
//! the letter's frame (FRMW of the reference's system time, 204 bytes of LRW process data, BRD
//! of 0x092C) through its six drives every 1 ms; the line workloads are lines of `n` drives
//! with the cyclic engine's own frames (the FRMW in the first, the process image's LRWs spread
//! over as many frames as it needs, the BRD in the last), sent back to back.

use crate::frame_wire_time_ps;
use crate::transport::SimTransport;
use crate::{Segment, SlaveSpec, preset};
use ecsync_dc::time::MasterInstant;
use ecsync_master::bringup::{BringupConfig, Network, Stage, bringup};
use ecsync_master::cyclic::{CyclicConfig, CyclicEngine};
use ecsync_master::io::{Engine, MASTER_MAC};
use ecsync_wire::register as reg;
use ecsync_wire::{Command, DatagramAddress, FrameBuilder};

/// A segment in OP and the cyclic frames to run through it.
#[derive(Debug, Clone)]
pub struct CycleBench {
    /// The segment, in OP with DC locked.
    pub segment: Segment,
    /// The cycle's frames as the master sends them, in order.
    pub frames: Vec<Vec<u8>>,
    /// Real time of the first cycle, ps.
    pub start_ps: u64,
    /// Cycle time, ps.
    pub cycle_ps: u64,
    /// Where the LRWs' working counters are: (frame, offset).
    pub lrw_wkc_at: Vec<(usize, usize)>,
    /// The sum of the LRW working counters every cycle must return (3 per drive in OP).
    pub expected_lrw_wkc: u16,
}

/// The bring-up the benches start from: a short static drift compensation and lock hold (the
/// benches time the cycle, not the bring-up).
fn bring_up(
    specs: &[SlaveSpec],
    static_drift_frames: u32,
    cycle_ns: u32,
) -> (Network, SimTransport) {
    let seg = Segment::new(specs).expect("a valid segment");
    let mut sim = SimTransport::new(seg);
    let cfg = BringupConfig {
        until: Stage::Op,
        cycle_ns,
        static_drift_frames,
        lock_hold_checks: 100,
        monitor_cycles: 10,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up of the bench segment");
    (net, sim)
}

impl CycleBench {
    /// A line of `n` servo drives (crystals spread over +-50 ppm), in OP, with the cyclic
    /// engine's frames; the cycle is the shortest whole millisecond the frames fit in.
    pub fn line(n: usize) -> Self {
        let specs = preset::line(n, 11);
        let drift = BringupConfig::default().static_drift_frames;
        let ms = 1_000_000_000;
        let (net, sim) = bring_up(&specs, drift, (ms / 1000) as u32);
        let bench = Self::line_on(net, sim);
        if bench.cycle_ps == ms {
            return bench;
        }
        // The frames take longer than a millisecond: the network is brought up again with
        // SYNC0 on their cycle, as a master would run it (on the millisecond, every drive
        // would see several SYNC0 pulses a cycle and count all but one as missed).
        let (net, sim) = bring_up(&specs, drift, (bench.cycle_ps / 1000) as u32);
        let again = Self::line_on(net, sim);
        debug_assert_eq!(again.cycle_ps, bench.cycle_ps);
        again
    }

    /// The bench of a line brought up (`net` on `sim`): its frames, and the cycle they fit
    /// in, whole milliseconds.
    fn line_on(net: Network, sim: SimTransport) -> Self {
        let cfg = CyclicConfig::for_network(&net, 1_000_000, 1).expect("a reference");
        let mut eng = CyclicEngine::new(
            ecsync_dc::MedianSync::default(),
            cfg,
            MasterInstant::from_ns(0),
        )
        .expect("the engine plans the frames");
        let frames: Vec<Vec<u8>> = (0..eng.frame_count())
            .map(|k| eng.frame_to_send_of(k, MasterInstant::from_ns(0)).to_vec())
            .collect();
        let lrw_wkc_at = (0..frames.len())
            .flat_map(|k| eng.lrw_wkc_offsets(k).iter().map(move |&at| (k, at)))
            .collect();
        // Back to back on the wire, then the last frame's way round the line.
        let wire_ps: u64 = frames.iter().map(|f| frame_wire_time_ps(f.len())).sum();
        let round_ps = sim.segment().round_trip_ps();
        let ms = 1_000_000_000;
        let cycle_ps = (wire_ps + round_ps).div_ceil(ms).max(1) * ms;
        CycleBench {
            start_ps: (sim.now_ps() / cycle_ps + 1) * cycle_ps,
            segment: sim.into_segment(),
            frames,
            cycle_ps,
            lrw_wkc_at,
            expected_lrw_wkc: net.expected_lrw_wkc,
        }
    }

    /// Brings paper-2024 up (with a short static drift compensation) and builds the frame.
    pub fn paper_2024() -> Self {
        let (net, sim) = bring_up(&preset::paper_2024(), 2_000, 1_000_000);
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
            frames: vec![buf],
            cycle_ps,
            lrw_wkc_at: vec![(
                0,
                lrw_at + ecsync_wire::DATAGRAM_HEADER_LEN + net.pdi_len as usize,
            )],
            expected_lrw_wkc: net.expected_lrw_wkc,
        }
    }

    /// A frame holding only datagram `which` of the cyclic frame (0 FRMW, 1 LRW, 2 BRD), or a
    /// 4-byte NOP for `which` = 3: to time the parts.
    pub fn single_datagram_frame(&self, which: usize) -> Vec<u8> {
        let f = ecsync_wire::EcatFrame::new_checked(&self.frames[0][..]).expect("valid");
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

    /// Keeps only frame `frame` of the cycle, reduced to datagram `which` (see
    /// [`CycleBench::single_datagram_frame`]): the LRW check then does not apply.
    pub fn keep_single_datagram(&mut self, which: usize) {
        self.frames = vec![self.single_datagram_frame(which)];
        self.lrw_wkc_at.clear();
    }

    /// Runs `cycles` cycles; returns the sum of the last cycle's LRW working counters as a
    /// check. `work` must hold the longest frame.
    pub fn run(&mut self, cycles: u64, work: &mut [u8]) -> u16 {
        let mut wkc = 0;
        for i in 0..cycles {
            let mut t = self.start_ps + i * self.cycle_ps;
            wkc = 0;
            for (k, frame) in self.frames.iter().enumerate() {
                let n = frame.len();
                work[..n].copy_from_slice(frame);
                let out = self.segment.process(&mut work[..n], t);
                debug_assert!(out.returned_sof_ps.is_some());
                t += frame_wire_time_ps(n);
                for &(_, at) in self.lrw_wkc_at.iter().filter(|w| w.0 == k) {
                    if at + 1 < n {
                        wkc += u16::from_le_bytes([work[at], work[at + 1]]);
                    }
                }
            }
        }
        self.start_ps += cycles * self.cycle_ps;
        wkc
    }
}
