//! The master identifies clocks by what answers, not by 0x0008 (issue 32 point 2): a slave keeps
//! a system time when its read of the system time's registers counts. Devices with receive times
//! only set 0x0008's DC bit all the same, as the EL2828, EL1004, EK1914 and EL3004 do
//! (../shared/captures/README.md): they get their propagation delays and take part in the
//! topology, but are neither the reference nor synchronised. Checked on the captures' network
//! (EK1100, EL2828, EL2889) and on random networks mixing every DC kind, against the segment's
//! ground truth: which unit each slave has, the true delays, the clocks' true system times.

mod common;

use common::Rng;

use ecsync_master::bringup::{DcCapability, EsiTiming, Network};
use ecsync_master::{BringupConfig, Engine, MasterError, Stage, bringup};
use ecsync_sim::catalog;
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel, PortKind};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::{Segment, SlaveSpec, Upstream};
use ecsync_wire::register::features;

/// A bring-up up to the lock, shortened where it does not matter here (2 000 static drift
/// frames, 20 checks held), the ESCs' forwarding and processing delays known to the master as
/// an ESI would give them (`specs`' models by their devices' identities): ESCs of different
/// kinds (an ET1100 coupler's 107.5 ns out, an ET1200's 145 ns back) make a round trip
/// asymmetric, which no latch shows.
fn to_lock(specs: &[SlaveSpec]) -> BringupConfig {
    BringupConfig {
        until: Stage::Lock,
        static_drift_frames: 2_000,
        lock_hold_checks: 20,
        esi: specs
            .iter()
            .map(|s| EsiTiming {
                vendor_id: s.device.vendor_id,
                product_code: s.device.product_code,
                forwarding_ns: s.model.forwarding_delay_ns.round() as i32,
                processing_ns: s.model.processing_delay_ns.round() as i32,
            })
            .collect(),
        ..BringupConfig::default()
    }
}

fn run(specs: &[SlaveSpec], cfg: BringupConfig) -> (SimTransport, Result<Network, MasterError>) {
    let mut sim = SimTransport::new(Segment::new(specs).expect("a valid segment"));
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let r = sim.run_procedure(&mut engine, |_, _, _| {});
    (sim, r)
}

/// The capability the master should find: the model's DC unit.
fn expected(dc: DcSupport) -> DcCapability {
    match dc {
        DcSupport::None => DcCapability::None,
        DcSupport::ReceiveTimes => DcCapability::ReceiveTimes,
        DcSupport::Full32 | DcSupport::Full64 => DcCapability::SystemTime,
    }
}

/// Every slave's system time at the transport's last instant, by the truth (`None` without
/// one): whole ns and fraction.
fn true_system_times(sim: &SimTransport) -> Vec<Option<(u64, f64, bool)>> {
    let seg = sim.segment();
    (0..seg.len())
        .map(|i| {
            let esc = seg.esc(i);
            let dc = esc.dc().filter(|_| esc.model().dc.has_system_time())?;
            let (ns, frac) = dc.system_time_split(sim.now_ps());
            Some((ns, frac, dc.is_64bit()))
        })
        .collect()
}

/// `a - b` of two true system times, ns, on 32 bits when either is 32 bits wide.
fn difference_ns(a: (u64, f64, bool), b: (u64, f64, bool)) -> f64 {
    let whole = if a.2 && b.2 {
        a.0.wrapping_sub(b.0) as i64
    } else {
        i64::from(a.0.wrapping_sub(b.0) as u32 as i32)
    };
    whole as f64 + (a.1 - b.1)
}

