//! A twin of a brought-up network: the network TOML (`[segment]`, the format of
//! `crate::config`) that `compare`, `bringup` and `serve` run, written from what the
//! master read and measured.
//!
//! - topology: each slave's upstream, upstream port and entry port from the bring-up's tree;
//! - identity: vendor, product, revision, serial and the SII's device name;
//! - ESC model: the one whose ESC type (0x0000), features (0x0008) and port descriptor (0x0007)
//!   the slave shows ([`crate::config::model_for_registers`]); the file says how well each
//!   matched;
//! - delays: the model's internal delays are known, so each slave's `cable_m` is solved for so
//!   that the twin's true propagation delay from the reference is the measured one. A slave's
//!   delay depends only on the links a frame crosses before it reaches that slave, so solving in
//!   network order, one slave at a time, is exact (up to the 5 ps per mm the cable is rounded
//!   to). A measured hop shorter than the model's own is written with no cable, and noted;
//! - crystals: `ppm` is the reference's crystal against the master's clock plus each slave's
//!   against the reference ([`ecsync_master::bringup::measure_clock_rates`]). The relative figures are
//!   the crystals' own; the reference's against the master is as good as the master's send
//!   stamps.

use crate::clock::CrystalParams;
use crate::config::{MODEL_NAMES, ModelMatch, model_for_registers, model_named};
use crate::model::{DcSupport, DeviceInfo, EscModel};
use crate::transport::SimTransport;
use crate::{CABLE_PS_PER_M, Segment, SlaveSpec, Upstream};
use ecsync_master::bringup::{DcCapability, Network, SlaveInfo, Stage};
use ecsync_master::{BringupConfig, Engine};
use std::fmt::Write as _;

/// Cable written where nothing measures it (the master's link to the first slave, and links to
/// slaves without a system time), m: the config's default.
pub const UNMEASURED_CABLE_M: f64 = 1.0;

/// Why a twin cannot be written.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TwinError {
    /// The bring-up did not record what a twin needs.
    #[error(
        "the bring-up did not measure {0}; bring the network up with delays (Stage::Delays or later)"
    )]
    Missing(&'static str),
    /// The recorded topology does not build a segment.
    #[error("the measured topology does not build a segment: {0}")]
    Topology(String),
}

/// What [`twin_toml`] wrote, and what it could not reproduce.
#[derive(Debug, Clone, PartialEq)]
pub struct Twin {
    /// The network TOML.
    pub toml: String,
    /// Each slave's model name, in network order.
    pub models: Vec<&'static str>,
    /// Each slave's cable, m.
    pub cables_m: Vec<f64>,
    /// What the twin does not reproduce exactly (also written as comments in the file).
    pub notes: Vec<String>,
}

