//! Report of `ecsync tsn run`: summary.json, summary.csv, a text table, plots (SVG and PNG)
//! and report.html, and the findings the paper claims, checked.

use super::{TsnScenario, Variant, VariantResult};
use crate::html::esc;
use crate::output::write_atomic;
use crate::plots::{COLORS, draw_envelopes, draw_hist, err, fonts, write_svg_png};
use crate::stats::Summary;
use ecsync_tsn::qbv::GateControlEntry;
use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// The compiled gate control lists.
#[derive(Debug, Clone, Serialize)]
pub struct GateOut {
    /// Gate cycle, ns.
    pub cycle_ns: u64,
    /// Towards the slaves.
    pub ethercat_port: Vec<GateControlEntry>,
    /// Towards the master.
    pub master_port: Vec<GateControlEntry>,
    /// Share of the cycle the EtherCAT gate is open towards the slaves.
    pub ethercat_open_fraction: f64,
}

/// The paper's claims, checked on this run (`None` when a variant needed was not run).
#[derive(Debug, Clone, Serialize, Default)]
pub struct Findings {
    /// M2 held DC frames at a closed gate.
    pub m2_blocks_dc_frames: Option<bool>,
    /// M2's largest delay measurement error, ns.
    pub m2_max_delay_error_ns: Option<f64>,
    /// DC frames M3 held at a closed gate.
    pub m3_blocked_frames: Option<u64>,
    /// M3's largest delay measurement error, ns.
    pub m3_max_delay_error_ns: Option<f64>,
    /// M3 measures every delay within 20 ns of the truth.
    pub m3_delays_within_20ns: Option<bool>,
    /// Precision (p99 of the slaves' spread): M2 over M3.
    pub precision_p99_m2_over_m3: Option<f64>,
    /// Precision (RMS of the spread): M2 over M3.
    pub precision_rms_m2_over_m3: Option<f64>,
    /// M3's precision at least 3 times better than M2's (p99; the paper's Table II).
    pub precision_at_least_3x_better: Option<bool>,
    /// Precision (p99): M3 over M1 (1 = as if the bridge were not there).
    pub precision_p99_m3_over_m1: Option<f64>,
    /// Master clock minus gPTP grandmaster, RMS, ns.
    pub gptp_offset_rms_ns: Option<f64>,
    /// That under 100 ns.
    pub gptp_offset_under_100ns: Option<bool>,
    /// What the figures mean beside the paper's.
    pub notes: Vec<String>,
}

/// summary.json.
#[derive(Debug, Clone, Serialize)]
pub struct TsnSummary {
    /// Scenario file.
    pub scenario: String,
    /// Slaves.
    pub slaves: usize,
    /// EtherCAT cycle, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift, ns.
    pub sync0_shift_ns: u32,
    /// Warm-up cycles.
    pub warmup_cycles: u64,
    /// Recorded cycles.
    pub cycles: u64,
    /// Seed.
    pub seed: u64,
    /// The bridge's gates.
    pub gate: GateOut,
    /// Per variant.
    pub variants: BTreeMap<String, VariantResult>,
    /// The paper's claims, checked.
    pub findings: Findings,
    /// Wall time, s.
    pub wall_s: f64,
}

fn ratio(a: f64, b: f64) -> Option<f64> {
    (b > 0.0 && a.is_finite() && b.is_finite()).then(|| a / b)
}

