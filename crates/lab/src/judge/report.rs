//! The judge's report.html: compare's look and code (its style sheet, its band panels): a
//! verdict first, then the plots, then the tables.

use super::JudgeOut;
use crate::html::{CSS, esc, inline_svg};
use crate::plots::{LATE_RED, Mark, Metric, TARGET_BLACK, band_panel, fonts};
use crate::run::Band;
use plotters::prelude::*;
use std::fmt::Write as _;

fn us(x: Option<f64>) -> String {
    x.map_or("&ndash;".into(), |v| format!("{:.1}", v / 1000.0))
}

fn ns(x: Option<f64>) -> String {
    x.map_or("&ndash;".into(), |v| format!("{v:.0}"))
}

/// The verdict in words: what the master kept and what it broke.
pub(crate) fn verdict(out: &JudgeOut) -> (bool, String) {
    let mut broke = Vec::new();
    if out.pd_frames == 0 {
        return (
            false,
            "The master exchanged no process data (no LRW, LRD or LWR frame).".into(),
        );
    }
    if out.late > 0 {
        let worst = out
            .drives
            .iter()
            .filter(|d| d.late > 0)
            .map(|d| format!("{} ({})", d.name, d.late))
            .collect::<Vec<_>>()
            .join(", ");
        broke.push(format!(
            "{} frame(s) reached a drive after the SYNC0 pulse they were meant for: {worst}",
            out.late
        ));
    }
    if out.missed > 0 {
        broke.push(format!(
            "{} SYNC0 pulse(s) found no new outputs",
            out.missed
        ));
    }
    // An oversampling terminal's blocks that no SYNC1 event took: samples never played
    // (ethercrab 0.7's `tx_rx_dc` stepping by SYNC0, #369).
    let lost_blocks: Vec<String> = out
        .drives
        .iter()
        .filter(|d| d.on_sync1 && d.overwritten > 0)
        .map(|d| format!("{} ({} of {} frames)", d.name, d.overwritten, d.frames))
        .collect();
    if !lost_blocks.is_empty() {
        broke.push(format!(
            "blocks of samples were overwritten before the SYNC1 event that plays them (the master cycles faster than SYNC1): {}",
            lost_blocks.join(", ")
        ));
    }
    if out.wkc_errors > 0 {
        broke.push(format!(
            "{} frame(s) came back with an unusual working counter ({} with 0)",
            out.wkc_errors, out.wkc_zero
        ));
    }
    if out.al_errors > 0 {
        broke.push(format!("{} AL error(s) were raised", out.al_errors));
    }
    let never = out
        .faults
        .iter()
        .filter(|f| f.recovery_ms.is_none())
        .count();
    if never > 0 {
        broke.push(format!(
            "after {never} fault(s) the drives did not all come back to OP"
        ));
    }
    let margin = out.margin_min_ns.map_or(String::new(), |m| {
        format!(" (margin min {:.1} us)", m / 1000.0)
    });
    if broke.is_empty() {
        (
            true,
            format!("The master kept every drive's outputs before SYNC0{margin}."),
        )
    } else {
        (
            false,
            format!(
                "The master broke the deadline or the exchange{margin}: {}.",
                broke.join("; ")
            ),
        )
    }
}

/// One band panel as an SVG document.
fn panel_svg(title: &str, bands: &[Band], block: u64, cycle_s: f64, m: &Metric) -> String {
    fonts();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for b in bands {
        lo = lo.min(f64::from(b.min));
        hi = hi.max(f64::from(b.max));
    }
    for mk in &m.marks {
        lo = lo.min(mk.at_ns);
        hi = hi.max(mk.at_ns);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (1100, 300)).into_drawing_area();
        let _ = root.fill(&WHITE);
        let _ = band_panel(
            &root,
            title,
            bands,
            block,
            cycle_s,
            0,
            (lo - pad, hi + pad),
            m,
        );
        let _ = root.present();
    }
    svg
}

fn figures(out: &JudgeOut) -> Vec<(String, String)> {
    let cycle_s = if out.pd_frames > 0 {
        out.run_s / out.pd_frames as f64
    } else {
        1e-3
    };
    let phase = Metric {
        title: "phase at the reference",
        unit_div: 1000.0,
        unit: "us",
        magnitude: false,
        marks: vec![Mark {
            at_ns: 0.0,
            label: "SYNC0".into(),
            color: LATE_RED,
        }],
    };
    let margin = Metric {
        title: "smallest SYNC0 margin",
        unit_div: 1000.0,
        unit: "us",
        magnitude: false,
        marks: vec![Mark {
            at_ns: 0.0,
            label: "late".into(),
            color: TARGET_BLACK,
        }],
    };
    let b = out.band_frames;
    vec![
        (
            panel_svg(
                "phase at the reference (s)",
                &out.phase_bands,
                b,
                cycle_s,
                &phase,
            ),
            format!(
                "The frames' phase at the reference against its SYNC0 pulse (0, red; before it negative), per block of {b} frames with process data: the extremes (light), the 1st to 99th percentile (darker) and the median (line)."
            ),
        ),
        (
            panel_svg(
                "smallest SYNC0 margin of any drive (s)",
                &out.margin_bands,
                b,
                cycle_s,
                &margin,
            ),
            format!(
                "Each frame's smallest SYNC0 margin over the drives, per block of {b} frames: below 0 (black) a drive's outputs came after the pulse they were meant for."
            ),
        ),
    ]
}