/// A TOML basic string.
fn quoted(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(o, "\\u{:04X}", u32::from(c));
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// The slave's name in the twin: its position and the SII's device name (unique by position).
fn slave_name(pos: u16, device_name: &str) -> String {
    let n = device_name.trim();
    if n.is_empty() {
        format!("slave-{pos}")
    } else {
        format!("{pos}: {n}")
    }
}

/// Sets each slave's cable (after the reference, in network order) so that the segment's true
/// delay from the reference is `targets`' (none shorter than 0 m). Slave i's delay depends on its
/// own cable and on those before it in network order only, so one pass is exact.
fn solve_cables(
    specs: &mut [SlaveSpec],
    targets: &[Option<f64>],
    reference: usize,
) -> Result<(), TwinError> {
    for s in specs.iter_mut().skip(reference + 1) {
        if s.upstream != Upstream::Master {
            s.cable_m = 0.0;
        }
    }
    for i in reference + 1..specs.len() {
        let Some(target) = targets[i] else {
            continue;
        };
        if specs[i].upstream == Upstream::Master {
            continue;
        }
        let seg = Segment::new(specs).map_err(|e| TwinError::Topology(e.to_string()))?;
        let Some(Some(twin)) = seg.true_delays_ns(reference).get(i).copied() else {
            return Err(TwinError::Topology(format!(
                "slave {i} is not reached in the twin"
            )));
        };
        let cable = (target - twin) * 1000.0 / CABLE_PS_PER_M;
        // Millimetres: the segment rounds the cable to whole picoseconds anyway.
        specs[i].cable_m = (cable.max(0.0) * 1000.0).round() / 1000.0;
    }
    Ok(())
}

/// True minus measured delay of each slave when the master brings `specs` up in the simulator
/// (256 latches, so the 40 ns stamps average out).
fn measurement_bias(specs: &[SlaveSpec], reference: usize) -> Result<Vec<Option<f64>>, TwinError> {
    let seg = Segment::new(specs).map_err(|e| TwinError::Topology(e.to_string()))?;
    let truth = seg.true_delays_ns(reference);
    let mut sim = SimTransport::new(seg);
    let cfg = BringupConfig {
        until: Stage::Delays,
        latch_rounds: 256,
        ..BringupConfig::default()
    };
    let mut engine = Engine::new(move |link| ecsync_master::bringup::bringup(link, cfg));
    let net = sim
        .run_procedure(&mut engine, |_, _, _| {})
        .map_err(|e| TwinError::Topology(format!("the twin does not come up: {e}")))?;
    Ok(net
        .slaves
        .iter()
        .zip(&truth)
        .map(|(s, t)| match (s.delay_ns, t) {
            (Some(m), Some(t)) => Some(t - m),
            _ => None,
        })
        .collect())
}

/// Writes the twin of `net`; `source` says where it was measured (a comment in the file).
/// `reference_ppm`: the reference's crystal error to write, the others' then follow from their
/// measured errors against it (`None`: as measured against the master's clock).
pub fn twin_toml(
    net: &Network,
    source: &str,
    reference_ppm: Option<f64>,
) -> Result<Twin, TwinError> {
    if net.slaves.is_empty() {
        return Err(TwinError::Missing("any slave"));
    }
    let reference = usize::from(net.reference);
    let mut notes = Vec::new();
    let (models, mut specs) = model_specs(net, &mut notes);
    solve_twin_cables(net, reference, &models, &mut specs, &mut notes)?;
    let ref_vs_master = reference_ppm.or(net.reference_ppm_vs_master);
    if ref_vs_master.is_none() {
        notes.push(
            "the reference's crystal against the master was not measured: written as 0 ppm".into(),
        );
    }
    let t = write_toml(net, source, ref_vs_master, &models, &specs, &notes);
    let cables_m = specs.iter().map(|s| s.cable_m).collect();
    Ok(Twin {
        toml: t,
        models,
        cables_m,
        notes,
    })
}

/// The model whose registers (ESC type, 0x0008, port descriptor) are slave `s`'s and whose DC
/// unit has receive times only, as the master found the slave's (by what answered).
fn receive_times_twin(s: &SlaveInfo) -> Option<&'static str> {
    MODEL_NAMES.into_iter().find(|n| {
        model_named(n).is_some_and(|m| {
            m.dc == DcSupport::ReceiveTimes
                && (m.esc_type, m.features(), m.port_descriptor())
                    == (s.esc_type, s.features, s.port_descriptor)
        })
    })
}

/// Each slave's model (by its ESC registers) and the segment's spec before the cables are
/// solved; a note where no model fits exactly.
fn model_specs(net: &Network, notes: &mut Vec<String>) -> (Vec<&'static str>, Vec<SlaveSpec>) {
    let n = net.slaves.len();
    let mut models = Vec::with_capacity(n);
    let mut specs: Vec<SlaveSpec> = Vec::with_capacity(n);
    for (i, s) in net.slaves.iter().enumerate() {
        let (mut name, how) = model_for_registers(s.esc_type, s.features, s.port_descriptor);
        match how {
            ModelMatch::Exact => {}
            ModelMatch::Ports => notes.push(format!(
                "slave {i}: ESC type {:#04x}, features {:#06x}: no model has exactly these; {name} has its ports and DC",
                s.esc_type, s.features
            )),
            ModelMatch::Nearest => notes.push(format!(
                "slave {i}: ESC type {:#04x}, features {:#06x}, port descriptor {:#04x}: no model fits; {name} is the nearest",
                s.esc_type, s.features, s.port_descriptor
            )),
        }
        if s.dc == DcCapability::ReceiveTimes {
            // 0x0008 says DC with receive times alone (the EL2828 reads 0x01FC): the model of
            // the same registers with receive times only, where there is one.
            match receive_times_twin(s) {
                Some(n) => name = n,
                None => notes.push(format!(
                    "slave {i}: has receive times but no system time, which no model with its registers has; {name} has a full DC unit"
                )),
            }
        }
        models.push(name);
        let upstream = match s.parent {
            None => Upstream::Master,
            Some((p, port)) => Upstream::Slave {
                index: usize::from(p),
                port,
            },
        };
        specs.push(SlaveSpec {
            model: model_named(name).unwrap_or_else(EscModel::servo_mii),
            device: DeviceInfo::coupler("twin", u32::from(s.position)),
            crystal: CrystalParams::default(),
            upstream,
            entry_port: s.entry_port,
            cable_m: if i == 0 { UNMEASURED_CABLE_M } else { 0.0 },
            ring: None,
        });
    }
    (models, specs)
}

