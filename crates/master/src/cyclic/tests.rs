use super::*;
use ecsync_dc::time::{MasterInstant, SystemTime};
use ecsync_dc::{BusShift, MedianSync};

#[test]
fn frame_layout_and_bus_shift_write() {
    let cfg = CyclicConfig {
        period_ns: 1_000_000,
        reference_station: 0x1000,
        pdi_len: 204,
        measure_init_frames: 10,
        reference_offset_ns: 0,
        lrw: Vec::new(),
    };
    let mut e =
        CyclicEngine::new(BusShift::default(), cfg.clone(), MasterInstant::from_ns(0)).unwrap();
    let f = e
        .frame_to_send(MasterInstant::from_ns(0x1122_3344_5566_7788))
        .to_vec();
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
    let m = CyclicEngine::new(MedianSync::default(), cfg, MasterInstant::from_ns(0)).unwrap();
    assert_eq!(m.frame_len(), f.len() - 20, "no FPWR for master shift");
}

/// A cycle of one frame without process data, the reference at station 0x1000.
fn no_image_config(period_ns: u64) -> CyclicConfig {
    CyclicConfig {
        period_ns: period_ns as u32,
        reference_station: 0x1000,
        pdi_len: 0,
        measure_init_frames: 2,
        reference_offset_ns: 0,
        lrw: Vec::new(),
    }
}

/// The cycle's frame sent at `send` as it comes back: the reference's FRMW read `raw`.
fn reply_with_reference_time<S: MasterSync>(
    e: &mut CyclicEngine<S>,
    send: u64,
    raw: u64,
) -> Vec<u8> {
    let mut f = e.frame_to_send(MasterInstant::from_ns(send)).to_vec();
    let at = e.plans[0].frmw_data_at.unwrap();
    f[at..at + 8].copy_from_slice(&raw.to_le_bytes());
    f[at + 8..at + 10].copy_from_slice(&1u16.to_le_bytes());
    f
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
        let next = input.nominal_start.as_ns() + p + if input.cycle >= 2 { p } else { 0 };
        CycleOutput {
            next_start: MasterInstant::from_ns(next),
            ..CycleOutput::default()
        }
    }
}

#[test]
fn a_dropped_cycle_is_no_phase_error() {
    let p = 1_000_000u64;
    let cfg = no_image_config(p);
    let mut e = CyclicEngine::new(DropsACycle, cfg, MasterInstant::from_ns(10 * p)).unwrap();
    let mut m_rs = Vec::new();
    for _ in 0..6 {
        // The frame leaves 20 us after the scheduled start and reaches the reference 7 us
        // later on its grid (reference time = master time + 3 ns).
        let send = e.scheduled_start().as_ns() + 20_000;
        let f = reply_with_reference_time(&mut e, send, send + 7_003);
        m_rs.push(
            e.complete(
                Some(&f),
                MasterInstant::from_ns(send),
                MasterInstant::from_ns(send + 50_000),
            )
            .m_rs_ns,
        );
    }
    // Cycles 0-1 average h_mr; from cycle 3 on every start is a period later than the
    // nominal grid: still the same phase of the reference's grid, so φ stays 0.
    assert_eq!(m_rs, [None, None, Some(0), Some(0), Some(0), Some(0)]);
}

/// Bus shift over a busy host (a CI run over veth): one frame leaves 119 us after its send
/// timestamp, so its write reaches the reference late and the reference's time reads
/// 113 us ahead, with a longer round trip; the next frame is back on the old timeline. No
/// step of the master's clock: the late frame is no base to look for one from.
#[test]
fn a_bus_shift_write_that_left_late_is_no_master_clock_step() {
    let p = 1_000_000u64;
    let cfg = no_image_config(p);
    let mut e =
        CyclicEngine::new(BusShift::default(), cfg, MasterInstant::from_ns(10 * p)).unwrap();
    // (wake-up after the schedule, reference time - send, round trip), us; from the run.
    let late = [(163, 113, 191), (74, 1, 205)];
    for i in 0..40 {
        let (wake, ahead, trip) = match i {
            20 | 21 => late[i - 20],
            _ => (60, 1, 70),
        };
        let send = e.scheduled_start().as_ns() + wake * 1000;
        let f = reply_with_reference_time(&mut e, send, send + ahead * 1000);
        let r = e.complete(
            Some(&f),
            MasterInstant::from_ns(send),
            MasterInstant::from_ns(send + trip * 1000),
        );
        assert!(r.ref_time.is_some(), "cycle {i}: the time is used");
    }
    assert_eq!(e.health().master_clock_steps, 0, "{:?}", e.health());
    assert_eq!(e.health().master_clock_correction_ns, 0);
    // Every start on the nominal grid: the schedule was not moved.
    assert_eq!(e.scheduled_start().as_ns(), 50 * p);
}