fn drive_table(h: &mut String, out: &JudgeOut) {
    h.push_str("<h2>Per drive</h2><table><tr><th>pos</th><th class=l>drive</th><th>frames</th><th>margin min us</th><th>margin p0.1 us</th><th>margin mean us</th><th>late</th><th>missed</th><th>|0x092C| mean ns</th><th>|0x092C| max ns</th><th>|t - ref| max ns</th><th>AL errors</th><th class=l>AL codes</th><th class=l>state</th></tr>");
    for d in &out.drives {
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.0}</td><td>{}</td><td class=l>{}</td><td class=l>{}</td></tr>",
            d.position,
            esc(&d.name),
            d.frames,
            us(d.margin_min_ns),
            us(d.margin_p001_ns),
            us(d.margin_mean_ns),
            d.late,
            d.missed,
            ns(d.time_diff_mean_ns),
            ns(d.time_diff_max_ns),
            d.deviation_max_ns,
            d.al_errors,
            esc(&d.al_codes.join(", ")),
            esc(&d.al_state)
        );
    }
    h.push_str("</table>");
}

fn run_table(h: &mut String, out: &JudgeOut) {
    let p = &out.phase;
    let rows: [(&str, String); 12] = [
        ("frames with process data", out.pd_frames.to_string()),
        (
            "phase mean / std, us",
            format!("{} / {}", us(p.mean_ns), us(p.std_ns)),
        ),
        (
            "phase p0.1 / p99.9, us",
            format!("{} / {}", us(p.p001_ns), us(p.p999_ns)),
        ),
        ("p99.9 of |phase - mean|, us", us(p.dev_p999_ns)),
        (
            "phase drift, ns/s",
            p.drift_ns_per_s
                .map_or("&ndash;".into(), |v| format!("{v:.2}")),
        ),
        (
            "spread p99.9 / max, ns",
            format!("{} / {}", ns(out.spread_p999_ns), ns(out.spread_max_ns)),
        ),
        ("late / missed", format!("{} / {}", out.late, out.missed)),
        (
            "working counter usual / errors / zero",
            format!(
                "{} / {} / {}",
                out.wkc_usual.map_or("&ndash;".into(), |w| w.to_string()),
                out.wkc_errors,
                out.wkc_zero
            ),
        ),
        (
            "lost (with process data)",
            format!("{} ({})", out.lost, out.lost_pd),
        ),
        (
            "late replies (over / max ns)",
            format!(
                "{} ({} / {})",
                out.late_replies, out.late_reply_threshold_ns, out.late_reply_max_ns
            ),
        ),
        ("retries", out.duplicates.to_string()),
        (
            "AL errors raised (read by the master)",
            format!("{} ({})", out.al_errors, out.al_errors_read),
        ),
    ];
    h.push_str("<h2>The run</h2><table>");
    for (k, v) in rows {
        let _ = write!(h, "<tr><td class=l>{k}</td><td>{v}</td></tr>");
    }
    h.push_str("</table>");
}

fn fault_table(h: &mut String, out: &JudgeOut) {
    if out.faults.is_empty() {
        return;
    }
    h.push_str("<h2>Faults</h2><table><tr><th>#</th><th class=l>kind</th><th>start s</th><th>end s</th><th class=l>drives in OP</th><th>back in OP after, ms</th><th class=l>what happened</th></tr>");
    for f in &out.faults {
        let _ = write!(
            h,
            "<tr><td>{}</td><td class=l>{}</td><td>{:.3}</td><td>{}</td><td class=l>{}</td><td>{}</td><td class=l>{}</td></tr>",
            f.fault,
            esc(&f.kind),
            f.start_s,
            f.end_s.map_or("&ndash;".into(), |e| format!("{e:.3}")),
            f.drives_in_op
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(" "),
            f.recovery_ms.map_or("never".into(), |r| format!("{r:.1}")),
            esc(&f.detail)
        );
    }
    h.push_str("</table>");
}

/// report.html of a judged master: the verdict, the plots (inline SVG), the tables.
pub fn report_html(out: &JudgeOut) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync judge: {}</title><style>{CSS}</style></head><body>",
        esc(&out.preset)
    );
    let _ = write!(
        h,
        "<h1>ecsync judge</h1><p>{}: {} drives, {:.1} s, {} frames ({} with process data), reference {}, SYNC0 cycle {} us.</p>",
        esc(&out.preset),
        out.drives.len(),
        out.run_s,
        out.frames,
        out.pd_frames,
        out.reference
            .map_or("none".into(), |r| format!("slave {r}")),
        out.cycle_ns
            .map_or("&ndash;".into(), |c| format!("{}", f64::from(c) / 1000.0))
    );
    let (ok, text) = verdict(out);
    let style = if ok {
        ""
    } else {
        " style=\"border-color:#c00;background:#fff0f0\""
    };
    let _ = write!(
        h,
        "<div class=verdict{style}><h2>{}</h2><p>{}</p></div>",
        if ok { "Kept" } else { "Broken" },
        esc(&text)
    );
    for (svg, caption) in figures(out) {
        let _ = write!(
            h,
            "<figure>{}<figcaption>{}</figcaption></figure>",
            inline_svg(&svg),
            esc(&caption)
        );
    }
    run_table(&mut h, out);
    drive_table(&mut h, out);
    fault_table(&mut h, out);
    h.push_str("</body></html>\n");
    h
}
