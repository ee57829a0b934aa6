//! report.html: the verdict and the tables first, then the plots with their captions. The
//! plots are inline SVG: the file alone shows them (sent by mail, attached to a ticket, opened
//! away from its folder); the SVG and PNG files beside it are for other uses.

use crate::report::{SummaryOut, verdict_text};
use std::fmt::Write as _;

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// A plot as report.html holds it: its file stem, its caption, the SVG document.
pub(crate) struct Figure<'a> {
    pub name: &'a str,
    pub caption: &'a str,
    pub svg: String,
}

/// `svg` as an element of an HTML body: plotters' SVG is one `<svg>` element with a viewBox
/// and no ids (nothing to clash between figures); anything before the element (an XML
/// declaration) has no place inside HTML and is dropped.
pub(crate) fn inline_svg(svg: &str) -> &str {
    svg.find("<svg").map_or("", |k| svg[k..].trim_end())
}

/// `f` as a figure of a report page: the SVG inline, its caption, links to its SVG and PNG
/// files (compare's report.html and the sweep's sweep.html alike).
pub(crate) fn figure_html(h: &mut String, f: &Figure<'_>) {
    let _ = write!(
        h,
        "<figure id=\"{name}\">{}<figcaption>{} <small>(also <a href=\"{name}.svg\">{name}.svg</a>, <a href=\"{name}.png\">{name}.png</a>)</small></figcaption></figure>",
        inline_svg(&f.svg),
        esc(f.caption),
        name = f.name
    );
}

/// The style sheet of compare's report, shared by the judge's (`crate::judge`).
pub(crate) const CSS: &str = "body{font-family:sans-serif;margin:2em;max-width:1200px;color:#222}table{border-collapse:collapse;margin:1em 0}\
td,th{border:1px solid #ccc;padding:3px 8px;text-align:right}td.l{white-space:nowrap}th{background:#eee}td.l,th.l{text-align:left}\
.verdict{border:2px solid #2c7a2c;background:#f3faf3;padding:0.8em 1.2em;margin:1em 0}.verdict h2{margin-top:0}\
.warn{border-left:4px solid #c77700;background:#fff8ec;padding:0.4em 0.8em;margin:0.4em 0}\
.interrupted{border:2px solid #c00;background:#fff0f0;padding:0.5em 1em}tr.letter td{color:#888}\
pre{background:#f7f7f7;padding:0.6em;overflow-x:auto;font-size:12px}\
figure{margin:1.5em 0}figcaption{color:#444;max-width:1100px}figure svg{display:block;max-width:100%;height:auto;border:1px solid #ddd}";

pub(crate) fn report_html(out: &SummaryOut, order: &[String], plots: &[Figure<'_>]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync compare: {}</title>\
<style>{CSS}</style></head><body>",
        esc(&out.scenario)
    );
    let _ = write!(
        h,
        "<h1>ecsync compare</h1><p>{}: {} slaves, host <b>{}</b>, {} &times; {} recorded cycles after {} warm-up cycles, cycle {} us, SYNC0 shift {} %, target phase {:.1} us, seed {}. Every method saw the same noise.</p>",
        esc(&out.scenario),
        out.slaves,
        esc(&out.host),
        crate::scenario::plural(u64::from(out.runs), "run", "runs"),
        out.cycles,
        out.warmup_cycles,
        out.cycle_ns / 1000,
        out.sync0_shift_pct,
        out.target_phase_ns as f64 / 1000.0,
        out.seed
    );
    if out.interrupted {
        let _ = write!(
            h,
            "<p class=interrupted><b>Interrupted</b>: the figures are of the {} recorded cycles done.</p>",
            out.cycles_done
        );
    }
    let r = &out.recommendation;
    let not_ranked: String = r
        .not_ranked
        .iter()
        .map(|n| format!("<p>Not ranked: {}</p>", esc(&n.why)))
        .collect();
    let _ = write!(
        h,
        "<div class=verdict><h2>Recommendation: {}</h2><p>{}</p><p>Ranking: {}.</p>{not_ranked}<p><small>Rule: {}.</small></p></div>",
        esc(if r.method.is_empty() {
            "none"
        } else {
            &r.method
        }),
        esc(&r.reason),
        esc(&r.ranking.join(" &gt; ")).replace("&amp;gt;", "&gt;"),
        esc(r.rule)
    );
    for w in &out.warnings {
        let _ = write!(h, "<p class=warn>{}</p>", esc(&w.message));
    }
    truth_table(&mut h, out, order);
    faults_table(&mut h, out, order);
    per_slave_table(&mut h, out);
    letter_table(&mut h, out, order);
    let _ = write!(h, "<h2>Plots</h2>");
    for f in plots {
        figure_html(&mut h, f);
    }
    let _ = write!(
        h,
        "<p>Quantiles: {} (relative error {:.2e}, absolute {} ns). Files: <a href=\"summary.json\">summary.json</a>, <a href=\"summary.csv\">summary.csv</a>, <a href=\"table1.txt\">table1.txt</a>. Wall time {:.1} s on {}.</p><pre>{}</pre></body></html>",
        esc(out.quantiles.definition),
        out.quantiles.rel_error,
        out.quantiles.abs_error_ns,
        out.wall_s,
        crate::scenario::plural(out.threads as u64, "thread", "threads"),
        esc(&verdict_text(out))
    );
    h
}

