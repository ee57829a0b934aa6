//! The identification reads every slave's SII side by side: its exchanges do not grow with
//! the network (a 2 000-drive line took 550 000 exchanges, 20 minutes of simulated time, when
//! the slaves were read one after the other), and every slave is still identified as the
//! segment made it.

use ecsync_dc::time::MasterInstant;
use ecsync_master::driver::{ExchangeStats, run_procedure};
use ecsync_master::{BringupConfig, Engine, Event, Network, Phase, Stage, bringup};
use ecsync_sim::transport::{SIM_PROCEDURE, SimTransport};
use ecsync_sim::{Segment, preset};

/// Brings a line of `n` drives up to its delays, the SII read in full; returns the network
/// and the identification's exchanges and master time, ns.
fn identify(n: usize) -> (Network, u64, u64) {
    let specs = preset::line(n, 11);
    let mut tr = SimTransport::new(Segment::new(&specs).unwrap());
    let cfg = BringupConfig {
        until: Stage::Delays,
        read_sii_details: true,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |l| bringup(l, cfg));
    let mut stats = ExchangeStats::default();
    // (exchanges, master time) when the identification began, and when the next phase did.
    let mut exchanges = 0u64;
    let mut began: Option<(u64, MasterInstant)> = None;
    let mut ended: Option<(u64, MasterInstant)> = None;
    let net = run_procedure(
        &mut tr,
        &mut engine,
        SIM_PROCEDURE,
        &mut stats,
        |_, x, ev| {
            exchanges += 1;
            for e in ev {
                match e {
                    Event::Phase(Phase::Identify) => began = Some((exchanges, x.sent)),
                    Event::Phase(_) if began.is_some() && ended.is_none() => {
                        ended = Some((exchanges, x.sent));
                    }
                    _ => {}
                }
            }
        },
    );
    let net = match net {
        Ok(r) => r.expect("bring-up"),
        Err(never) => match never {},
    };
    let ((x0, t0), (x1, t1)) = (began.unwrap(), ended.unwrap());
    for (s, spec) in net.slaves.iter().zip(&specs) {
        assert_eq!(
            (s.vendor_id, s.product_code, s.name.as_str()),
            (
                spec.device.vendor_id,
                spec.device.product_code,
                spec.device.name.as_str()
            ),
            "slave {}",
            s.position
        );
        assert!(!s.sms.is_empty(), "slave {}: its SyncManagers", s.position);
    }
    (net, x1 - x0, t1.as_ns() - t0.as_ns())
}

#[test]
fn identification_takes_as_many_exchanges_for_forty_drives_as_for_two() {
    let (small, x_small, t_small) = identify(2);
    let (large, x_large, t_large) = identify(40);
    assert_eq!((small.slaves.len(), large.slaves.len()), (2, 40));
    eprintln!("exchanges {x_small} / {x_large}, master time {t_small} / {t_large} ns");
    // One after the other, forty drives would take twenty times the exchanges of two.
    assert!(
        x_large <= x_small + x_small / 5,
        "{x_large} exchanges for 40 drives against {x_small} for 2"
    );
    // Its time grows with the frames' length on the wire, not by the slaves' number: under
    // half of what twenty times the two drives' would be.
    assert!(
        2 * t_large < 20 * t_small,
        "{t_large} ns for 40 drives against {t_small} for 2"
    );
}
