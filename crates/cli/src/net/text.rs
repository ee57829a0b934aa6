//! What `ecsync run` prints on the terminal: the bring-up's slaves and lock, then the cyclic
//! phase's summary.

use ecsync_lab::realnet::summary::{BringupOut, RunOut};
use ecsync_master::bringup::{DcCapability, Phase};
use ecsync_net::tx_stamp::TxStampSource;

/// The bring-up as text: the slaves with their delays and DC, and whether DC locked.
pub(super) fn print_bringup(b: &BringupOut) {
    println!(
        "bring-up: {} slaves, reference at position {}, {:.2} s",
        b.slaves.len(),
        b.reference,
        b.wall_s
    );
    println!(
        "{:>3}  {:>7}  {:<28} {:>12}  {:>10}",
        "pos", "station", "name", "delay ns", "DC"
    );
    for s in &b.slaves {
        let mut name = s.identity.name.clone();
        name.truncate(28);
        let dc = match s.identity.dc {
            DcCapability::SystemTime if s.identity.position == b.reference => "reference",
            DcCapability::SystemTime => "system time",
            DcCapability::ReceiveTimes => "rx times",
            DcCapability::None => "none",
        };
        println!(
            "{:>3}  {:#07x}  {:<28} {:>12}  {:>10}",
            s.identity.position,
            s.identity.station,
            name,
            s.delay_ns.map_or("-".to_string(), |d| format!("{d:.1}")),
            dc
        );
    }
    match (b.converged, b.time_to_lock_ms) {
        (true, Some(t)) => println!(
            "DC locked {t:.1} ms after drift compensation began; {} after lock {} ns.",
            if b.max_abs_092c_by_broadcast {
                "|0x092C| by one broadcast (the OR of every slave's: a bound on the largest)"
            } else {
                "largest |0x092C|"
            },
            b.max_abs_092c_after_lock_ns
        ),
        _ => println!("DC did NOT lock."),
    }
}

/// The cyclic phase's summary as text: what ran and what went wrong, what happened to the
/// drives and the link, the figures, and where t_ms came from.
pub(super) fn print_run(o: &RunOut) {
    println!();
    println!(
        "{} cycles of {} at {} us on {} in {:.1} s ({}); {} skipped by host stalls, {} frames lost, {} replies after their cycle's deadline, {} duplicate replies, {} bad working counters.",
        o.cycles,
        o.method,
        o.cycle_ns / 1000,
        o.iface,
        o.duration_s,
        o.stopped,
        o.skipped_cycles,
        o.lost_frames,
        o.late_replies,
        o.duplicate_replies,
        o.bad_wkc
    );
    if let Some(r) = &o.redundancy {
        println!(
            "Ring (second port {}): {} frames round the whole ring, {} made of both sides' copies, {} with one copy back; broken {} times, whole again {} times{}.",
            r.ring_iface,
            r.intact,
            r.merged,
            r.partial,
            r.breaks,
            r.restores,
            if r.broken_at_end {
                ", broken at the end"
            } else {
                ""
            }
        );
    }
    print_run_events(o);
    print_run_figures(o);
    print_t_ms(o);
    if let Some(p) = &o.csv {
        println!("per-cycle CSV: {p}");
    }
    for w in &o.warnings {
        println!();
        println!("Warning: {w}");
    }
}