/// A host stall of 3 s: the engine skips the 3000 slots, the median method keeps its phase
/// (φ stays at the frames' 3 ns), and a 32-bit reference is still extended right although
/// its time moved on by more than half its 4.3 s range between two replies.
#[test]
fn skipped_cycles_keep_the_phase_and_the_reference_time() {
    let p = 1_000_000u64;
    let cfg = no_image_config(p);
    let median = MedianSync::new(11, 0.01, 2);
    // The reference's 32-bit time wraps during the stall.
    let first = (1u64 << 32) * 7 - 6 * p;
    let mut e = CyclicEngine::new(median, cfg, MasterInstant::from_ns(first)).unwrap();
    let mut seen = Vec::new();
    for i in 0..8 {
        if i == 5 {
            e.skip_cycles(3000);
            assert_eq!(e.cycle(), 3005);
            assert_eq!(e.scheduled_start().as_ns(), first + 3005 * p);
        }
        let send = e.scheduled_start().as_ns() + 20_000;
        let t_ra = send + 7_003;
        // The first reply has the full time; a 32-bit reference's later ones only the low half.
        let raw = if i == 0 { t_ra } else { u64::from(t_ra as u32) };
        let f = reply_with_reference_time(&mut e, send, raw);
        let r = e.complete(
            Some(&f),
            MasterInstant::from_ns(send),
            MasterInstant::from_ns(send + 50_000),
        );
        seen.push((
            r.cycle,
            r.ref_time.map(SystemTime::as_ns) == Some(t_ra),
            r.m_rs_ns,
        ));
    }
    let cycles: Vec<u64> = seen.iter().map(|s| s.0).collect();
    assert_eq!(cycles, [0, 1, 2, 3, 4, 3005, 3006, 3007]);
    assert!(seen.iter().all(|s| s.1), "{seen:?}");
    assert!(
        seen[2..].iter().all(|s| s.2.is_some_and(|m| m.abs() <= 3)),
        "{seen:?}"
    );
}