/// Builds the summary and checks the paper's claims.
pub fn summarize(s: &TsnScenario, results: &[VariantResult], wall_s: f64) -> TsnSummary {
    let get = |v: Variant| results.iter().find(|r| r.variant == v);
    let mut f = Findings::default();
    if let Some(m2) = get(Variant::M2) {
        f.m2_blocks_dc_frames = Some(m2.blocked.total() > 0);
        f.m2_max_delay_error_ns = Some(m2.max_abs_delay_error_ns);
    }
    if let Some(m3) = get(Variant::M3) {
        f.m3_blocked_frames = Some(m3.blocked.total());
        f.m3_max_delay_error_ns = Some(m3.max_abs_delay_error_ns);
        f.m3_delays_within_20ns = Some(m3.max_abs_delay_error_ns <= 20.0 && !m3.delays.is_empty());
        if let Some(g) = &m3.gptp {
            f.gptp_offset_rms_ns = Some(g.offset.rms);
            f.gptp_offset_under_100ns = Some(g.offset.rms < 100.0);
        }
    }
    if let (Some(m2), Some(m3)) = (get(Variant::M2), get(Variant::M3)) {
        f.precision_p99_m2_over_m3 = ratio(m2.slave_spread.p99_abs, m3.slave_spread.p99_abs);
        f.precision_rms_m2_over_m3 = ratio(m2.slave_spread.rms, m3.slave_spread.rms);
        f.precision_at_least_3x_better = f.precision_p99_m2_over_m3.map(|r| r >= 3.0);
    }
    if let (Some(m1), Some(m3)) = (get(Variant::M1), get(Variant::M3)) {
        f.precision_p99_m3_over_m1 = ratio(m3.slave_spread.p99_abs, m1.slave_spread.p99_abs);
    }
    f.notes = notes(results, s);
    TsnSummary {
        scenario: s.name.clone(),
        slaves: s.slaves.len(),
        cycle_ns: s.cycle_ns,
        sync0_shift_ns: s.sync0_shift_ns,
        warmup_cycles: s.warmup_cycles,
        cycles: s.cycles,
        seed: s.seed,
        gate: GateOut {
            cycle_ns: s.bridge.cycle_ns,
            ethercat_port: s.bridge.ethercat_port.control_list(),
            master_port: s.bridge.master_port.control_list(),
            ethercat_open_fraction: s.bridge.ethercat_port.open_fraction(),
        },
        variants: results
            .iter()
            .map(|r| (r.variant.name().to_string(), r.clone()))
            .collect(),
        findings: f,
        wall_s,
    }
}

