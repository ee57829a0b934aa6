//! Propagation delays over random topologies: the master's measurement (receive time latches
//! averaged over rounds, the tree rebuilt from DL status) against the segment's ground truth
//! (the time a frame's first bit really took from the reference's processing unit to each
//! slave's).
//!
//! Topologies: lines, trees with 3- and 4-port junctions (port 3 branches included), stars; 1 to
//! 64 slaves; random cable lengths, PHY, forwarding and processing delays (tDiff known to the
//! master as its ESI would give it); 2-port slaves without DC mixed in; 32- and 64-bit DC;
//! clocks that wrap their low 32 bits during the measurement.

mod common;

use common::Rng;

use ecsync_master::bringup::EsiTiming;
use ecsync_master::{BringupConfig, Engine, Stage, bringup};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel, PortKind};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use proptest::prelude::*;
use proptest::test_runner::{RngAlgorithm, TestRng, TestRunner};
use std::cell::Cell;

#[derive(Debug, Clone, Copy)]
enum Shape {
    Line,
    Star,
    Tree,
}

#[derive(Debug, Clone)]
struct Gen {
    shape: Shape,
    n: usize,
    seed: u64,
}

fn build(g: &Gen) -> (Vec<SlaveSpec>, Vec<EsiTiming>) {
    let mut r = Rng::new(g.seed);
    let mut specs: Vec<SlaveSpec> = Vec::new();
    let mut esi = Vec::new();
    // Free ports per slave, in the order children should take them.
    let mut free: Vec<Vec<u8>> = Vec::new();
    for i in 0..g.n {
        // Choose the ESC: junctions where the shape wants branching.
        let want_junction = match g.shape {
            Shape::Line => false,
            Shape::Star => i == 0,
            Shape::Tree => r.below(4) == 0,
        };
        let ebus = r.below(3) == 0;
        let kind = if ebus { PortKind::Ebus } else { PortKind::Mii };
        let (ports, dc) = if want_junction {
            let four = r.below(2) == 0;
            let ports = if four {
                [kind; 4]
            } else {
                // 3-port junctions: ports 0, 1, 3 (as an EK1100 with its port 3 branch) or 0, 1, 2.
                if r.below(2) == 0 {
                    [kind, kind, PortKind::None, kind]
                } else {
                    [kind, kind, kind, PortKind::None]
                }
            };
            let dc = if r.below(2) == 0 {
                DcSupport::ReceiveTimes
            } else {
                DcSupport::Full64
            };
            (ports, dc)
        } else {
            let dc = match r.below(10) {
                0 | 1 => DcSupport::None,
                2 => DcSupport::Full32,
                _ => DcSupport::Full64,
            };
            ([kind, kind, PortKind::None, PortKind::None], dc)
        };
        let forwarding = r.f(60.0, 700.0).round();
        let tdiff = if r.below(2) == 0 {
            0
        } else {
            r.below(81) as i32 - 40
        };
        let model = EscModel {
            esc_type: 0x11,
            revision: 0,
            build: 0,
            fmmu_count: 8,
            sm_count: 8,
            ram_kib: 4,
            ports,
            dc,
            forwarding_delay_ns: forwarding,
            processing_delay_ns: (forwarding + f64::from(tdiff)).max(0.0),
            link_phy_delay_ns: if ebus {
                r.f(0.0, 40.0)
            } else {
                r.f(100.0, 500.0)
            },
            sii_read_busy_us: 5.0,
            enhanced_dc_sync: false,
            ..EscModel::servo_mii()
        };
        let mut device = DeviceInfo::coupler("random", i as u32);
        device.product_code = 0x1000 + i as u32;
        esi.push(EsiTiming {
            vendor_id: device.vendor_id,
            product_code: device.product_code,
            forwarding_ns: model.forwarding_delay_ns.round() as i32,
            processing_ns: model.processing_delay_ns.round() as i32,
        });
        // Local clocks: some start just below a 2^32 ns boundary so that their low 32 bits wrap
        // during the bring-up (within the first ~100 ms).
        let initial = if r.below(3) == 0 {
            (r.below(1 << 20) << 32) - r.below(100_000_000)
        } else {
            r.next() >> 4
        };
        let upstream = if i == 0 {
            Upstream::Master
        } else {
            // Attach to a slave with a free port: the last one for lines, the root for stars
            // while it has ports, any for trees.
            let candidates: Vec<usize> = (0..i).filter(|&k| !free[k].is_empty()).collect();
            if candidates.is_empty() {
                break;
            }
            let parent = match g.shape {
                Shape::Line => *candidates.last().unwrap(),
                Shape::Star => {
                    if !free[0].is_empty() {
                        0
                    } else {
                        *candidates.last().unwrap()
                    }
                }
                Shape::Tree => candidates[r.below(candidates.len() as u64) as usize],
            };
            let k = r.below(free[parent].len() as u64) as usize;
            let port = free[parent].remove(k);
            Upstream::Slave {
                index: parent,
                port,
            }
        };
        free.push(
            [3u8, 1, 2]
                .into_iter()
                .filter(|&p| model.ports[usize::from(p)] != PortKind::None)
                .collect(),
        );
        specs.push(SlaveSpec {
            model,
            device,
            crystal: CrystalParams {
                ppm: r.f(-100.0, 100.0),
                wander_ppm_per_sqrt_s: 0.01,
                wander_step_ps: 1_000_000_000,
                initial_local_ns: initial,
                seed: r.next(),
            },
            upstream,
            entry_port: 0,
            cable_m: r.f(0.1, 100.0),
            ring: None,
        });
    }
    (specs, esi)
}

