//! Plots (SVG and PNG, drawn with plotters) and report.html.
//!
//! * `fig4_histograms`: the distributions of the M-rS and rS-IS errors of every method, one row
//!   per method, laid out like the letter's Fig. 4 (all runs merged);
//! * `series_<quantity>`: the errors over the recorded cycles of run 0 (the band between the
//!   minimum and maximum of each block of 1000 cycles);
//! * `truth_phase`: the distribution of the true arrival phase at the reference against the DC
//!   grid, with the SYNC0 shift marked.

use crate::compare::Comparison;
use crate::report::SummaryOut;
use crate::run::RunResult;
use crate::stats::Histogram;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::io;
use std::path::Path;
use std::sync::Once;

pub(crate) const COLORS: [RGBColor; 5] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0xff, 0x7f, 0x0e),
    RGBColor(0x94, 0x67, 0xbd),
];

pub(crate) fn fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // Bitmaps need a font file; DejaVu Sans is embedded so no system font is needed.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

pub(crate) fn err<E: std::fmt::Display>(e: E) -> io::Error {
    io::Error::other(e.to_string())
}

/// The range of a histogram that holds all but `tail` of the samples on each side, widened a
/// little, in bin-centre units.
fn range(h: &Histogram, tail: f64) -> (f64, f64) {
    let lo = h.quantile(tail);
    let hi = h.quantile(1.0 - tail);
    if !(lo.is_finite() && hi.is_finite()) {
        // No samples (a run too short to measure anything): an empty plot around zero.
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    (lo - pad, hi + pad)
}

pub(crate) fn draw_hist<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    h: &Histogram,
    title: &str,
    unit_div: f64,
    unit: &str,
    color: RGBColor,
) -> io::Result<()> {
    let (lo, hi) = range(h, 0.0005);
    let bins: Vec<(f64, u64)> = h.bins().filter(|(x, _)| *x >= lo && *x <= hi).collect();
    // Re-bin to at most 200 bars so that every plot reads the same.
    let width = (hi - lo) / 200.0;
    let mut bars = vec![0u64; 200];
    for (x, c) in bins {
        let k = (((x - lo) / width) as usize).min(199);
        bars[k] += c;
    }
    let total: u64 = h.total().max(1);
    let ymax = bars.iter().copied().max().unwrap_or(1) as f64 / total as f64 * 100.0;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(32)
        .y_label_area_size(48)
        .build_cartesian_2d(lo / unit_div..hi / unit_div, 0.0..ymax * 1.1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(unit)
        .y_desc("% of samples")
        .light_line_style(WHITE)
        .draw()
        .map_err(err)?;
    chart
        .draw_series(bars.iter().enumerate().map(|(k, &c)| {
            let x0 = (lo + k as f64 * width) / unit_div;
            let x1 = (lo + (k + 1) as f64 * width) / unit_div;
            Rectangle::new(
                [(x0, 0.0), (x1, c as f64 / total as f64 * 100.0)],
                color.mix(0.8).filled(),
            )
        }))
        .map_err(err)?;
    Ok(())
}

fn fig4<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((order.len(), 2));
    for (i, name) in order.iter().enumerate() {
        let Some(m) = c.scenario.methods.iter().position(|x| x == name) else {
            continue;
        };
        let merge = |pick: fn(&RunResult) -> &Histogram| {
            let mut it = c.results[m].iter();
            let mut h = pick(it.next()?).clone();
            for r in it {
                h.merge(pick(r));
            }
            Some(h)
        };
        let letter = crate::letter::letter_name(name);
        let label = if letter == "-" {
            name.clone()
        } else {
            format!("{letter} ({name})")
        };
        if let Some(h) = merge(|r| &r.m_rs.hist) {
            draw_hist(
                &rows[2 * i],
                &h,
                &format!("{label}: M-rS error"),
                1000.0,
                "us",
                COLORS[i % 5],
            )?;
        }
        if let Some(h) = merge(|r| &r.rs_is.hist) {
            draw_hist(
                &rows[2 * i + 1],
                &h,
                &format!("{label}: rS-IS error |0x092C|"),
                1.0,
                "ns",
                COLORS[i % 5],
            )?;
        }
    }
    root.present().map_err(err)
}