fn notes(results: &[VariantResult], s: &TsnScenario) -> Vec<String> {
    let mut n = Vec::new();
    let get = |v: Variant| results.iter().find(|r| r.variant == v);
    if let Some(m2) = get(Variant::M2) {
        let b = &m2.blocked;
        n.push(format!(
            "M2: {} of {} delay measurement frames (the paper's DM_T) and {} of {} cyclic frames (SM) waited at the closed gate, up to {:.1} us; none on the way back (DM_R), because the return window is scheduled after the outgoing one, as the paper argues. A held DM_T lengthens the round trip but not the slave's own span, so the master's delay comes out {:.1} us too long, and with it every slave's delay from the master: the paper's Table I effect (there 100 % and 67 % of M1's delays in a model with 25-unit hops).",
            b.latch_forward,
            b.latch_frames,
            b.cyclic_forward,
            b.cyclic_frames,
            b.max_wait_ns / 1000.0,
            m2.max_abs_delay_error_ns / 1000.0
        ));
        n.push(format!(
            "M2: the master writes its time to the reference every cycle (bus shift); a frame held at the gate delivers a time that is old by the hold, and the reference's control loop follows it, so the slaves' time lags the master's by {:.1} us on average (max {:.1} us) and moves as the master's frames walk through the bridge's gate cycle ({:.0} ppm between the two crystals). The other slaves follow the reference by FRMW but trail its changes: the precision among the slaves (p99 of their spread) is {:.0} ns against {:.0} ns in M3.",
            m2.master_minus_reference.mean / 1000.0,
            m2.master_minus_reference.max_abs / 1000.0,
            (s.master.ppm - s.bridge.ppm).abs(),
            m2.slave_spread.p99_abs,
            get(Variant::M3).map_or(f64::NAN, |m3| m3.slave_spread.p99_abs)
        ));
    }
    if let Some(m3) = get(Variant::M3) {
        n.push(format!(
            "M3: gPTP synchronized the master to the bridge before the bring-up (offset RMS {:.1} ns with {} ns hardware timestamps), so every frame the master places in its window by its own clock reaches the bridge inside the bridge's window: {} frames held; delays within {:.1} ns of the truth.",
            m3.gptp.map_or(f64::NAN, |g| g.offset.rms),
            s.master.timestamp_ns,
            m3.blocked.total(),
            m3.max_abs_delay_error_ns
        ));
    }
    if let (Some(m1), Some(m3)) = (get(Variant::M1), get(Variant::M3)) {
        n.push(format!(
            "M3 against M1: precision p99 {:.1} ns vs {:.1} ns, master minus reference mean {:.1} ns vs {:.1} ns: the bridge makes no difference once the master is synchronized to it. The paper's M3 is 25-60 % off M1 because its model clocks drift by 10 % and its periods are a few ticks (its section VI-D); with real crystals and nanosecond timestamps the gap closes.",
            m3.slave_spread.p99_abs,
            m1.slave_spread.p99_abs,
            m3.master_minus_reference.mean,
            m1.master_minus_reference.mean
        ));
        // M-rS is the frame's way from the master to the reference: a bridge on it lengthens
        // it by a constant, which a reader of the table would otherwise take for an error.
        n.push(format!(
            "M-rS is {:.1} us longer in M3 than in M1 ({:.1} us against {:.1} us; std {:.3} us against {:.3} us): the bridge stores each frame whole before it forwards it (the cyclic frame's wire time at 100 Mbit/s) and adds its {:.1} us residence. A constant on the way, which the master's write of its time allows for: no error.",
            (m3.m_rs.mean - m1.m_rs.mean) / 1000.0,
            m3.m_rs.mean / 1000.0,
            m1.m_rs.mean / 1000.0,
            m3.m_rs.std / 1000.0,
            m1.m_rs.std / 1000.0,
            s.bridge.residence_ns as f64 / 1000.0
        ));
    }
    n
}

fn row(label: &str, results: &[VariantResult], f: impl Fn(&VariantResult) -> String) -> String {
    let mut l = format!("{label:<44}");
    for r in results {
        let _ = write!(l, "{:>18}", f(r));
    }
    l.push('\n');
    l
}