/// The drives recovered, out of OP and hot-connected, the SM events they missed, and what went
/// wrong on the link (the reference's time gone, the interface down, a second responder).
fn print_run_events(o: &RunOut) {
    for r in o.recoveries.iter().filter(|r| !r.slaves.is_empty()) {
        let why = if r.left_op.is_empty() {
            String::new()
        } else {
            format!(" ({})", r.left_op.join("; "))
        };
        println!(
            "Recovered slave(s) {} (reset or out of OP: configured again; 1 = next to the master) at {:.3} s, in {:.0} ms{why}.",
            r.slaves
                .iter()
                .map(u16::to_string)
                .collect::<Vec<_>>()
                .join(", "),
            r.start_s,
            r.end_s.map_or(f64::NAN, |e| (e - r.start_s) * 1e3)
        );
    }
    for l in &o.left_op {
        println!(
            "Drive {} left OP for {} with AL status code {} at {:.3} s{}.",
            l.slave,
            l.state,
            l.reason,
            l.found_s,
            match l.back_in_op_s {
                Some(t) => format!(", back in OP at {t:.3} s"),
                None => ", not back in OP by the end".to_string(),
            }
        );
    }
    if let Some(r) = o.recoveries.iter().find(|r| r.appeared > 0) {
        println!(
            "{} slave(s) appeared at the end of the network at {:.3} s (hot connect): counted, not taken in (bring the network up again to use them).",
            r.appeared, r.start_s
        );
    }
    if !o.sm_events_missed.is_empty() {
        let missed: Vec<String> = o
            .sm_events_missed
            .iter()
            .map(|c| format!("{}: {}", c.position, c.missed_between_reads))
            .collect();
        let total: u64 = o
            .sm_events_missed
            .iter()
            .map(|c| u64::from(c.missed_between_reads))
            .sum();
        println!(
            "SM events missed (0x1C32:0B, the drives' own count of SYNC0 cycles without new outputs, between its reads {:.1} s and {:.1} s in){}; by slave, 1 = next to the master: {}",
            o.sm_events_missed
                .iter()
                .map(|c| c.first_read_s)
                .fold(f64::INFINITY, f64::min),
            o.sm_events_missed
                .iter()
                .map(|c| c.read_s)
                .fold(0.0, f64::max),
            if total > 0 {
                " -- SYNC0 came before the outputs: a SYNC0 shift too small for this host's jitter, or frames lost"
            } else {
                ""
            },
            missed.join(", ")
        );
    }
    if o.reference_held_cycles > 0 {
        println!(
            "The reference's time was gone or not believed in {} cycles: the method held over meanwhile.",
            o.reference_held_cycles
        );
    }
    if o.link_down_errors > 0 {
        println!(
            "The interface was down or refused frames {} times (frames lost meanwhile; the run went on).",
            o.link_down_errors
        );
    }
    if o.duplicate_replies * 2 > o.cycles {
        println!(
            "A second responder: {} of {} cycles' frames were answered twice (two segments on the wire, or a loop).",
            o.duplicate_replies, o.cycles
        );
    }
}

/// The errors (M-rS, rS-IS), the task's wake-up and send latencies, spinning's cost, the round
/// trip and the kernel's send path, us.
fn print_run_figures(o: &RunOut) {
    let us = |x: f64| x / 1e3;
    println!(
        "{:<22} {:>10} {:>10} {:>10} {:>10}",
        "us", "mean", "std", "max", "min"
    );
    let none = [
        "the run stopped before the method's initialisation (--init-s) ended",
        "no cycle came back with it",
    ];
    for (i, (name, s)) in [("M-rS", &o.m_rs), ("rS-IS |0x092C|", &o.rs_is)]
        .into_iter()
        .enumerate()
    {
        if s.n == 0 {
            // Not NaNs: a run stopped before its method's initialisation ended has no M-rS.
            println!("{name:<22} none measured: {}", none[i]);
            continue;
        }
        println!(
            "{:<22} {:>10.3} {:>10.3} {:>10.3} {:>10.3}",
            name,
            us(s.mean),
            us(s.std),
            us(s.max),
            us(s.min)
        );
    }
    if o.m_rs.mean.abs() > 1000.0_f64.max(2.0 * o.m_rs.std) {
        // Users read a large mean as a large error; it is where the method aims.
        println!(
            "(M-rS counts from h_mr, the mean phase of the init frames (the letter's eq. 10): a method that aims at the target phase on the DC grid sits a constant {:.1} us from it by aim, not by error; its spread (std) is the sync's)",
            us(o.m_rs.mean)
        );
    }
    let w = &o.wake_latency;
    println!(
        "wake-up latency, us:   p50 {:.1}  p99 {:.1}  p99.9 {:.1}  max {:.1}",
        w.p50_us, w.p99_us, w.p999_us, w.max_us
    );
    for (name, l) in [
        ("sleeping", &o.send.wake_to_send_plain),
        ("spinning", &o.send.wake_to_send_spin),
    ] {
        if let Some(l) = l {
            println!(
                "wake to send ({name}), us: p50 {:.1}  p99 {:.1}  p99.9 {:.1}  max {:.1}",
                l.p50_us, l.p99_us, l.p999_us, l.max_us
            );
        }
    }
    if let Some(m) = o.send.spin_margin_us {
        println!(
            "spin: {m} us margin, {:.1} % of a core ({:.1} us per spinning cycle){}",
            o.send.spin_cpu_pct,
            o.send.spin_us_per_cycle,
            o.send
                .spin_over_plain_p99
                .map_or(String::new(), |r| format!(
                    ", p99 spinning / sleeping {r:.3}"
                ))
        );
    }
    println!(
        "round trip, us:        mean {:.1}  p99 {:.1}  max {:.1}",
        us(o.round_trip.mean),
        us(o.round_trip.p99_abs),
        us(o.round_trip.max_abs)
    );
    if o.tx_path.n > 0 {
        println!(
            "send to kernel TX timestamp, us: mean {:.1}  std {:.1}  max {:.1}",
            us(o.tx_path.mean),
            us(o.tx_path.std),
            us(o.tx_path.max)
        );
    }
}