/// What every network must show after the bring-up to the lock: each slave's capability as its
/// model has it, the reference the first slave with a system time, offsets written to exactly
/// the slaves with one (and nothing written to the others' DC units), every delay within
/// `tolerance_ns` of the truth, and every system time within the lock threshold of the
/// reference's by the truth. Returns the worst delay error, ns.
fn assert_clocks_by_answer(
    what: &str,
    sim: &SimTransport,
    net: &Network,
    threshold_ns: u32,
    tolerance_ns: f64,
) -> f64 {
    let seg = sim.segment();
    let kinds: Vec<DcSupport> = (0..seg.len()).map(|i| seg.esc(i).model().dc).collect();
    let found: Vec<DcCapability> = net.slaves.iter().map(|s| s.dc).collect();
    let want: Vec<DcCapability> = kinds.iter().map(|&d| expected(d)).collect();
    assert_eq!(found, want, "{what}: capabilities by position");
    let first = kinds
        .iter()
        .position(|d| d.has_system_time())
        .expect("a system time");
    assert_eq!(usize::from(net.reference), first, "{what}: the reference");
    let truth = seg.true_delays_ns(first);
    let mut worst = 0.0f64;
    for (i, s) in net.slaves.iter().enumerate() {
        let esc = seg.esc(i);
        assert_eq!(
            s.offset.is_some(),
            kinds[i].has_system_time(),
            "{what}: slave {i} ({:?}) synchronised",
            kinds[i]
        );
        if kinds[i] == DcSupport::ReceiveTimes {
            let dc = esc.dc().expect("receive times");
            assert_eq!(
                (dc.offset(), dc.delay()),
                (0, 0),
                "{what}: slave {i} untouched"
            );
        }
        match (s.delay_ns, truth[i]) {
            (Some(d), Some(t)) => {
                worst = worst.max((d - t).abs());
                assert!(
                    (d - t).abs() <= tolerance_ns,
                    "{what}: slave {i} delay {d:.1}, true {t:.1}"
                );
            }
            (None, _) => assert_eq!(kinds[i], DcSupport::None, "{what}: slave {i} has a delay"),
            (Some(_), None) => panic!("{what}: slave {i} has no true delay"),
        }
    }
    assert!(net.lock.converged, "{what}: locked");
    let times = true_system_times(sim);
    let r = times[first].expect("the reference's time");
    for (i, t) in times.iter().enumerate() {
        if let Some(t) = t {
            let d = difference_ns(*t, r);
            assert!(
                d.abs() <= f64::from(threshold_ns),
                "{what}: slave {i} {d:.0} ns from the reference by the truth"
            );
        }
    }
    worst
}

/// How far a measured delay may be from the truth, ns: 20 (the master's averaged latches, as
/// tests/topologies.rs holds them), 25 on a network with an ESC whose ports stamp on different
/// grids (an EK1100's MII ports on 40 ns, its EBUS port on 10 ns: a span between them carries
/// the difference of the grids' rounding, which the dithered rounds do not average away; 21 ns
/// at worst in the random networks below, 7 without such an ESC).
fn delay_tolerance_ns(specs: &[SlaveSpec]) -> f64 {
    let mixed = specs.iter().any(|s| {
        let k = |kind| s.model.ports.contains(&kind);
        k(PortKind::Mii) && k(PortKind::Ebus)
    });
    if mixed { 25.0 } else { 20.0 }
}

/// The captures' network (EK1100, EL2828, EL2889 in a line, the EL2889's crystal +2.24 ppm
/// against the EK1100's as the captures show): the EL2828 reads 0x0008 with its DC bit set and
/// has no system time. The master makes the EK1100 the reference and synchronises the EL2889
/// alone; the EL2828 gets its delay.
#[test]
fn the_captured_network_has_the_ek1100_as_reference_and_syncs_the_el2889_alone() {
    let devices = [
        (catalog::ek1100_model(), catalog::ek1100(1), 0.0),
        (catalog::el2828_model(), catalog::el2828(2), -1.3),
        (catalog::el2889_model(), catalog::el2889(3), 2.24),
    ];
    let specs: Vec<SlaveSpec> = devices
        .into_iter()
        .enumerate()
        .map(|(i, (model, device, ppm))| SlaveSpec {
            model,
            device,
            crystal: CrystalParams {
                ppm,
                initial_local_ns: 1_000_000_000 + 777_777_777 * i as u64,
                seed: i as u64,
                ..CrystalParams::default()
            },
            upstream: Upstream::in_line(i),
            entry_port: 0,
            cable_m: if i == 0 { 2.0 } else { 0.0 },
            ring: None,
        })
        .collect();
    let cfg = to_lock(&specs);
    let threshold = cfg.lock_threshold_ns;
    let (sim, net) = run(&specs, cfg);
    let net = net.expect("bring-up to the lock");
    // The EL2828 says DC in 0x0008, as the real one does, and is found without a system time.
    let el2828 = &net.slaves[1];
    assert_eq!(el2828.features, 0x01fc);
    assert_ne!(el2828.features & features::DC, 0);
    assert_eq!(el2828.dc, DcCapability::ReceiveTimes);
    assert_eq!(net.reference, 0, "the EK1100");
    let tolerance = delay_tolerance_ns(&specs);
    let worst = assert_clocks_by_answer("EK1100-EL2828-EL2889", &sim, &net, threshold, tolerance);
    eprintln!(
        "delays {:?} ns, worst error {worst:.1} ns, lock after {:?} ns",
        net.slaves.iter().map(|s| s.delay_ns).collect::<Vec<_>>(),
        net.lock.time_to_lock_ns
    );
}