/// The text table.
pub fn table_text(sum: &TsnSummary) -> String {
    let results: Vec<VariantResult> = sum.variants.values().cloned().collect();
    let mut t = String::new();
    let _ = writeln!(
        t,
        "TSN-EtherCAT: {} slaves, cycle {} us, SYNC0 at +{} us, {} s recorded after {} s warm-up; EtherCAT gate open {:.0} % of the cycle",
        sum.slaves,
        sum.cycle_ns / 1000,
        sum.sync0_shift_ns / 1000,
        sum.cycles * u64::from(sum.cycle_ns) / 1_000_000_000,
        sum.warmup_cycles * u64::from(sum.cycle_ns) / 1_000_000_000,
        sum.gate.ethercat_open_fraction * 100.0
    );
    t.push_str(&row("", &results, |r| r.variant.name().to_string()));
    let ns = |x: f64| format!("{x:.1}");
    let us = |x: f64| format!("{:.3}", x / 1000.0);
    t.push_str(&row("DC frames held at a gate", &results, |r| {
        r.blocked.total().to_string()
    }));
    t.push_str(&row(
        "  delay measurement (DM_T) held / sent",
        &results,
        |r| format!("{}/{}", r.blocked.latch_forward, r.blocked.latch_frames),
    ));
    t.push_str(&row("  cyclic (SM) held / sent", &results, |r| {
        format!("{}/{}", r.blocked.cyclic_forward, r.blocked.cyclic_frames)
    }));
    t.push_str(&row("  longest hold (us)", &results, |r| {
        us(r.blocked.max_wait_ns)
    }));
    t.push_str(&row("max |delay error| (ns)", &results, |r| {
        ns(r.max_abs_delay_error_ns)
    }));
    t.push_str(&row(
        "DC lock after drift compensation (ms)",
        &results,
        |r| r.time_to_lock_ms.map_or("-".into(), |v| format!("{v:.1}")),
    ));
    let sm = |label: &str, pick: fn(&VariantResult) -> &Summary, unit_us: bool| {
        let f = move |x: f64| {
            if unit_us {
                format!("{:.3}", x / 1000.0)
            } else {
                format!("{x:.1}")
            }
        };
        let u = if unit_us { "us" } else { "ns" };
        let mut s = String::new();
        s.push_str(&row(&format!("{label} mean ({u})"), &results, |r| {
            f(pick(r).mean)
        }));
        s.push_str(&row(&format!("{label} std ({u})"), &results, |r| {
            f(pick(r).std)
        }));
        s.push_str(&row(&format!("{label} p99 |x| ({u})"), &results, |r| {
            f(pick(r).p99_abs)
        }));
        s.push_str(&row(&format!("{label} max |x| ({u})"), &results, |r| {
            f(pick(r).max_abs)
        }));
        s
    };
    t.push_str(&sm("precision: slave spread", |r| &r.slave_spread, false));
    t.push_str(&sm(
        "master - reference",
        |r| &r.master_minus_reference,
        true,
    ));
    t.push_str(&sm("M-rS (t_ra - t_ms)", |r| &r.m_rs, true));
    t.push_str(&sm("rS-IS |0x092C|", |r| &r.rs_is, false));
    t.push_str(&row("late frames (after SYNC0)", &results, |r| {
        r.late_frames.to_string()
    }));
    t.push_str(&row("cross-traffic frames to the master", &results, |r| {
        r.cross_traffic_frames.map_or("-".into(), |n| n.to_string())
    }));
    t.push_str(&row("gPTP messages held by cross traffic", &results, |r| {
        r.gptp.map_or("-".into(), |g| {
            format!("{}/{}", g.held_by_cross_traffic, g.messages)
        })
    }));
    t.push_str(&row("gPTP master - grandmaster RMS (ns)", &results, |r| {
        r.gptp
            .map_or("-".into(), |g| format!("{:.1}", g.offset.rms))
    }));
    t.push_str(&row(
        "gPTP link delay measured / true (ns)",
        &results,
        |r| {
            r.gptp.map_or("-".into(), |g| {
                format!(
                    "{:.1}/{:.1}",
                    g.measured_link_delay_ns, g.true_link_delay_ns
                )
            })
        },
    ));
    let f = &sum.findings;
    let yn = |b: Option<bool>| b.map_or("-", |b| if b { "yes" } else { "NO" });
    let _ = writeln!(t, "\nThe paper's claims on this network:");
    let _ = writeln!(
        t,
        "  M2 blocks DC frames: {}; M2 delay error {:.1} ns",
        yn(f.m2_blocks_dc_frames),
        f.m2_max_delay_error_ns.unwrap_or(f64::NAN)
    );
    let _ = writeln!(
        t,
        "  M3 blocks none: {} ({} held); M3 delays within 20 ns: {} ({:.1} ns)",
        yn(f.m3_blocked_frames.map(|b| b == 0)),
        f.m3_blocked_frames.map_or("-".into(), |b| b.to_string()),
        yn(f.m3_delays_within_20ns),
        f.m3_max_delay_error_ns.unwrap_or(f64::NAN)
    );
    let _ = writeln!(
        t,
        "  M3 precision >= 3x M2's: {} (p99 x{:.1}, RMS x{:.1})",
        yn(f.precision_at_least_3x_better),
        f.precision_p99_m2_over_m3.unwrap_or(f64::NAN),
        f.precision_rms_m2_over_m3.unwrap_or(f64::NAN)
    );
    let _ = writeln!(
        t,
        "  gPTP offset RMS < 100 ns: {} ({:.1} ns)",
        yn(f.gptp_offset_under_100ns),
        f.gptp_offset_rms_ns.unwrap_or(f64::NAN)
    );
    t
}