fn topology() -> impl Strategy<Value = Gen> {
    (0u8..3, 1usize..=64, any::<u64>()).prop_map(|(s, n, seed)| Gen {
        shape: match s {
            0 => Shape::Line,
            1 => Shape::Star,
            _ => Shape::Tree,
        },
        n,
        seed,
    })
}

#[test]
fn measured_delays_match_the_ground_truth() {
    // A fixed seed: CI sees the same 500 topologies every run (set PROPTEST_RNG_SEED-free runs
    // by changing the seed here when exploring).
    let mut runner = TestRunner::new_with_rng(
        ProptestConfig {
            cases: 500,
            failure_persistence: None,
            ..ProptestConfig::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[0x5e; 32]),
    );
    let worst = Cell::new(0.0f64);
    let wrapped = Cell::new(0usize);
    let checked = Cell::new(0usize);
    let shapes = Cell::new([0usize; 3]);
    let without_dc = Cell::new(0usize);
    let result = runner.run(&topology(), |g| {
        let (specs, esi) = build(&g);
        // At least one slave must have a system time to act as reference.
        prop_assume!(specs.iter().any(|s| s.model.dc.has_system_time()));
        let seg = Segment::new(&specs).expect("valid topology");
        let mut sim = SimTransport::new(seg);
        let cfg = BringupConfig {
            until: Stage::Delays,
            esi,
            ..BringupConfig::default()
        };
        let mut engine = Engine::new(move |link| bringup(link, cfg));
        let net = sim
            .run_procedure(&mut engine, |_, _, _| {})
            .expect("bring-up to delays");
        let truth = sim.segment().true_delays_ns(usize::from(net.reference));
        prop_assert_eq!(net.slaves.len(), specs.len());
        let mut sh = shapes.get();
        sh[g.shape as usize] += 1;
        shapes.set(sh);
        for s in &net.slaves {
            let pos = usize::from(s.position);
            let esc = sim.segment().esc(pos);
            let spec = &specs[sim.segment().spec_index(pos)];
            if let Some(dc) = esc.dc() {
                // Did this clock's low 32 bits wrap between power-up and the last latch?
                let now = dc.local_ns(sim.now_ps());
                if now >> 32 != spec.crystal.initial_local_ns >> 32 {
                    wrapped.set(wrapped.get() + 1);
                }
            } else {
                without_dc.set(without_dc.get() + 1);
            }
            if let Some(d) = s.delay_ns {
                let t = truth[pos].expect("reached");
                worst.set(worst.get().max((d - t).abs()));
                checked.set(checked.get() + 1);
                prop_assert!(
                    (d - t).abs() <= 20.0,
                    "{:?}: slave {} measured {:.1} ns, true {:.1} ns",
                    g,
                    pos,
                    d,
                    t
                );
            } else {
                prop_assert!(!esc.model().dc.has_system_time());
            }
        }
        Ok(())
    });
    eprintln!(
        "{} delays checked (shapes line/star/tree {:?}), worst error {:.1} ns, {} clocks wrapped their low 32 bits, {} slaves without DC",
        checked.get(),
        shapes.get(),
        worst.get(),
        wrapped.get(),
        without_dc.get()
    );
    if let Err(e) = result {
        panic!("{e}");
    }
    assert!(checked.get() > 5_000);
    assert!(
        wrapped.get() > 100,
        "the clocks must wrap during the measurement"
    );
    assert!(without_dc.get() > 100);
}

/// A slave's system time at one instant: whole ns, the fraction, whether it is 64 bits wide.
type SystemTime = (u64, f64, bool);