/// With `compare --faults`: per method, what the faults did and how it came back (all runs;
/// the re-lock time is the worst run's).
fn faults_table(h: &mut String, out: &SummaryOut, order: &[String]) {
    if out.methods.values().all(|m| m.faults.is_empty()) {
        return;
    }
    let kinds = out
        .methods
        .values()
        .find_map(|m| m.faults.first())
        .map(|f| f.relock_kinds.clone())
        .unwrap_or_default();
    let _ = write!(
        h,
        "<h2>Faults</h2><p>All runs. Dropped: frames the schedule lost; lost: cycles whose frame did not come back; recovered: slaves the master configured again (network positions); held: cycles the master did not believe the reference's time and held over. Re-lock: from the fault's end to the first of 100 cycles in a row with |0x092C| under the method's lock band (100 ns, or twice the 99.9th percentile it holds outside the faults' windows if more: the letter's bus shift writes the master's jitter into the reference), its M-rS within its error band (twice the 99.9th percentile of its distance from its median outside the windows, at least 1 us), the reference believed and every slave's process data (the worst run). Every fault's edges and every recovery: <a href=\"faults.csv\">faults.csv</a>.</p><table><tr><th class=l>method</th><th>dropped</th><th>lost</th><th>late</th><th>duplicates</th><th>skipped</th><th>held</th><th>recovered</th><th>max |0x092C| ns</th><th>lock band |0x092C| ns</th><th>M-rS band ns</th>"
    );
    for k in &kinds {
        let _ = write!(h, "<th>re-lock after {} ms</th>", esc(k.as_str()));
    }
    let _ = write!(h, "</tr>");
    for m in order {
        let Some(mo) = out.methods.get(m) else {
            continue;
        };
        let f = &mo.faults;
        let sum = |g: fn(&crate::run::FaultsTruth) -> u64| f.iter().map(g).sum::<u64>();
        let mut recovered: Vec<u16> = f
            .iter()
            .flat_map(|x| x.recoveries.iter().flat_map(|r| r.slaves.iter().copied()))
            .collect();
        recovered.sort_unstable();
        recovered.dedup();
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:?}</td><td>{}</td>",
            esc(m),
            sum(|x| x.counts.lost_out + x.counts.lost_back),
            sum(|x| x.lost_cycles),
            sum(|x| x.late_replies),
            sum(|x| x.duplicate_replies),
            sum(|x| x.skipped_cycles),
            sum(|x| x.held_cycles),
            recovered,
            f.iter().map(|x| x.max_rs_is_ns).max().unwrap_or(0)
        );
        let band = f.iter().map(|x| x.lock_band_092c_ns).fold(0.0f64, f64::max);
        let m_band = f
            .iter()
            .filter_map(|x| x.lock_band_m_rs_ns)
            .fold(None, |a: Option<f64>, b| Some(a.map_or(b, |a| a.max(b))));
        let _ = write!(
            h,
            "<td>{band:.0}</td><td>{}</td>",
            m_band.map_or_else(|| "-".to_string(), |b| format!("{b:.0}"))
        );
        for k in 0..kinds.len() {
            let mut worst = Some(0.0f64);
            for x in f {
                worst = match (worst, x.relock_ms.get(k).copied().flatten()) {
                    (Some(a), Some(b)) => Some(a.max(b)),
                    _ => None,
                };
            }
            match worst {
                Some(ms) => {
                    let _ = write!(h, "<td>{ms:.1}</td>");
                }
                None => {
                    let _ = write!(h, "<td>never</td>");
                }
            }
        }
        let _ = write!(h, "</tr>");
    }
    let _ = write!(h, "</table>");
}