/// summary.csv: one row per variant and quantity.
pub fn csv(sum: &TsnSummary) -> String {
    let mut c = String::from("variant,quantity,n,mean_ns,std_ns,rms_ns,p99_abs_ns,max_abs_ns\n");
    for (name, r) in &sum.variants {
        for (q, s) in [
            ("slave_spread", &r.slave_spread),
            ("master_minus_reference", &r.master_minus_reference),
            ("m_rs", &r.m_rs),
            ("rs_is", &r.rs_is),
            ("sync0_margin", &r.sync0_margin),
        ] {
            let _ = writeln!(
                c,
                "{name},{q},{},{:.3},{:.3},{:.3},{:.3},{:.3}",
                s.n, s.mean, s.std, s.rms, s.p99_abs, s.max_abs
            );
        }
        if let Some(g) = &r.gptp {
            let s = &g.offset;
            let _ = writeln!(
                c,
                "{name},gptp_offset,{},{:.3},{:.3},{:.3},{:.3},{:.3}",
                s.n, s.mean, s.std, s.rms, s.p99_abs, s.max_abs
            );
        }
    }
    c
}

fn histograms<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    results: &[VariantResult],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((results.len(), 2));
    for (i, r) in results.iter().enumerate() {
        let p = &r.plots;
        draw_hist(
            &rows[2 * i],
            &p.master_minus_reference.dist,
            &format!("{}: master - reference (truth)", r.variant.name()),
            1000.0,
            "us",
            COLORS[i % 5],
        )?;
        draw_hist(
            &rows[2 * i + 1],
            &p.slave_spread.dist,
            &format!(
                "{}: precision, spread of the slaves (truth)",
                r.variant.name()
            ),
            1.0,
            "ns",
            COLORS[i % 5],
        )?;
    }
    root.present().map_err(err)
}

fn series<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    results: &[VariantResult],
    which: usize,
    title: &str,
    unit_div: f64,
    unit: &str,
    cycle_s: f64,
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((results.len(), 1));
    for (i, r) in results.iter().enumerate() {
        draw_envelopes(
            &rows[i],
            &r.plots.series[which],
            &format!("{}: {title}", r.variant.name()),
            cycle_s,
            unit_div,
            unit,
            COLORS[i % 5],
        )?;
    }
    root.present().map_err(err)
}

type Plot<'a> = dyn Fn(&Path, bool) -> io::Result<()> + 'a;