/// The delays ethercrab wrote to 0x0928 of the real devices (FPWR 0x0928 in `file`), by
/// station.
fn captured_delays(file: &str) -> Vec<(u16, u32)> {
    common::read_pcapng(&common::captures_dir().join(file))
        .iter()
        .filter(|f| !common::has_returned(&f.data))
        .flat_map(|f| common::datagrams(&f.data))
        .filter(|d| d.command == ecsync_wire::Command::Fpwr.code() && d.ado == 0x0928)
        .map(|d| (d.adp, common::u32_of(&d.data)))
        .collect()
}

/// Without ESI timings, as a master meets real Beckhoff terminals (their ESIs give no
/// forwarding and processing delays), ecsync's delays on the preset of the captured network
/// are what ethercrab measured on the real devices (its 0x0928 writes in three captures: the
/// EL2828 140-145 ns, the EL2889 295-300 ns), within 10 ns of their mean: the model's EK1100
/// and terminals give the real devices' receive times.
#[test]
#[ignore = "needs ../shared/captures"]
fn delays_on_the_preset_are_those_ethercrab_measured_on_the_real_devices() {
    let real: Vec<(u16, u32)> = [
        "replay-dc.pcapng",
        "replay-issue-255.pcapng",
        "replay-ek1100-el2828-el2889.pcapng",
    ]
    .iter()
    .flat_map(|f| captured_delays(f))
    .collect();
    assert_eq!(real.len(), 9, "three writes in each capture");
    let name = "ek1100-el2828-el2889";
    let specs = ecsync_sim::config::parse_segment(
        name,
        ecsync_sim::preset::named(name).expect("the preset"),
    )
    .expect("the preset is valid");
    let cfg = BringupConfig {
        esi: Vec::new(),
        ..to_lock(&specs)
    };
    let (_, net) = run(&specs, cfg);
    let net = net.expect("bring-up to the lock");
    for s in &net.slaves {
        let theirs: Vec<f64> = real
            .iter()
            .filter(|(station, _)| *station == s.station)
            .map(|&(_, d)| f64::from(d))
            .collect();
        let mean = theirs.iter().sum::<f64>() / theirs.len() as f64;
        let mine = s.delay_ns.expect("a delay");
        eprintln!(
            "{}: ecsync {mine:.1} ns, ethercrab on the real devices {theirs:?}",
            s.name
        );
        assert!(
            (mine - mean).abs() <= 10.0,
            "{}: {mine:.1} vs {mean:.1}",
            s.name
        );
    }
}

/// The same terminals with the EL2828 first: the reference is the first slave that keeps a
/// system time, not the first that says DC.
#[test]
fn a_receive_times_slave_first_is_not_the_reference() {
    let specs: Vec<SlaveSpec> = [
        (catalog::el2828_model(), catalog::el2828(1), 20.0),
        (catalog::el2889_model(), catalog::el2889(2), -30.0),
        (catalog::el2889_model(), catalog::el2889(3), 45.0),
    ]
    .into_iter()
    .enumerate()
    .map(|(i, (model, device, ppm))| SlaveSpec {
        model,
        device,
        crystal: CrystalParams {
            ppm,
            initial_local_ns: 3_000_000_000 + 1_234_567 * i as u64,
            seed: 10 + i as u64,
            ..CrystalParams::default()
        },
        upstream: Upstream::in_line(i),
        entry_port: 0,
        cable_m: 0.0,
        ring: None,
    })
    .collect();
    let cfg = to_lock(&specs);
    let threshold = cfg.lock_threshold_ns;
    let (sim, net) = run(&specs, cfg);
    let net = net.expect("bring-up to the lock");
    assert_eq!(net.reference, 1);
    assert_clocks_by_answer("EL2828-EL2889-EL2889", &sim, &net, threshold, 20.0);
}