/// From the declaration of sync on, through the configuration that follows (PRE-OP, SYNC0,
/// SAFE-OP, OP) and the monitoring, every slave with a system time stays within the lock's
/// 100 ns of the reference by the truth, on random topologies of up to 64 slaves with crystals
/// of +-100 ppm. The truth is sampled every 16th exchange; a 32-bit clock (or a 32-bit
/// reference) is compared on 32 bits. (44 ns at worst in these 32 networks; 133 ns when the
/// bring-up sent no FRMW between the lock and OP, the clocks running free meanwhile.)
#[test]
fn clocks_stay_together_from_the_lock_to_op() {
    let mut runner = TestRunner::new_with_rng(
        ProptestConfig {
            cases: 32,
            failure_persistence: None,
            ..ProptestConfig::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[0x7a; 32]),
    );
    let worst = Cell::new(0.0f64);
    let checked = Cell::new(0usize);
    let result = runner.run(&topology(), |g| {
        let (specs, esi) = build(&g);
        prop_assume!(specs.iter().any(|s| s.model.dc.has_system_time()));
        let mut sim = SimTransport::new(Segment::new(&specs).expect("valid topology"));
        let cfg = BringupConfig {
            until: Stage::Op,
            esi,
            lock_hold_checks: 200,
            monitor_cycles: 100,
            ..BringupConfig::default()
        };
        let mut engine = Engine::new(move |link| bringup(link, cfg));
        // (real time, every slave's system time then: None without one).
        let mut seen: Vec<(u64, Vec<Option<SystemTime>>)> = Vec::new();
        let mut exchanges = 0u64;
        let net = sim
            .run_procedure(&mut engine, |tr, _, _| {
                exchanges += 1;
                if !exchanges.is_multiple_of(16) {
                    return;
                }
                let (seg, t_ps) = (tr.segment(), tr.last_exchange().sent_ps);
                let times = (0..seg.len())
                    .map(|i| {
                        let esc = seg.esc(i);
                        let dc = esc.dc().filter(|_| esc.model().dc.has_system_time())?;
                        let (ns, frac) = dc.system_time_split(t_ps);
                        Some((ns, frac, dc.is_64bit()))
                    })
                    .collect();
                seen.push((t_ps, times));
            })
            .expect("bring-up to OP");
        let reference = usize::from(net.reference);
        let declared_ps = sim.real_ps_at(ecsync_dc::time::MasterInstant::from_ns(
            net.lock.declared_ns.expect("declared in sync"),
        ));
        for (t_ps, times) in seen.iter().filter(|(t, _)| *t >= declared_ps) {
            let Some((r, rf, r_wide)) = times[reference] else {
                continue;
            };
            for (i, x) in times.iter().enumerate() {
                let Some((a, af, wide)) = *x else { continue };
                let whole = if wide && r_wide {
                    a.wrapping_sub(r) as i64
                } else {
                    i64::from((a as u32).wrapping_sub(r as u32) as i32)
                };
                let d = (whole as f64 + (af - rf)).abs();
                worst.set(worst.get().max(d));
                checked.set(checked.get() + 1);
                prop_assert!(
                    d <= 100.0,
                    "{:?}: slave {} {:.1} ns from the reference at {:.3} s",
                    g,
                    i,
                    d,
                    *t_ps as f64 * 1e-12
                );
            }
        }
        Ok(())
    });
    eprintln!(
        "{} slave samples after the lock, worst |slave - reference| {:.1} ns",
        checked.get(),
        worst.get()
    );
    if let Err(e) = result {
        panic!("{e}");
    }
    assert!(checked.get() > 1_000);
}

/// The time a frame's first bit takes round the segment (what the cycle check and the cyclic
/// phase's give-up time use) is when a frame sent into it comes back, on lines, stars and
/// trees alike; in a tree the farthest slave is not half way round (twice its time, the old
/// figure, refused a 2 000-drive tree of 20 lines at 7.7 ms as needing 3.8 ms more).
#[test]
fn the_round_trip_is_when_a_frame_comes_back() {
    let mut runner = TestRunner::new_with_rng(
        ProptestConfig {
            cases: 200,
            failure_persistence: None,
            ..ProptestConfig::default()
        },
        TestRng::from_seed(RngAlgorithm::ChaCha, &[0x7b; 32]),
    );
    let beyond_half_way = Cell::new(0usize);
    let result = runner.run(&topology(), |g| {
        let (specs, _) = build(&g);
        let mut seg = Segment::new(&specs).unwrap();
        let mut buf = vec![0u8; 128];
        let mut b =
            ecsync_wire::FrameBuilder::new(&mut buf, [0xff; 6], [0, 1, 2, 3, 4, 5]).unwrap();
        b.push(
            ecsync_wire::Command::Brd,
            0,
            ecsync_wire::DatagramAddress::Position { adp: 0, ado: 0 },
            &[0, 0],
        )
        .unwrap();
        let n = b.finish();
        let round_ps = seg.round_trip_ps();
        let farthest_ps = seg.pu_offsets_ps().into_iter().flatten().max().unwrap_or(0);
        let t_send_ps = 1_000_000_000;
        let back = seg.process(&mut buf[..n], t_send_ps).returned_sof_ps;
        prop_assert_eq!(back, Some(t_send_ps + round_ps), "{:?}", g);
        if round_ps + 1000 < 2 * farthest_ps {
            beyond_half_way.set(beyond_half_way.get() + 1);
        }
        Ok(())
    });
    result.unwrap();
    // Trees whose farthest slave is not half way round were among them.
    assert!(beyond_half_way.get() > 10, "{}", beyond_half_way.get());
}
