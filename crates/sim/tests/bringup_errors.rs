//! A bring-up that fails says where: the phase, and the slave when the failing exchange
//! concerned one (issue 11). The faults are made by a test transport around the simulated
//! segment, switched on by the test when the bring-up reports a phase (the driver hands the
//! events over after the exchange of the phase's first frame, so a fault hits its second):
//!
//! * a lost frame: every frame sent while `lose` is set goes to the segment but its reply is
//!   dropped, so the one bring-up driver waits out its reply timeout;
//! * a dead slave: every FPRD, FPWR and FPRW to `dead_station` is readdressed to a station no
//!   slave has, so that nobody answers it (working counter 0, data as sent) — what the master
//!   sees of a slave at the end of a line that lost power. Broadcasts still count it and an
//!   FRMW still reaches it, so the tests kill a slave where its next exchange is addressed to
//!   it alone;
//! * a misconfigured slave: the FPWRs of process data SyncManager entries (SM2 on,
//!   0x0810-0x087F) to `blank_sync_managers_of` reach it as zeros, so it refuses SAFE-OP; those
//!   of every SyncManager (the mailbox's too) to `blank_mailbox_of`, so it refuses PRE-OP.

use ecsync_dc::time::MasterInstant;
use ecsync_master::driver::{ExchangeStats, ProcedureConfig, run_procedure};
use ecsync_master::transport::{Never, Received, Transport};
use ecsync_master::{
    BringupConfig, Engine, Event, MasterError, Network, Phase, SlaveId, Stage, bringup,
};
use ecsync_sim::transport::{SIM_PROCEDURE, SimTransport};
use ecsync_sim::{Segment, preset};
use ecsync_wire::{AlState, AlStatusCode, Command, Datagram, EcatFrame};
use std::collections::VecDeque;

/// A station address no slave of the bring-up has (they count up from 0x1000).
const NOBODY: u16 = 0xfffe;

/// What was done to one frame in flight.
#[derive(Debug, Default)]
struct Sent {
    lost: bool,
    /// Payload offsets of the datagrams readdressed from the dead station.
    readdressed: Vec<usize>,
}

/// The simulated segment with faults a test switches on and off.
struct Faults {
    inner: SimTransport,
    /// Frames sent while set are lost.
    lose: bool,
    /// This many of the next frames are lost.
    lose_next: u32,
    /// The slave at this station does not answer its configured-address datagrams.
    dead_station: Option<u16>,
    /// The process data SyncManager writes to this station arrive as zeros.
    blank_sync_managers_of: Option<u16>,
    /// Every SyncManager write to this station arrives as zeros.
    blank_mailbox_of: Option<u16>,
    in_flight: VecDeque<Sent>,
}

impl Faults {
    fn new(segment: Segment) -> Self {
        Faults {
            inner: SimTransport::new(segment),
            lose: false,
            lose_next: 0,
            dead_station: None,
            blank_sync_managers_of: None,
            blank_mailbox_of: None,
            in_flight: VecDeque::new(),
        }
    }
}

/// Payload offsets of the FPRD, FPWR and FPRW datagrams to `station` whose register address
/// lies in `registers`.
fn datagrams_to(
    frame: &[u8],
    station: u16,
    registers: std::ops::RangeInclusive<u16>,
) -> Vec<usize> {
    let Ok(f) = EcatFrame::new_checked(frame) else {
        return Vec::new();
    };
    let mut out = Vec::new();
    let mut it = f.datagrams();
    loop {
        let at = it.offset();
        let Some(Ok(d)) = it.next() else { break };
        let configured = matches!(
            d.command(),
            Ok(Command::Fprd | Command::Fpwr | Command::Fprw)
        );
        if configured && d.adp() == station && registers.contains(&d.ado()) {
            out.push(at);
        }
    }
    out
}

/// Sets the ADP of the datagrams at `offsets` of the frame's payload.
fn set_adp(frame: &mut [u8], offsets: &[usize], adp: u16) {
    let Ok(mut f) = EcatFrame::new_checked(frame) else {
        return;
    };
    let payload = f.payload_mut();
    for &at in offsets {
        if let Ok(mut d) = Datagram::new_checked(&mut payload[at..]) {
            d.set_adp(adp);
        }
    }
}