/// A random network of `n` slaves: lines, trees or stars of servo drives (ET1100, MII), EBUS
/// terminals (ET1200) and junctions (ET1100s with three or four MII ports, or an EK1100's MII,
/// EBUS and MII), each on a port of its own kind (an EBUS terminal on an EBUS port), with a DC
/// unit drawn from every kind (junctions at least receive times, as the datasheet requires of
/// ESCs with more than two ports), crystals within +-50 ppm.
fn random_network(r: &mut Rng, n: usize) -> Vec<SlaveSpec> {
    let shape = r.below(3);
    let mut specs: Vec<SlaveSpec> = Vec::with_capacity(n);
    let mut free: Vec<Vec<u8>> = Vec::with_capacity(n);
    for i in 0..n {
        let (upstream, kind) = if i == 0 {
            (Upstream::Master, PortKind::Mii)
        } else {
            let candidates: Vec<usize> = (0..i).filter(|&k| !free[k].is_empty()).collect();
            let Some(&last) = candidates.last() else {
                break;
            };
            let parent = match shape {
                0 => last,
                1 if !free[0].is_empty() => 0,
                1 => last,
                _ => candidates[r.below(candidates.len() as u64) as usize],
            };
            let k = r.below(free[parent].len() as u64) as usize;
            let port = free[parent].remove(k);
            let kind = specs[parent].model.ports[usize::from(port)];
            (
                Upstream::Slave {
                    index: parent,
                    port,
                },
                kind,
            )
        };
        let junction = kind == PortKind::Mii
            && match shape {
                0 => false,
                1 => i == 0,
                _ => r.below(4) == 0,
            };
        let dc = match (junction, r.below(4)) {
            (false, 0) => DcSupport::None,
            (_, 1) | (true, 0) => DcSupport::ReceiveTimes,
            (_, 2) => DcSupport::Full32,
            _ => DcSupport::Full64,
        };
        let mut model = match (kind, junction, r.below(3)) {
            (PortKind::Ebus, _, _) => EscModel::ebus_terminal(dc),
            (_, true, 0) => catalog::ek1100_model(),
            (_, true, 1) => {
                let mut m = EscModel::junction_mii();
                m.ports[2] = PortKind::None;
                m
            }
            (_, true, _) => EscModel::junction_mii(),
            _ => EscModel::servo_mii(),
        };
        model.dc = dc;
        free.push(
            [3u8, 1, 2]
                .into_iter()
                .filter(|&p| model.ports[usize::from(p)] != PortKind::None)
                .collect(),
        );
        specs.push(SlaveSpec {
            model,
            // A product of its own, for the ESI timing of its model.
            device: DeviceInfo {
                product_code: 0x1000 + i as u32,
                ..DeviceInfo::coupler("random", i as u32 + 1)
            },
            crystal: CrystalParams {
                ppm: r.f(-50.0, 50.0),
                initial_local_ns: r.next() >> 4,
                seed: r.next(),
                ..CrystalParams::default()
            },
            upstream,
            entry_port: 0,
            cable_m: if kind == PortKind::Ebus {
                0.0
            } else {
                r.f(0.1, 20.0)
            },
            ring: None,
        });
    }
    specs
}

/// 40 random networks of 1 to 24 slaves: on each, the master finds every slave's DC unit by
/// what answers, makes the first slave with a system time the reference, synchronises exactly
/// the slaves with one, measures every delay within 20 ns of the truth and locks (every system
/// time within the lock threshold of the reference's by the truth). A network without any
/// system time has no reference: the bring-up says so.
#[test]
fn random_networks_of_every_dc_kind_sync_exactly_the_system_time_slaves() {
    let mut r = Rng::new(0x32_c10c);
    let (mut networks, mut without, mut worst) = (0, 0, 0.0f64);
    let mut kinds = [0usize; 4];
    for k in 0..40 {
        let n = 1 + r.below(24) as usize;
        let specs = random_network(&mut r, n);
        let cfg = to_lock(&specs);
        let threshold = cfg.lock_threshold_ns;
        let (sim, net) = run(&specs, cfg);
        let what = format!("network {k} ({} slaves)", specs.len());
        if !specs.iter().any(|s| s.model.dc.has_system_time()) {
            let e = net.expect_err("no reference without a system time");
            assert!(
                matches!(e.root(), MasterError::NoReferenceClock),
                "{what}: {e}"
            );
            without += 1;
            continue;
        }
        let net = net.unwrap_or_else(|e| panic!("{what}: {e}"));
        let tolerance = delay_tolerance_ns(&specs);
        worst = worst.max(assert_clocks_by_answer(
            &what, &sim, &net, threshold, tolerance,
        ));
        for s in &specs {
            kinds[s.model.dc as usize] += 1;
        }
        networks += 1;
    }
    eprintln!(
        "{networks} networks locked ({without} without a system time); slaves none/rx times/32/64: \
         {kinds:?}; worst delay error {worst:.1} ns"
    );
    assert!(networks >= 30);
    assert!(
        kinds.iter().all(|&c| c >= 20),
        "every kind drawn: {kinds:?}"
    );
}