fn series<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
    which: usize,
    title: &str,
    unit_div: f64,
    unit: &str,
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((order.len(), 1));
    for (i, name) in order.iter().enumerate() {
        let Some(m) = c.scenario.methods.iter().position(|x| x == name) else {
            continue;
        };
        let Some(r) = c.results[m].first() else {
            continue;
        };
        let s = &r.series[which];
        if s.is_empty() {
            continue;
        }
        draw_envelopes(
            &rows[i],
            s,
            &format!("{name}: {title}"),
            f64::from(c.scenario.cycle_ns) * 1e-9,
            unit_div,
            unit,
            COLORS[i % 5],
        )?;
    }
    root.present().map_err(err)
}

fn truth_phase<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((order.len(), 1));
    for (i, name) in order.iter().enumerate() {
        let Some(m) = c.scenario.methods.iter().position(|x| x == name) else {
            continue;
        };
        let mut it = c.results[m].iter();
        let Some(first) = it.next() else { continue };
        let mut h = first.phase.hist.clone();
        for r in it {
            h.merge(&r.phase.hist);
        }
        draw_hist(
            &rows[i],
            &h,
            &format!(
                "{name}: true arrival at the reference after its DC grid point (SYNC0 at +{:.0} us)",
                c.scenario.sync0_shift_pct * f64::from(c.scenario.cycle_ns) / 1e5
            ),
            1000.0,
            "us",
            COLORS[i % 5],
        )?;
    }
    root.present().map_err(err)
}

/// Draws a series of min..max envelopes (one per block of cycles) against seconds.
pub(crate) fn draw_envelopes<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    s: &[crate::run::Envelope],
    title: &str,
    cycle_s: f64,
    unit_div: f64,
    unit: &str,
    col: RGBColor,
) -> io::Result<()> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for e in s {
        lo = lo.min(f64::from(e.min));
        hi = hi.max(f64::from(e.max));
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    let t_end = s.last().map_or(1.0, |e| e.cycle as f64) * cycle_s;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 15))
        .margin(6)
        .x_label_area_size(28)
        .y_label_area_size(56)
        .build_cartesian_2d(
            0.0..t_end.max(cycle_s),
            (lo - pad) / unit_div..(hi + pad) / unit_div,
        )
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("s since the start of recording")
        .y_desc(unit)
        .light_line_style(WHITE)
        .draw()
        .map_err(err)?;
    let block_s = crate::run::SERIES_BLOCK as f64 * cycle_s;
    chart
        .draw_series(s.iter().map(|e| {
            let t = e.cycle as f64 * cycle_s;
            let (a, b) = (f64::from(e.min) / unit_div, f64::from(e.max) / unit_div);
            // A block whose values are all equal is drawn across its span, so it shows.
            let pts = if a == b {
                vec![(t, a), (t + block_s * 0.8, a)]
            } else {
                vec![(t, a), (t, b)]
            };
            PathElement::new(pts, col.mix(0.6).stroke_width(2))
        }))
        .map_err(err)?;
    Ok(())
}

type Plot<'a> = dyn Fn(&Path, bool) -> io::Result<()> + 'a;