/// Where t_ms came from (`--tx-stamp`), and why auto settled for less.
fn print_t_ms(o: &RunOut) {
    let t = &o.t_ms;
    let source = match t.source {
        TxStampSource::SendTimestamp => "the send timestamp (before the send)",
        TxStampSource::KernelSoftware => "the kernel's software transmit stamp",
        TxStampSource::NicHardware => "the NIC's hardware transmit stamp",
    };
    print!("t_ms (--tx-stamp {}): {source}", t.mode);
    if t.source != TxStampSource::SendTimestamp {
        print!(
            ", {} cycles ({} without a stamp kept the send timestamp)",
            t.cycles_from_tx_stamp, t.cycles_without_tx_stamp
        );
    }
    println!();
    if let Some(n) = &t.note {
        println!("  ({n})");
    }
}

/// What `run` says when a signal stopped its bring-up, given the phases it had started (in
/// order; the last one was in progress): the ones done, and what they had measured, which is
/// not reported (the bring-up was not done, no summary is written).
pub(super) fn stopped_in_bring_up(started: &[Phase]) -> String {
    let Some((now, done)) = started.split_last() else {
        return "ecsync run: stopped before the bring-up began; nothing measured, nothing written"
            .to_string();
    };
    if done.is_empty() {
        return format!(
            "ecsync run: stopped during the bring-up, in its first phase ({now}); nothing measured, nothing written"
        );
    }
    let names: Vec<&str> = done.iter().map(|p| p.name()).collect();
    // The phases whose results are measurements (the rest write or change states).
    let measured: Vec<&str> = done
        .iter()
        .filter_map(|p| match p {
            Phase::Scan => Some("the slave count"),
            Phase::Identify => Some("each slave's identity and DC"),
            Phase::Delays => Some("the propagation delays"),
            Phase::StaticDrift => Some("the lock of the clocks"),
            _ => None,
        })
        .collect();
    format!(
        "ecsync run: stopped during the bring-up, in its {now} phase, after {} (measured: {}); the bring-up was not done, so nothing is reported or written",
        names.join(", "),
        measured.join(", ")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_after_the_delays_says_they_were_measured() {
        let t = stopped_in_bring_up(&[
            Phase::Scan,
            Phase::Identify,
            Phase::Delays,
            Phase::Offsets,
            Phase::StaticDrift,
        ]);
        assert!(t.contains("in its drift phase"), "{t}");
        assert!(t.contains("after scan, identify, delays, offsets"), "{t}");
        assert!(t.contains("the propagation delays"), "{t}");
        assert!(!t.contains("the lock"), "the drift phase was not done: {t}");
        assert!(!t.contains("nothing measured"), "{t}");
    }

    #[test]
    fn a_stop_in_the_scan_measured_nothing() {
        assert!(stopped_in_bring_up(&[Phase::Scan]).contains("nothing measured"));
        assert!(stopped_in_bring_up(&[]).contains("nothing measured"));
        assert!(!stopped_in_bring_up(&[Phase::Scan, Phase::Identify]).contains("delays"));
    }
}
