//! The twin of a network (`ecsync_sim::twin`) against the simulator's ground truth: a
//! segment of lines and a junction with crystals within +-50 ppm is brought up, its twin written
//! to TOML, parsed as `compare`/`bringup`/`serve --config` parse it, and brought up again. The
//! twin must have the original's models, topology and ports, its true delays within 20 ns of the
//! original's true delays, and its crystals within 0.1 ppm of the original's against the
//! reference. The truth is the original segment's, never what the master measured.

mod common;

use common::Rng;

use ecsync_master::{BringupConfig, Engine, Network, Stage, bringup};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::config::parse_segment;
use ecsync_sim::model::{DcSupport, DeviceInfo, EscModel};
use ecsync_sim::transport::SimTransport;
use ecsync_sim::twin::twin_toml;
use ecsync_sim::{Segment, SlaveSpec, Upstream};

/// (model name, model) of the line slaves.
fn line_model(r: &mut Rng) -> (&'static str, EscModel) {
    match r.below(4) {
        0 => ("servo-mii", EscModel::servo_mii()),
        1 => ("servo-mii-dc32", EscModel::servo_mii_dc32()),
        2 => ("ebus-terminal", EscModel::ebus_terminal(DcSupport::Full64)),
        _ => (
            "ebus-terminal-no-dc",
            EscModel::ebus_terminal(DcSupport::None),
        ),
    }
}