/// Zeroes the data of the `command` datagrams at `offsets` of the frame's payload.
fn zero_data(frame: &mut [u8], offsets: &[usize], command: Command) {
    let Ok(mut f) = EcatFrame::new_checked(frame) else {
        return;
    };
    let payload = f.payload_mut();
    for &at in offsets {
        if let Ok(mut d) = Datagram::new_checked(&mut payload[at..])
            && d.command() == Ok(command)
        {
            d.data_mut().fill(0);
        }
    }
}

impl Transport for Faults {
    type Error = Never;

    fn now(&mut self) -> MasterInstant {
        self.inner.now()
    }

    fn sleep_until(&mut self, t: MasterInstant) {
        self.inner.sleep_until(t);
    }

    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, Never> {
        let lost_next = self.lose_next > 0;
        self.lose_next = self.lose_next.saturating_sub(1);
        let mut sent = Sent {
            lost: self.lose || lost_next,
            readdressed: Vec::new(),
        };
        let (dead, blank, blank_all) = (
            self.dead_station,
            self.blank_sync_managers_of,
            self.blank_mailbox_of,
        );
        let r = self.inner.send_with(len, at, |buf| {
            fill(buf);
            if let Some(station) = dead {
                sent.readdressed = datagrams_to(buf, station, 0..=u16::MAX);
                set_adp(buf, &sent.readdressed, NOBODY);
            }
            if let Some(station) = blank {
                let sm = datagrams_to(buf, station, 0x0810..=0x087f);
                zero_data(buf, &sm, Command::Fpwr);
            }
            if let Some(station) = blank_all {
                let sm = datagrams_to(buf, station, 0x0800..=0x087f);
                zero_data(buf, &sm, Command::Fpwr);
            }
        });
        self.in_flight.push_back(sent);
        r
    }

    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        deadline: MasterInstant,
    ) -> Result<Option<Received>, Never> {
        loop {
            let Some(r) = self.inner.recv(buf, deadline)? else {
                return Ok(None);
            };
            // The segment answers in the order frames were sent.
            let sent = self.in_flight.pop_front().unwrap_or_default();
            if sent.lost {
                continue;
            }
            if let Some(station) = self.dead_station {
                set_adp(&mut buf[..r.len], &sent.readdressed, station);
            }
            return Ok(Some(r));
        }
    }
}

/// Brings up a line of six drives: `setup` readies the transport, `at_phase` sees it when the
/// bring-up reports a phase. The simulator's driver: no retries.
fn bring_up(
    cfg: BringupConfig,
    setup: impl FnOnce(&mut Faults),
    at_phase: impl FnMut(Phase, &mut Faults),
) -> Result<Network, MasterError> {
    bring_up_with(cfg, SIM_PROCEDURE, setup, at_phase).0
}

/// [`bring_up`] with the driver's `procedure`; also returns its counters.
fn bring_up_with(
    cfg: BringupConfig,
    procedure: ProcedureConfig,
    setup: impl FnOnce(&mut Faults),
    mut at_phase: impl FnMut(Phase, &mut Faults),
) -> (Result<Network, MasterError>, ExchangeStats) {
    let mut tr = Faults::new(Segment::new(&preset::line(6, 7)).unwrap());
    setup(&mut tr);
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let mut stats = ExchangeStats::default();
    let r = run_procedure(&mut tr, &mut engine, procedure, &mut stats, |tr, _, ev| {
        for e in ev {
            if let Event::Phase(p) = e {
                at_phase(*p, tr);
            }
        }
    });
    match r {
        Ok(r) => (r, stats),
        Err(never) => match never {},
    }
}

fn quick() -> BringupConfig {
    BringupConfig {
        latch_rounds: 4,
        static_drift_frames: 300,
        lock_hold_checks: 20,
        monitor_cycles: 20,
        ..BringupConfig::default()
    }
}