/// Writes every plot and report.html into `dir`.
pub fn write_all(c: &Comparison, out: &SummaryOut, order: &[String], dir: &Path) -> io::Result<()> {
    fonts();
    let rows = order.len() as u32;
    let plots: Vec<(&str, (u32, u32), Box<Plot<'_>>)> = vec![
        (
            "fig4_histograms",
            (1100, 260 * rows),
            Box::new(move |p: &Path, svg: bool| {
                if svg {
                    fig4(
                        SVGBackend::new(p, (1100, 260 * rows)).into_drawing_area(),
                        c,
                        order,
                    )
                } else {
                    fig4(
                        BitMapBackend::new(p, (1100, 260 * rows)).into_drawing_area(),
                        c,
                        order,
                    )
                }
            }),
        ),
        (
            "series_m_rs",
            (1100, 200 * rows),
            Box::new(move |p: &Path, svg: bool| {
                let t = "M-rS error, min..max per 1000 cycles (run 0)";
                if svg {
                    series(
                        SVGBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        0,
                        t,
                        1000.0,
                        "us",
                    )
                } else {
                    series(
                        BitMapBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        0,
                        t,
                        1000.0,
                        "us",
                    )
                }
            }),
        ),
        (
            "series_rs_is",
            (1100, 200 * rows),
            Box::new(move |p: &Path, svg: bool| {
                let t = "rS-IS error |0x092C|, min..max per 1000 cycles (run 0)";
                if svg {
                    series(
                        SVGBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        1,
                        t,
                        1.0,
                        "ns",
                    )
                } else {
                    series(
                        BitMapBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        1,
                        t,
                        1.0,
                        "ns",
                    )
                }
            }),
        ),
        (
            "series_true_phase",
            (1100, 200 * rows),
            Box::new(move |p: &Path, svg: bool| {
                let t = "true arrival phase at the reference, min..max per 1000 cycles (run 0)";
                if svg {
                    series(
                        SVGBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        2,
                        t,
                        1000.0,
                        "us",
                    )
                } else {
                    series(
                        BitMapBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                        2,
                        t,
                        1000.0,
                        "us",
                    )
                }
            }),
        ),
        (
            "truth_phase",
            (1100, 200 * rows),
            Box::new(move |p: &Path, svg: bool| {
                if svg {
                    truth_phase(
                        SVGBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                    )
                } else {
                    truth_phase(
                        BitMapBackend::new(p, (1100, 200 * rows)).into_drawing_area(),
                        c,
                        order,
                    )
                }
            }),
        ),
    ];
    for (name, _, f) in &plots {
        for (ext, svg) in [("svg", true), ("png", false)] {
            let fin = dir.join(format!("{name}.{ext}"));
            let tmp = dir.join(format!("{name}.tmp-ecsync.{ext}"));
            f(&tmp, svg)?;
            std::fs::rename(&tmp, &fin)?;
        }
    }
    let html = report_html(out, order, &plots.iter().map(|p| p.0).collect::<Vec<_>>());
    crate::report::write_atomic(&dir.join("report.html"), html.as_bytes())
}

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn report_html(out: &SummaryOut, order: &[String], plots: &[&str]) -> String {
    let mut h = String::new();
    let us = |v: f64| format!("{:.3}", v / 1000.0);
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync compare: {}</title>\
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px}}table{{border-collapse:collapse;margin:1em 0}}\
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}th{{background:#eee}}td.l,th.l{{text-align:left}}\
.letter{{color:#777}}img{{max-width:100%;border:1px solid #ddd;margin:0.5em 0}}</style></head><body>",
        esc(&out.scenario)
    );
    let _ = write!(
        h,
        "<h1>ecsync compare</h1><p>{}: {} slaves, host <b>{}</b>, {} runs &times; {} recorded cycles after {} warm-up cycles, cycle {} us, SYNC0 shift {} %, seed {}. Every method saw the same noise.</p>",
        esc(&out.scenario),
        out.slaves,
        esc(&out.host),
        out.runs,
        out.cycles,
        out.warmup_cycles,
        out.cycle_ns / 1000,
        out.sync0_shift_pct,
        out.seed
    );
    let _ = write!(h, "<h2>Plots</h2>");
    for p in plots {
        let _ = write!(h, "<h3>{p}</h3><img src=\"{p}.svg\" alt=\"{p}\">");
    }
    let _ = write!(
        h,
        "<h2>Table 1 (us): ecsync beside the letter</h2><table><tr><th class=l>Indicator</th>"
    );
    for m in order {
        let mo = &out.methods[m];
        let _ = write!(
            h,
            "<th colspan=2>{} {}</th>",
            esc(m),
            if mo.letter_name == "-" {
                String::new()
            } else {
                format!("({})", mo.letter_name)
            }
        );
    }
    let _ = write!(h, "</tr><tr><th></th>");
    for _ in order {
        let _ = write!(h, "<th>M-rS</th><th>rS-IS</th>");
    }
    let _ = write!(h, "</tr>");
    for (label, k) in [("MMean", 0), ("MStd", 1), ("MMax", 2), ("MMin", 3)] {
        let pick = |i: &crate::report::Indicators| [i.mean, i.std, i.max, i.min][k];
        let pickl = |r: &crate::letter::Row| [r.mean, r.std, r.max, r.min][k];
        let _ = write!(h, "<tr><td class=l>{label} ecsync</td>");
        for m in order {
            let mo = &out.methods[m];
            let _ = write!(
                h,
                "<td>{}</td><td>{}</td>",
                us(pick(&mo.m_rs)),
                us(pick(&mo.rs_is))
            );
        }
        let _ = write!(h, "</tr><tr class=letter><td class=l>{label} letter</td>");
        for m in order {
            match &out.methods[m].letter {
                Some(l) => {
                    let _ = write!(
                        h,
                        "<td>{}</td><td>{}</td>",
                        us(pickl(&l.m_rs)),
                        us(pickl(&l.rs_is))
                    );
                }
                None => {
                    let _ = write!(h, "<td>-</td><td>-</td>");
                }
            }
        }
        let _ = write!(h, "</tr>");
    }
    let _ = write!(h, "</table>");
    let _ = write!(
        h,
        "<h2>Ground truth</h2><table><tr><th class=l>method</th><th>true phase std (us)</th><th>phase p99.9 |x| (us)</th><th>|slave-ref| p99 (ns)</th><th>|slave-ref| max (ns)</th><th>SYNC0 margin min (us)</th><th>late frames @ {} %</th><th>smallest safe shift (%)</th><th>lost frames</th><th>DC lock (ms)</th></tr>",
        out.sync0_shift_pct
    );
    for m in order {
        let mo = &out.methods[m];
        let g = &mo.ground_truth;
        let _ = write!(
            h,
            "<tr><td class=l>{}</td><td>{:.3}</td><td>{:.3}</td><td>{:.1}</td><td>{:.1}</td><td>{:.1}</td><td>{}</td><td>{:.1}</td><td>{}</td><td>{:.1}</td></tr>",
            esc(m),
            g.phase.std / 1000.0,
            g.phase.p999 / 1000.0,
            g.slave_ref_diff.p99,
            g.slave_ref_diff.max_abs,
            g.sync0_margin.min / 1000.0,
            g.late_frames,
            g.smallest_safe_shift_pct,
            g.lost_frames,
            mo.lock_ms
        );
    }
    let _ = write!(
        h,
        "</table><p>Definitions: M-rS is the letter's eq. (10) &phi; for master-shift methods and t<sub>ra</sub> &minus; t<sub>ms</sub> for bus shift; rS-IS is the magnitude of a BRD of 0x092C (the OR of every slave's register, as the letter reads it). The true phase is when the frame reached the reference, in its system time, after the DC grid point the master aims at; SYNC0 fires at the shift after it; a frame is late when its last bit passes the last slave after SYNC0. Files: <a href=\"summary.json\">summary.json</a>, <a href=\"summary.csv\">summary.csv</a>, <a href=\"table1.txt\">table1.txt</a>. Wall time {:.1} s on {} threads.</p></body></html>",
        out.wall_s, out.threads
    );
    h
}