/// An image too large for a frame: the LRWs spread over frames after the first (which
/// carries the FRMW), the BRD in the last; the working counters add up.
#[test]
fn a_large_image_takes_several_frames() {
    let mut ranges = Vec::new();
    for i in 0..200u32 {
        ranges.push((34 * i, 34, 3));
    }
    let lrw = crate::pdi::lrw_chunks(6800, &ranges);
    let cfg = CyclicConfig {
        period_ns: 4_000_000,
        reference_station: 0x1000,
        pdi_len: 6800,
        measure_init_frames: 1,
        reference_offset_ns: 0,
        lrw: lrw.clone(),
    };
    let mut e = CyclicEngine::new(MedianSync::default(), cfg, MasterInstant::from_ns(0)).unwrap();
    let n = e.frame_count();
    assert!(n >= 5, "{n}");
    let cmds = |k: usize, e: &mut CyclicEngine<MedianSync>| -> Vec<Command> {
        let f = e.frame_to_send_of(k, MasterInstant::from_ns(0)).to_vec();
        ecsync_wire::EcatFrame::new_checked(&f[..])
            .unwrap()
            .datagrams()
            .map(|d| d.unwrap().command().unwrap())
            .collect()
    };
    // The first frame carries the FRMW and the BRD of the time difference; the others
    // process data only.
    assert_eq!(cmds(0, &mut e)[..2], [Command::Frmw, Command::Brd]);
    for k in 1..n {
        assert!(
            cmds(k, &mut e).iter().all(|&c| c == Command::Lrw),
            "frame {k}"
        );
    }
    for k in 0..n {
        assert!(e.frame_len_of(k) <= ecsync_wire::MAX_FRAME_LEN);
    }
    // Every logical byte is in the frame that holds its chunk; byte 0 is in the first
    // frame that has an LRW.
    let first_lrw = (0..n).find(|&k| !e.plans[k].lrw_wkc_at.is_empty());
    assert_eq!(e.frame_of_logical(0), first_lrw);
    assert!(e.frame_of_logical(6799).is_some());
    assert_eq!(e.frame_of_logical(6800), None);
    // Replies carry each chunk's expected working counter: the record sums them.
    let mut replies: Vec<Vec<u8>> = (0..n)
        .map(|k| e.frame_to_send_of(k, MasterInstant::from_ns(0)).to_vec())
        .collect();
    let mut k_chunk = 0;
    for (k, r) in replies.iter_mut().enumerate() {
        for &w in &e.plans[k].lrw_wkc_at {
            r[w..w + 2].copy_from_slice(&lrw[k_chunk].expected_wkc.to_le_bytes());
            k_chunk += 1;
        }
    }
    assert_eq!(k_chunk, lrw.len());
    let views: Vec<Option<&[u8]>> = replies.iter().map(|r| Some(&r[..])).collect();
    let rec = e.complete_frames(
        &views,
        MasterInstant::from_ns(10),
        MasterInstant::from_ns(20),
    );
    assert_eq!(rec.lrw_wkc, Some(600));
    assert_eq!(rec.receive.map(MasterInstant::as_ns), Some(20));
    // One frame lost: the cycle is lost.
    let mut views = views;
    views[1] = None;
    let rec = e.complete_frames(
        &views,
        MasterInstant::from_ns(10),
        MasterInstant::from_ns(20),
    );
    assert_eq!(rec.receive, None);
    assert_eq!(rec.lrw_wkc, None);
}

/// Asks for the next start `jump_ns` after the nominal one from cycle 3 on (a controller
/// gone unstable, in either direction).
struct Jumps(i64);

impl MasterSync for Jumps {
    fn name(&self) -> &'static str {
        "jumps"
    }
    fn update(&mut self, input: &CycleInput) -> CycleOutput {
        let p = u64::from(input.period_ns);
        let jump = if input.cycle >= 2 { self.0 } else { 0 };
        CycleOutput {
            next_start: MasterInstant::from_ns(
                input
                    .scheduled_start
                    .as_ns()
                    .wrapping_add(p)
                    .wrapping_add(jump as u64),
            ),
            ..CycleOutput::default()
        }
    }
}

/// A method asking for a start hours away (or in the past) gets one two periods on (or the
/// cycle's own), counted: the task does not sleep for hours, and the comparison can say the
/// method went unstable. Two periods minus a period's step are still the method's.
#[test]
fn an_unstable_method_s_schedule_is_held_within_two_periods() {
    let p = 1_000_000u64;
    for (jump, step, wild) in [
        (3_600_000_000_000i64, 2 * p, 3),
        (-5 * p as i64, 0, 3),
        (p as i64, 2 * p, 0),
        (-(p as i64), 0, 0),
    ] {
        let mut e = CyclicEngine::new(
            Jumps(jump),
            no_image_config(p),
            MasterInstant::from_ns(10 * p),
        )
        .unwrap();
        let mut starts = vec![e.scheduled_start().as_ns()];
        for _ in 0..5 {
            let send = e.scheduled_start().as_ns() + 20_000;
            let f = reply_with_reference_time(&mut e, send, send + 7_000);
            e.complete(
                Some(&f),
                MasterInstant::from_ns(send),
                MasterInstant::from_ns(send + 50_000),
            );
            starts.push(e.scheduled_start().as_ns());
        }
        let steps: Vec<u64> = starts.windows(2).map(|w| w[1].wrapping_sub(w[0])).collect();
        assert_eq!(steps, [p, p, step, step, step], "jump {jump}");
        assert_eq!(e.health().wild_schedule_cycles, wild, "jump {jump}");
    }
}