fn us3(ns: f64) -> String {
    if ns.is_finite() {
        format!("{:.3}", ns / 1000.0)
    } else {
        "-".into()
    }
}

fn truth_table(h: &mut String, out: &SummaryOut, order: &[String]) {
    let _ = write!(
        h,
        "<h2>Ground truth</h2><p>Only a simulator has it; all runs pooled. The phase is when the frame reached the reference, after the DC grid point; every method aims at the target ({:.1} us) and SYNC0 fires at {:.1} us. A frame is late when its last bit passes a drive after that drive's SYNC0.</p>\
<table><tr><th class=l>method</th><th>mean phase &minus; target (us)</th><th>phase std (us)</th><th>RMS about the target (us)</th><th>min &minus; target (us)</th><th>p99.9 &minus; target (us)</th><th>max &minus; target (us)</th><th>|phase &minus; target| p99.9 (us)</th><th>slave spread p99.9 (ns)</th><th>late frames</th><th>smallest safe SYNC0 shift (%)</th><th>SYNC0 margin min (us)</th><th>init drift offset (us)</th><th>in sync</th><th>lost frames</th><th>DC lock (ms)</th></tr>",
        out.target_phase_ns as f64 / 1000.0,
        out.sync0_shift_pct * f64::from(out.cycle_ns) / 1e5
    );
    for m in order {
        let Some(mo) = out.methods.get(m) else {
            continue;
        };
        let g = &mo.ground_truth;
        let pick = if *m == out.recommendation.method {
            " style=\"background:#eef8ee\""
        } else {
            ""
        };
        let _ = write!(
            h,
            "<tr{pick}><td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.1}</td><td>{}</td><td>{:.1}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.1}</td></tr>",
            esc(m),
            us3(g.offset_from_target_ns),
            us3(g.phase.std),
            us3(g.phase_error.rms),
            us3(g.phase.min - g.target_phase_ns as f64),
            us3(g.phase.p999 - g.target_phase_ns as f64),
            us3(g.phase.max - g.target_phase_ns as f64),
            us3(g.phase_error.p999_abs),
            g.slave_ref_diff.p999_abs,
            g.late_frames,
            g.smallest_safe_shift_pct,
            us3(g.sync0_margin.min),
            mo.init_drift.map_or("-".to_string(), |d| us3(d.offset_ns)),
            mo.controller.map_or("-".to_string(), |c| format!(
                "{:.1} %",
                c.in_sync_fraction * 100.0
            )),
            g.lost_frames,
            mo.lock_ms
        );
    }
    let _ = write!(h, "</table>");
}