fn slave(position: u16) -> Option<SlaveId> {
    Some(SlaveId {
        position,
        station: 0x1000 + position,
    })
}

#[test]
fn the_faults_do_nothing_when_off() {
    let net = bring_up(quick(), |_| {}, |_, _| {}).expect("bring-up");
    assert_eq!(net.slaves.len(), 6);
    assert!(net.lock.converged);
}

#[test]
fn a_frame_lost_fewer_times_than_the_retries_is_sent_again() {
    let procedure = ProcedureConfig {
        retries: 2,
        ..SIM_PROCEDURE
    };
    let lose_two = |p, tr: &mut Faults| {
        if p == Phase::Identify {
            tr.lose_next = 2;
        }
    };
    let (net, stats) = bring_up_with(quick(), procedure, |_| {}, lose_two);
    assert_eq!(net.expect("bring-up").slaves.len(), 6);
    assert_eq!(stats.lost, 2);
    assert_eq!(stats.sent, stats.replies + 2);
    // One retry fewer, and the frame is lost for good.
    let procedure = ProcedureConfig {
        retries: 1,
        ..SIM_PROCEDURE
    };
    let (net, _) = bring_up_with(quick(), procedure, |_| {}, lose_two);
    let e = net.unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Identify));
    assert_eq!(e.slave(), slave(0));
    assert!(matches!(e.root(), MasterError::FrameLost { .. }), "{e:?}");
}

#[test]
fn a_lost_first_frame_fails_the_scan() {
    let mut cfg = quick();
    cfg.until = Stage::Delays;
    let e = bring_up(cfg, |tr| tr.lose = true, |_, _| {}).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Scan));
    assert_eq!(e.slave(), None, "a broadcast concerns no one slave");
    assert!(
        matches!(
            e.root(),
            MasterError::FrameLost {
                what: "count slaves",
                first: Some((ecsync_wire::Command::Brd, 0)),
                datagrams: 1,
                attempts: 1
            }
        ),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "scan: frame lost: no reply to count slaves (BRD 0x0000:0x0000) after 1 send"
    );
}

#[test]
fn a_lost_broadcast_names_the_phase() {
    let e = bring_up(quick(), |_| {}, |p, tr| tr.lose = p == Phase::Scan).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Reset));
    assert_eq!(e.slave(), None);
    assert_eq!(
        e.to_string(),
        "reset: frame lost: no reply to reset (BWR 0x0000:0x0120 and 33 more datagrams) after 1 send"
    );
}

#[test]
fn a_lost_frame_to_one_slave_names_it() {
    // The SYNC0 phase reads the reference's system time, then switches SYNC0 off in slave 0.
    let e = bring_up(quick(), |_| {}, |p, tr| tr.lose = p == Phase::Sync0).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Sync0));
    assert_eq!(e.slave(), slave(0));
    assert!(matches!(e.root(), MasterError::FrameLost { .. }), "{e:?}");
    assert_eq!(
        e.to_string(),
        "sync0: slave 0 (station 0x1000): frame lost: no reply to SYNC0 off (FPWR 0x1000:0x0981) after 1 send"
    );
}

#[test]
fn a_lost_frame_to_many_slaves_names_the_phase() {
    // The first frame of the delays latches the receive times (a broadcast), the second reads
    // them from every slave.
    let e = bring_up(quick(), |_| {}, |p, tr| tr.lose = p == Phase::Delays).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Delays));
    assert_eq!(e.slave(), None);
    assert_eq!(
        e.to_string(),
        "delays: frame lost: no reply to read receive times (FPRD 0x1000:0x0900 and 5 more datagrams) after 1 send"
    );
}

#[test]
fn a_lost_cyclic_frame_in_op_fails_the_monitor() {
    let e = bring_up(quick(), |_| {}, |p, tr| tr.lose = p == Phase::Monitor).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Monitor));
    assert!(
        matches!(e.root(), MasterError::FrameLost { what: "cyclic", .. }),
        "{e:?}"
    );
}

