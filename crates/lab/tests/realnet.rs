//! `ecsync run`'s session on a real network, driven in-process (no binary spawned): a thread
//! in a network namespace of its own makes a veth pair, serves the virtual segment on one end
//! (`ecsync_net::serve`, a second thread) and runs the bring-up and
//! `ecsync_lab::realnet::run_cyclic` on the other. Checked against what only the served
//! segment knows: every frame the master says it sent arrived, the delays it measured are the
//! cables' and ports' true ones, and its summary's counts are the cycles it ran.
#![cfg(target_os = "linux")]

#[path = "common/ip.rs"]
mod ip;

use ecsync_dc::MethodKind;
use ecsync_dc::time::MasterDuration;
use ecsync_lab::realnet::summary::{BringupOut, RunOut};
use ecsync_lab::realnet::{CyclicOptions, RunHead, run_cyclic};
use ecsync_master::driver::{ExchangeStats, ProcedureConfig, Stopped, run_procedure};
use ecsync_master::transport::SendMode;
use ecsync_master::{BringupConfig, Engine, Network, bringup};
use ecsync_net::serve::ServeStats;
use ecsync_net::sys::PacketSocket;
use ecsync_net::tx_stamp::TxStampSource;
use ecsync_net::{RealLink, rt};
use ecsync_sim::Segment;
use ecsync_sim::preset::PAPER_2024_TOML;
use ip::ip;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

const CYCLE_NS: u32 = 1_000_000;
const SHIFT_NS: u32 = 300_000;
const CYCLES: u64 = 2_000;
const INIT_FRAMES: u64 = 100;

/// This thread in a network namespace of its own with the veth pair `va`-`vb`, both up.
fn own_namespace_with_veth() -> Result<(), String> {
    // SAFETY: unshare takes no pointers; it moves only the calling thread to a new network
    // namespace (the `ip` children spawned from it inherit it).
    if unsafe { libc::unshare(libc::CLONE_NEWNET) } != 0 {
        return Err(format!(
            "unshare(CLONE_NEWNET): {}",
            std::io::Error::last_os_error()
        ));
    }
    ip(&["link", "add", "va", "type", "veth", "peer", "name", "vb"])?;
    ip(&["link", "set", "va", "up"])?;
    ip(&["link", "set", "vb", "up"])
}

struct Outcome {
    net: Network,
    out: RunOut,
    stopped: Stopped,
    served: ServeStats,
    true_delays_ns: Vec<Option<f64>>,
}

/// Serves the letter's segment on `vb` and runs the master's session on `va`.
fn session_over_veth() -> Result<Outcome, String> {
    own_namespace_with_veth()?;
    let s = ecsync_lab::parse("paper-2024.toml", PAPER_2024_TOML).map_err(|e| e.to_string())?;
    let segment = Segment::new(&s.slaves).map_err(|e| e.to_string())?;
    let sock = PacketSocket::open_vlan_aware("vb").map_err(|e| e.to_string())?;
    let stop = Arc::new(AtomicBool::new(false));
    let served = {
        let stop = stop.clone();
        std::thread::spawn(move || {
            let mut segment = segment;
            let mut faults = ecsync_sim::fault::FaultPlayer::new(Default::default(), 0);
            let r = ecsync_net::serve::serve::<std::io::Sink, ()>(
                &sock,
                &mut segment,
                None,
                &mut faults,
                ecsync_net::serve::ServeConfig::default(),
                &stop,
                (),
            );
            (r, segment)
        })
    };
    let master = || -> Result<(Network, RunOut, Stopped), String> {
        let mut link = RealLink::open("va").map_err(|e| e.to_string())?;
        let cfg = BringupConfig {
            cycle_ns: CYCLE_NS,
            sync0_shift_ns: SHIFT_NS,
            monitor_cycles: 100,
            lock_hold_checks: 200,
            ..BringupConfig::default()
        };
        let mut engine = Engine::new(move |l| bringup(l, cfg));
        let mut exchanges = ExchangeStats::default();
        let procedure = ProcedureConfig {
            reply_timeout_ns: 20_000_000,
            retries: 10,
        };
        let net = run_procedure(
            &mut link,
            &mut engine,
            procedure,
            &mut exchanges,
            |_, _, _| {},
        )
        .map_err(|e| e.to_string())?
        .map_err(|e| format!("bring-up: {e}"))?;
        let method = s.params.build(MethodKind::Median, &s.method_context());
        let opts = CyclicOptions {
            cycle_ns: CYCLE_NS,
            sync0_shift_ns: SHIFT_NS,
            target_phase_ns: 0,
            measure_init_frames: INIT_FRAMES,
            duration: None,
            max_cycles: Some(CYCLES),
            lost_in_a_row: 1_000,
            reply_timeout: MasterDuration::from_us(900),
            t_ms_from_tx_stamp: false,
            sync_error_limit: None,
            oversampled: Vec::new(),
        };
        let mut phase =
            run_cyclic(&mut link, &net, method, &opts, None, None).map_err(|e| e.to_string())?;
        phase.finish_csv().map_err(|e| e.to_string())?;
        let stopped = match &phase.stopped {
            Ok(Some(s)) => *s,
            other => return Err(format!("the cyclic phase ended with {other:?}")),
        };
        let head = RunHead {
            iface: "va".into(),
            method: MethodKind::Median.to_string(),
            cycle_ns: CYCLE_NS,
            sync0_shift_ns: SHIFT_NS,
            bringup_link: exchanges,
            rt: rt::setup(0, rt::Pin::No),
            bringup: BringupOut::of(&net, 0.0),
            send: SendMode::Plain,
            spin_margin_us: None,
            tx_stamp_mode: "off".into(),
            t_ms_source: TxStampSource::SendTimestamp,
            t_ms_note: None,
            csv: None,
            ring_iface: None,
        };
        let out = RunOut::new(head, &phase, &link);
        Ok((net, out, stopped))
    };
    let result = master();
    stop.store(true, Ordering::Relaxed);
    let (served, segment) = served.join().map_err(|_| "the serving thread panicked")?;
    let served = served.map_err(|e| format!("serve: {e}"))?;
    let (net, out, stopped) = result?;
    let true_delays_ns = segment.true_delays_ns(usize::from(net.reference));
    Ok(Outcome {
        net,
        out,
        stopped,
        served,
        true_delays_ns,
    })
}