/// The cables solved from the measured delays, then again for the measured delays less the
/// master's measurement bias on the twin; a note where a delay is shorter than a model's hop.
fn solve_twin_cables(
    net: &Network,
    reference: usize,
    models: &[&'static str],
    specs: &mut [SlaveSpec],
    notes: &mut Vec<String>,
) -> Result<(), TwinError> {
    if net.slaves[reference].delay_ns.is_none() {
        return Err(TwinError::Missing("the propagation delays"));
    }
    let measured: Vec<Option<f64>> = net.slaves.iter().map(|s| s.delay_ns).collect();
    solve_cables(specs, &measured, reference)?;
    // The master's measurement has a bias of its own where the models' internal delays differ
    // along a path (an EBUS leaf behind an MII port: tens of ns). Measured on the twin, the same
    // bias shows, so the cables are solved again for the measured delays less the bias: then the
    // twin's measurement is the real one, and its true delays the real network's.
    let bias = measurement_bias(specs, reference)?;
    let targets: Vec<Option<f64>> = measured
        .iter()
        .zip(&bias)
        .map(|(m, b)| m.map(|m| m + b.unwrap_or(0.0)))
        .collect();
    solve_cables(specs, &targets, reference)?;
    for (i, s) in specs.iter().enumerate() {
        if let (Some(target), true) = (targets[i], i > reference && s.cable_m == 0.0) {
            let seg = Segment::new(specs).map_err(|e| TwinError::Topology(e.to_string()))?;
            if let Some(Some(twin)) = seg.true_delays_ns(reference).get(i)
                && twin - target > 1.0
            {
                notes.push(format!(
                        "slave {i}: the measured delay is {:.1} ns shorter than the {} model's own hop; written with no cable",
                        twin - target,
                        models[i]
                    ));
            }
        }
    }
    Ok(())
}

/// The twin's TOML text.
fn write_toml(
    net: &Network,
    source: &str,
    ref_vs_master: Option<f64>,
    models: &[&'static str],
    specs: &[SlaveSpec],
    notes: &[String],
) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "# A twin of the network measured on {source} by `ecsync run --save-network`."
    );
    let _ = writeln!(
        t,
        "# Models from 0x0000/0x0007/0x0008, cable_m solved from the measured delays, ppm from"
    );
    let _ = writeln!(
        t,
        "# receive times latched seconds apart (crates/sim/src/twin.rs says how). Add the"
    );
    let _ = writeln!(
        t,
        "# [host], [run] and [methods.*] tables of a preset to `compare` on it."
    );
    for note in notes {
        let _ = writeln!(t, "# note: {note}");
    }
    let _ = writeln!(t, "\n[segment]\nseed = 1");
    for (i, s) in net.slaves.iter().enumerate() {
        let _ = writeln!(t, "\n[[segment.slave]]");
        let _ = writeln!(t, "name = {}", quoted(&slave_name(s.position, &s.name)));
        let _ = writeln!(t, "model = {}", quoted(models[i]));
        // The built-in devices: a drive (mailbox, process data) or a coupler (neither). Their
        // process data is the built-in drive's, not the real device's.
        let drive = s.mailbox.is_some_and(|m| m.coe()) || !s.sms.is_empty();
        let _ = writeln!(
            t,
            "device = {}",
            quoted(if drive { "servo-drive" } else { "coupler" })
        );
        let _ = writeln!(t, "vendor_id = {:#010x}", s.vendor_id);
        let _ = writeln!(t, "product_code = {:#010x}", s.product_code);
        let _ = writeln!(t, "revision = {:#010x}", s.revision);
        let _ = writeln!(t, "serial = {}", s.serial);
        if !s.name.is_empty() {
            let _ = writeln!(t, "device_name = {}", quoted(&s.name));
        }
        match s.parent {
            None => {
                let _ = writeln!(t, "upstream = \"master\"");
            }
            Some((p, port)) => {
                let up = &net.slaves[usize::from(p)];
                let _ = writeln!(
                    t,
                    "upstream = {}",
                    quoted(&slave_name(up.position, &up.name))
                );
                let _ = writeln!(t, "upstream_port = {port}");
            }
        }
        let _ = writeln!(t, "entry_port = {}", s.entry_port);
        let _ = writeln!(t, "cable_m = {}", specs[i].cable_m);
        if let Some(d) = s.delay_ns {
            let _ = writeln!(t, "# measured delay from the reference: {d:.1} ns");
        }
        let rel = s.ppm_vs_reference.unwrap_or(0.0);
        let ppm = ((1.0 + ref_vs_master.unwrap_or(0.0) * 1e-6) * (1.0 + rel * 1e-6) - 1.0) * 1e6;
        let _ = writeln!(t, "ppm = {:.4}  # {rel:+.4} ppm against the reference", ppm);
    }
    t
}