#[test]
fn a_slave_dead_during_identification_is_named() {
    // The slaves are identified side by side: the first frame (every slave's ESC information)
    // has left when the phase is reported, and the dead slave's next datagram, its EEPROM
    // owner write, gets no working counter.
    let e = bring_up(
        quick(),
        |_| {},
        |p, tr| {
            if p == Phase::Identify {
                tr.dead_station = Some(0x1003);
            }
        },
    )
    .unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Identify));
    assert_eq!(e.slave(), slave(3));
    assert_eq!(
        e.root(),
        &MasterError::WorkingCounter {
            command: Command::Fpwr,
            what: "SII owner",
            expected: 1,
            got: 0,
        }
    );
    assert_eq!(
        e.to_string(),
        "identify: slave 3 (station 0x1003): FPWR SII owner: working counter 0, expected 1"
    );
}

#[test]
fn a_slave_dead_during_drift_compensation_is_named_by_its_0x092c_read() {
    let e = bring_up(
        quick(),
        |_| {},
        |p, tr| {
            if p == Phase::StaticDrift {
                tr.dead_station = Some(0x1004);
            }
        },
    )
    .unwrap_err();
    assert_eq!(e.phase(), Some(Phase::StaticDrift));
    assert_eq!(e.slave(), slave(4));
    assert!(
        matches!(
            e.root(),
            MasterError::WorkingCounter {
                what: "read system time difference",
                got: 0,
                ..
            }
        ),
        "{e:?}"
    );
}

#[test]
fn a_slave_dead_at_sync0_is_named() {
    let e = bring_up(
        quick(),
        |_| {},
        |p, tr| {
            if p == Phase::Sync0 {
                tr.dead_station = Some(0x1002);
            }
        },
    )
    .unwrap_err();
    assert_eq!(e.phase(), Some(Phase::Sync0));
    assert_eq!(e.slave(), slave(2));
    assert!(
        e.to_string()
            .starts_with("sync0: slave 2 (station 0x1002): FPWR SYNC0 off")
    );
}

#[test]
fn a_slave_dead_before_safe_op_is_named() {
    let e = bring_up(
        quick(),
        |_| {},
        |p, tr| {
            if p == Phase::SafeOp {
                tr.dead_station = Some(0x1005);
            }
        },
    )
    .unwrap_err();
    assert_eq!(e.phase(), Some(Phase::SafeOp));
    assert_eq!(e.slave(), slave(5));
    assert_eq!(
        e.to_string(),
        // The requests go side by side, in the first exchange after SAFE-OP's start, which
        // the hook above sees only once it is done: the first datagram to the dead slave after
        // the hook is its AL status read.
        "safe-op: slave 5 (station 0x1005): FPRD AL status: working counter 0, expected 1"
    );
}

#[test]
fn a_slave_that_refuses_safe_op_is_named_with_its_al_status_code() {
    let e = bring_up(
        quick(),
        |tr| tr.blank_sync_managers_of = Some(0x1002),
        |_, _| {},
    )
    .unwrap_err();
    assert_eq!(e.phase(), Some(Phase::SafeOp));
    assert_eq!(e.slave(), slave(2));
    assert_eq!(
        e.root(),
        &MasterError::StateChange {
            slave: 0x1002,
            state: AlState::SafeOp,
            code: AlStatusCode::InvalidOutputConfiguration,
        }
    );
    assert_eq!(
        e.to_string(),
        "safe-op: slave 2 (station 0x1002): could not enter SAFE-OP: AL status code 0x001d \
         (Invalid output configuration)"
    );
}

#[test]
fn a_drive_without_its_mailbox_set_up_refuses_pre_op_and_says_why() {
    let e = bring_up(quick(), |tr| tr.blank_mailbox_of = Some(0x1003), |_, _| {}).unwrap_err();
    assert_eq!(e.phase(), Some(Phase::PreOp));
    assert_eq!(e.slave(), slave(3));
    assert_eq!(
        e.root(),
        &MasterError::StateChange {
            slave: 0x1003,
            state: AlState::PreOp,
            code: AlStatusCode::InvalidMailboxConfig,
        }
    );
    println!("{e}");
}