/// Writes summary.json, summary.csv, table.txt, the plots and report.html into `dir`.
pub fn write_all(sum: &TsnSummary, results: &[VariantResult], dir: &Path) -> io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let json = serde_json::to_string_pretty(sum).map_err(err)?;
    write_atomic(&dir.join("summary.json"), json.as_bytes())?;
    write_atomic(&dir.join("summary.csv"), csv(sum).as_bytes())?;
    let table = table_text(sum);
    write_atomic(&dir.join("table.txt"), table.as_bytes())?;
    fonts();
    let n = results.len().max(1) as u32;
    let cycle_s = f64::from(sum.cycle_ns) * 1e-9;
    let bridged: Vec<VariantResult> = results
        .iter()
        .filter(|r| r.variant.has_bridge())
        .cloned()
        .collect();
    let m3: Vec<VariantResult> = results
        .iter()
        .filter(|r| r.variant == Variant::M3)
        .cloned()
        .collect();
    // Draws `$draw(root)` on an SVG or a PNG backend of `$size`.
    macro_rules! on_backend {
        ($p:expr, $svg:expr, $size:expr, $draw:expr) => {
            if $svg {
                $draw(SVGBackend::new($p, $size).into_drawing_area())
            } else {
                $draw(BitMapBackend::new($p, $size).into_drawing_area())
            }
        };
    }
    let mut plots: Vec<(&str, Box<Plot<'_>>)> = Vec::new();
    plots.push((
        "tsn_histograms",
        Box::new(move |p: &Path, svg: bool| {
            on_backend!(p, svg, (1100, 240 * n), |root| histograms(root, results))
        }),
    ));
    // Time series: name, variants, which series, title, unit divisor, unit, row height.
    type Spec<'s> = (
        &'static str,
        &'s [VariantResult],
        usize,
        &'static str,
        f64,
        &'static str,
        u32,
    );
    let specs: [Spec<'_>; 4] = [
        (
            "tsn_series_master_minus_reference",
            results,
            0,
            "master - reference, min..max per 1000 cycles",
            1000.0,
            "us",
            200,
        ),
        (
            "tsn_series_precision",
            results,
            1,
            "spread of the slaves' system times, min..max per 1000 cycles",
            1.0,
            "ns",
            200,
        ),
        (
            "tsn_series_gate_hold",
            &bridged,
            3,
            "hold of the cyclic frame at the gate towards the slaves",
            1000.0,
            "us",
            200,
        ),
        (
            "tsn_gptp_offset",
            &m3,
            2,
            "gPTP: master clock - grandmaster (bridge) clock (truth)",
            1.0,
            "ns",
            220,
        ),
    ];
    for (name, rs, which, title, div, unit, row) in specs {
        if rs.is_empty() {
            continue;
        }
        let size = (1100, row * rs.len() as u32);
        plots.push((
            name,
            Box::new(move |p: &Path, svg: bool| {
                on_backend!(p, svg, size, |root| series(
                    root, rs, which, title, div, unit, cycle_s
                ))
            }),
        ));
    }
    // report.html holds the SVGs themselves: the file alone shows its plots.
    let mut figures = Vec::with_capacity(plots.len());
    for (name, f) in &plots {
        figures.push((*name, write_svg_png(dir, name, f.as_ref())?));
    }
    write_atomic(
        &dir.join("report.html"),
        html(sum, &table, &figures).as_bytes(),
    )
}

fn html(sum: &TsnSummary, table: &str, plots: &[(&str, String)]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync tsn run: {}</title>\
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}}pre{{background:#f6f6f6;padding:1em}}\
figure svg{{display:block;max-width:100%;height:auto;border:1px solid #ddd;margin:0.5em 0}}</style></head><body>\
<h1>ecsync tsn run</h1><p>{}: the TSN paper's M1 (no TSN), M2 (bridge, no gPTP) and M3 (bridge, master synchronized by gPTP) on {} slaves, measured against the simulator's ground truth.</p>",
        esc(&sum.scenario),
        esc(&sum.scenario),
        sum.slaves
    );
    let _ = write!(h, "<h2>Plots</h2>");
    for (p, svg) in plots {
        let _ = write!(
            h,
            "<h3>{p}</h3><figure>{}<figcaption><a href=\"{p}.svg\">{p}.svg</a>, <a href=\"{p}.png\">{p}.png</a></figcaption></figure>",
            crate::html::inline_svg(svg)
        );
    }
    let _ = write!(
        h,
        "<h2>Table</h2><pre>{}</pre><h2>Notes</h2><ul>",
        esc(table)
    );
    for n in &sum.findings.notes {
        let _ = write!(h, "<li>{}</li>", esc(n));
    }
    let _ = write!(
        h,
        "</ul><p>Gate control lists (802.1Qbv, bit 1 EtherCAT, bit 0 best effort): towards the slaves {}; towards the master {}.</p><p>Files: <a href=\"summary.json\">summary.json</a>, <a href=\"summary.csv\">summary.csv</a>, <a href=\"table.txt\">table.txt</a>. Wall time {:.1} s.</p></body></html>",
        esc(&format!("{:?}", sum.gate.ethercat_port)),
        esc(&format!("{:?}", sum.gate.master_port)),
        sum.wall_s
    );
    h
}