fn per_slave_table(h: &mut String, out: &SummaryOut) {
    let m = &out.recommendation.method;
    let Some(mo) = out.methods.get(m) else { return };
    let _ = write!(
        h,
        "<h3>Per drive, with {}</h3><p>SYNC0 minus the instant the frame's last bit passed the drive, and the smallest SYNC0 shift each drive needs. Late frames: frames after the drive's SYNC0. SYNC0 missed: pulses with no new outputs since the one before (the ground truth of what a drive counts: a late frame right after a late one is not one more, its outputs are the next pulse's as far as the drive can tell). Drive's count: its SM-event-missed counter 0x1C32:0B over the same cycles (- for a drive without CoE DC mode).</p><table><tr><th>slave</th><th>position</th><th>margin min (us)</th><th>margin p0.1 (us)</th><th>margin mean (us)</th><th>late frames</th><th>SYNC0 missed</th><th>drive's count</th><th>smallest safe shift (%)</th></tr>",
        esc(m)
    );
    for s in &mo.ground_truth.per_slave {
        let _ = write!(
            h,
            "<tr><td class=l>{}{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.1}</td></tr>",
            esc(&s.name),
            if s.on_sync1 { " [SYNC1]" } else { "" },
            s.position,
            us3(s.margin_min_ns),
            us3(s.margin_p001_ns),
            us3(s.margin_mean_ns),
            s.late_frames,
            s.sync0_missed,
            s.drive_count_shown(),
            s.smallest_safe_shift_pct
        );
    }
    let _ = write!(h, "</table>");
    for note in mo
        .ground_truth
        .per_slave
        .iter()
        .filter_map(|s| s.restart_note())
    {
        let _ = write!(h, "<p>{}</p>", esc(&note));
    }
    if mo.ground_truth.per_slave.iter().any(|s| s.on_sync1) {
        let _ = write!(
            h,
            "<p>[SYNC1]: an oversampling terminal, which takes its outputs at SYNC1 events: its margin, late frames and missed pulses are SYNC1's, on the cycle's grid where the others' SYNC0 pulses are, and its own count is of SYNC1 events.</p>"
        );
    }
}

fn letter_table(h: &mut String, out: &SummaryOut, order: &[String]) {
    let _ = write!(
        h,
        "<h2>The letter's measurements</h2><p>Table 1's statistics (us): the means over {} of each run's mean, standard deviation, maximum and minimum. M-rS is the letter's eq. (10) &phi; for master shift and t<sub>ra</sub> &minus; t<sub>ms</sub> for bus shift; rS-IS the magnitude of a BRD of 0x092C (the OR of every drive's). {}</p><table><tr><th class=l rowspan=2>method</th><th colspan=4>M-rS</th><th colspan=4>rS-IS</th></tr><tr><th>MMean</th><th>MStd</th><th>MMax</th><th>MMin</th><th>MMean</th><th>MStd</th><th>MMax</th><th>MMin</th></tr>",
        crate::scenario::plural(u64::from(out.runs), "run", "runs"),
        if out.letter_testbed {
            "This is the letter's testbed: its values are shown in grey below ours."
        } else {
            "This is not the letter's testbed, so its values are not shown: they are no comparison here."
        }
    );
    for m in order {
        let Some(mo) = out.methods.get(m) else {
            continue;
        };
        let name = if mo.letter_name == "-" {
            esc(m)
        } else {
            format!("{} ({})", esc(m), mo.letter_name)
        };
        let (a, b) = (&mo.m_rs, &mo.rs_is);
        let _ = write!(
            h,
            "<tr><td class=l>{name}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            us3(a.mean),
            us3(a.std),
            us3(a.max),
            us3(a.min),
            us3(b.mean),
            us3(b.std),
            us3(b.max),
            us3(b.min)
        );
        if let Some(l) = &mo.letter {
            let (a, b) = (&l.m_rs, &l.rs_is);
            let _ = write!(
                h,
                "<tr class=letter><td class=l>the letter</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                us3(a.mean),
                us3(a.std),
                us3(a.max),
                us3(a.min),
                us3(b.mean),
                us3(b.std),
                us3(b.max),
                us3(b.min)
            );
        }
    }
    let _ = write!(h, "</table>");
    if let Some(note) = crate::report::m_rs_aim_note(out, order) {
        let _ = write!(h, "<p>{}</p>", esc(&note));
    }
}