/// Needs root: `unshare(CLONE_NEWNET)` takes CAP_SYS_ADMIN, and the test harness's threads
/// rule out a user namespace of its own (unshare(CLONE_NEWUSER) refuses a multithreaded
/// process). Asked for where the machine refuses, it fails naming why.
#[test]
#[ignore = "needs network namespaces (root)"]
fn the_real_network_session_runs_in_process_against_the_served_segment() {
    let run = std::thread::spawn(session_over_veth)
        .join()
        .expect("no panic");
    let o = match run {
        Ok(o) => o,
        Err(e) if e.starts_with("unshare") || e.starts_with("ip ") => panic!(
            "this test needs a network namespace and a veth pair (root and iproute2), and this machine refused: {e}"
        ),
        Err(e) => panic!("{e}"),
    };
    let out = &o.out;
    assert_eq!(o.stopped, Stopped::Cycles);
    assert_eq!(out.cycles, CYCLES);
    assert_eq!(out.stopped, "cycles");
    assert_eq!(o.net.slaves.len(), 6, "the letter's six drives");
    assert!(out.bringup.converged, "DC locked in the bring-up");
    // Every frame the master sent reached the segment (nothing else speaks EtherCAT in this
    // namespace), and the segment answered every one it received.
    assert_eq!(
        o.served.received, out.link.sent,
        "{:?} vs {:?}",
        o.served, out.link
    );
    assert_eq!(o.served.answered, o.served.received);
    // A host under test load may miss a reply's deadline now and then: 1 % of the cycles, and
    // one more for each reply the serving thread itself sent over a millisecond after its wire
    // time (its own count; the reply timeout is 0.9 ms). Losses with the segment answering on
    // time are ours. (Beside other real-time tests a local run lost 103 of 2 000 once; under
    // four busy loops on this 2-core machine 141-181, with 216-329 such replies; unloaded none
    // lost, with 0 or 1 such reply.)
    let excused = CYCLES / 100 + o.served.host_stalled;
    println!(
        "lost {} of {CYCLES}; serve late {} times, over 1 ms {} (latest {} ns)",
        out.lost_frames, o.served.host_late, o.served.host_stalled, o.served.host_late_max_ns
    );
    assert!(
        out.lost_frames <= excused,
        "lost {}: serve sent {} replies over 1 ms late",
        out.lost_frames,
        o.served.host_stalled
    );
    assert_eq!(out.bad_wkc, 0, "every LRW answered by all six drives");
    // The method's figures come from the answered cycles after its init frames.
    let after_init = CYCLES - INIT_FRAMES;
    assert!(out.m_rs.n <= after_init && out.m_rs.n + out.lost_frames >= after_init);
    assert!(out.rs_is.n > 0 && out.round_trip.n + out.lost_frames == CYCLES);
    // The delays the master measured against the segment's true ones: the latches are the
    // ESCs' own, so the host's jitter does not enter (a few ns of rounding).
    let mut compared = 0;
    for (s, truth) in o.net.slaves.iter().zip(&o.true_delays_ns) {
        if let (Some(m), Some(t)) = (s.delay_ns, truth) {
            assert!(
                (m - t).abs() <= 10.0,
                "slave {}: {m} ns measured, {t} true",
                s.position
            );
            compared += 1;
        }
    }
    assert_eq!(compared, 6);
}