/// A reference drive, a short line, a four-port junction with a line on each of ports 3, 1
/// and 2 (port 3 first in processing order), and a line after the junction's last branch.
fn segment(seed: u64) -> (Vec<SlaveSpec>, Vec<&'static str>) {
    let mut r = Rng::new(seed);
    let mut specs: Vec<SlaveSpec> = Vec::new();
    let mut names = Vec::new();
    let mut push = |specs: &mut Vec<SlaveSpec>,
                    r: &mut Rng,
                    (name, model): (&'static str, EscModel),
                    upstream: Upstream| {
        let i = specs.len();
        specs.push(SlaveSpec {
            model,
            device: DeviceInfo::servo_drive(i as u32 + 1),
            crystal: CrystalParams {
                ppm: r.f(-50.0, 50.0),
                initial_local_ns: r.next() >> 20,
                seed: seed + i as u64,
                ..CrystalParams::default()
            },
            upstream,
            entry_port: 0,
            cable_m: r.f(0.2, 20.0),
            ring: None,
        });
        names.push(name);
        i
    };
    let mut last = push(
        &mut specs,
        &mut r,
        ("servo-mii", EscModel::servo_mii()),
        Upstream::Master,
    );
    for _ in 0..1 + r.below(3) {
        let m = ("servo-mii", EscModel::servo_mii());
        last = push(
            &mut specs,
            &mut r,
            m,
            Upstream::Slave {
                index: last,
                port: 1,
            },
        );
    }
    let junction = push(
        &mut specs,
        &mut r,
        ("junction-mii", EscModel::junction_mii()),
        Upstream::Slave {
            index: last,
            port: 1,
        },
    );
    for port in [3u8, 1, 2] {
        let mut up = (junction, port);
        for _ in 0..1 + r.below(3) {
            let m = line_model(&mut r);
            let i = push(
                &mut specs,
                &mut r,
                m,
                Upstream::Slave {
                    index: up.0,
                    port: up.1,
                },
            );
            up = (i, 1);
        }
    }
    (specs, names)
}

/// Brought up to the delays, the crystals measured over 2 s, the SII's details read.
fn bring_up(specs: &[SlaveSpec]) -> (Network, Segment) {
    let seg = Segment::new(specs).expect("valid segment");
    let mut sim = SimTransport::new(seg);
    let cfg = BringupConfig {
        until: Stage::Delays,
        rate_window_ns: 2_000_000_000,
        read_sii_details: true,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .expect("bring-up to the delays");
    let seg = Segment::new(specs).expect("valid segment");
    (net, seg)
}

/// Each slave's configured crystal against the reference's, ppm (network order).
fn relative_ppm(seg: &Segment, reference: usize) -> Vec<Option<f64>> {
    let ppm = |i: usize| seg.esc(i).dc().map(|d| d.clock().params().ppm);
    (0..seg.len())
        .map(|i| match (ppm(i), ppm(reference)) {
            (Some(p), Some(r)) => Some(((1.0 + p * 1e-6) / (1.0 + r * 1e-6) - 1.0) * 1e6),
            _ => None,
        })
        .collect()
}

#[test]
fn a_twin_has_the_original_s_delays_models_ports_and_crystals() {
    let (mut worst_delay_ns, mut worst_ppm, mut slaves) = (0.0f64, 0.0f64, 0usize);
    for seed in [1u64, 2, 3, 4] {
        let (specs, names) = segment(seed);
        let (net, seg) = bring_up(&specs);
        let reference = usize::from(net.reference);
        let truth = seg.true_delays_ns(reference);
        let truth_ppm = relative_ppm(&seg, reference);
        let twin = twin_toml(&net, "the simulator", None).expect("a twin");
        let twin_specs = parse_segment("twin.toml", &twin.toml)
            .unwrap_or_else(|e| panic!("the twin does not parse: {e}\n{}", twin.toml));
        let (net2, seg2) = bring_up(&twin_specs);
        assert_eq!(usize::from(net2.reference), reference, "seed {seed}");
        let truth2 = seg2.true_delays_ns(reference);
        let truth2_ppm = relative_ppm(&seg2, reference);
        assert_eq!(net2.slaves.len(), specs.len());
        for (pos, (a, b)) in net.slaves.iter().zip(&net2.slaves).enumerate() {
            let what = format!("seed {seed}, slave {pos}\n{}", twin.toml);
            // The segment keeps the spec order here (each slave listed after its upstream, in
            // processing order), so the names line up by position.
            assert_eq!(seg.spec_index(pos), pos, "{what}");
            assert_eq!(twin.models[pos], names[pos], "{what}");
            assert_eq!(seg2.esc(pos).model(), seg.esc(pos).model(), "{what}");
            assert_eq!((b.parent, b.entry_port), (a.parent, a.entry_port), "{what}");
            assert_eq!(b.port_descriptor, a.port_descriptor, "{what}");
            assert_eq!(
                (b.vendor_id, b.product_code, b.revision, b.serial, &b.name),
                (a.vendor_id, a.product_code, a.revision, a.serial, &a.name),
                "{what}"
            );
            if a.delay_ns.is_some() {
                let (t, t2) = (truth[pos].expect("reached"), truth2[pos].expect("reached"));
                worst_delay_ns = worst_delay_ns.max((t2 - t).abs());
                assert!(
                    (t2 - t).abs() <= 20.0,
                    "{what}: twin's delay {t2:.1} ns, original's {t:.1} ns"
                );
            }
            if let Some(p) = truth_ppm[pos] {
                let p2 = truth2_ppm[pos].expect("the twin has the crystal");
                worst_ppm = worst_ppm.max((p2 - p).abs());
                assert!(
                    (p2 - p).abs() <= 0.1,
                    "{what}: twin's crystal {p2:+.4} ppm against the reference, original's {p:+.4}"
                );
            }
            slaves += 1;
        }
    }
    eprintln!(
        "{slaves} slaves over 4 segments: worst delay error {worst_delay_ns:.1} ns, worst relative crystal error {worst_ppm:.4} ppm"
    );
}

/// The twin of the captures' network (presets/ek1100-el2828-el2889.toml): the EL2828 reads
/// 0x0008 = 0x01FC, DC bits set, as the EL2889's ET1200 with a system time does (less bit 8),
/// yet the master finds receive times only: its twin gets the model with its registers and
/// receive times only (the EL2889's 0x00FC is the el2889 model's alone), and the twin's
/// bring-up finds the same clocks.
#[test]
fn a_receive_times_terminal_is_twinned_with_receive_times() {
    let name = "ek1100-el2828-el2889";
    let specs = parse_segment(name, ecsync_sim::preset::named(name).expect("the preset"))
        .expect("the preset is valid");
    let (net, _) = bring_up(&specs);
    let twin = twin_toml(&net, "the simulator", None).expect("a twin");
    assert_eq!(
        twin.models,
        ["et1100-coupler", "et1200-terminal-receive-times", "el2889"],
        "{}",
        twin.toml
    );
    let twin_specs = parse_segment("twin.toml", &twin.toml).expect("the twin parses");
    let (net2, _) = bring_up(&twin_specs);
    let dc = |n: &Network| n.slaves.iter().map(|s| s.dc).collect::<Vec<_>>();
    assert_eq!(dc(&net2), dc(&net));
    assert_eq!(
        twin_specs.iter().map(|s| s.model.dc).collect::<Vec<_>>(),
        [
            DcSupport::Full64,
            DcSupport::ReceiveTimes,
            DcSupport::Full64
        ]
    );
}
