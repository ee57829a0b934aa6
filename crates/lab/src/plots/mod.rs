//! Plots (SVG and PNG, drawn with plotters), each with a caption in words, and report.html
//! around them (the `html` module).
//!
//! * `hist_<metric>`: one histogram per metric with every method overlaid on shared axes (all
//!   runs pooled; log scale of the share of cycles, so the tails show); the phase and the SYNC0
//!   margin carry the deadline;
//! * `series_<metric>`: run 0 over time as percentile bands (min..max, 1st..99th percentile,
//!   median) over at most [`crate::run::BAND_POINTS`] blocks, one panel per method on a shared
//!   axis: the files are as large at a billion cycles as at a thousand;
//! * `fig4_histograms`: the letter's Fig. 4 layout (M-rS and rS-IS of each method).

use crate::compare::Comparison;
use crate::html::report_html;
use crate::output::write_atomic;
use crate::report::SummaryOut;
use crate::run::{Band, RunResult};
use crate::stats::{Dist, Stats};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::io;
use std::path::Path;
use std::sync::Once;

pub(crate) const COLORS: [RGBColor; 8] = [
    RGBColor(0x1f, 0x77, 0xb4),
    RGBColor(0x17, 0xbe, 0xcf),
    RGBColor(0xd6, 0x27, 0x28),
    RGBColor(0x2c, 0xa0, 0x2c),
    RGBColor(0x8c, 0x56, 0x4b),
    RGBColor(0xe3, 0x77, 0xc2),
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

/// The range holding all but `tail` of the samples on each side, widened a little.
fn range(h: &Dist, tail: f64) -> (f64, f64) {
    let lo = h.quantile(tail);
    let hi = h.quantile(1.0 - tail);
    if !(lo.is_finite() && hi.is_finite()) {
        // No samples (a run too short to measure anything): an empty plot around zero.
        return (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1.0);
    (lo - pad, hi + pad)
}

/// `bins` counts of `h` over `[lo, hi)`, values outside added to the end bins.
fn rebin(h: &Dist, lo: f64, hi: f64, bins: usize) -> Vec<u64> {
    let width = (hi - lo) / bins as f64;
    let mut out = vec![0u64; bins];
    for (x, c) in h.bins() {
        let k = ((x - lo) / width).floor().clamp(0.0, (bins - 1) as f64) as usize;
        out[k] += c;
    }
    out
}

/// One distribution as bars (the TSN run's plots).
pub(crate) fn draw_hist<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    h: &Dist,
    title: &str,
    unit_div: f64,
    unit: &str,
    color: RGBColor,
) -> io::Result<()> {
    let (lo, hi) = range(h, 0.0005);
    let bars = rebin(h, lo, hi, 200);
    let width = (hi - lo) / 200.0;
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

fn pooled(c: &Comparison, m: usize, pick: fn(&RunResult) -> &Stats) -> Stats {
    let mut s = Stats::new();
    for r in &c.results[m] {
        s.merge(pick(r));
    }
    s
}

/// A vertical line on a histogram or series: where, its label.
struct Mark {
    at_ns: f64,
    label: String,
    color: RGBColor,
}

/// Every method's distribution of one metric on shared axes, as outlines on a log scale.
#[allow(clippy::too_many_arguments)]
fn overlaid<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
    pick: fn(&RunResult) -> &Stats,
    title: &str,
    unit_div: f64,
    unit: &str,
    marks: &[Mark],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let dists: Vec<(usize, &String, Stats)> = order
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let m = c
                .scenario
                .methods
                .iter()
                .position(|x| x.name() == name.as_str())?;
            Some((i, name, pooled(c, m, pick)))
        })
        .collect();
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, _, s) in &dists {
        if s.count() == 0 {
            continue;
        }
        let (a, b) = range(&s.dist, 0.0005);
        lo = lo.min(a);
        hi = hi.max(b);
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (-1.0, 1.0);
    }
    // A deadline near the distributions is drawn inside the axes; one far off is named at the
    // edge.
    let width = hi - lo;
    for mk in marks {
        if mk.at_ns > hi && mk.at_ns - hi < 2.0 * width {
            hi = mk.at_ns + 0.05 * width;
        }
        if mk.at_ns < lo && lo - mk.at_ns < 2.0 * width {
            lo = mk.at_ns - 0.05 * width;
        }
    }
    const BINS: usize = 160;
    let bw = (hi - lo) / BINS as f64;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(lo / unit_div..hi / unit_div, (1e-5f64..100.0).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(unit)
        .y_desc("% of cycles (log)")
        .light_line_style(RGBColor(0xee, 0xee, 0xee))
        .draw()
        .map_err(err)?;
    for (i, name, s) in &dists {
        let total = s.count().max(1) as f64;
        let bars = rebin(&s.dist, lo, hi, BINS);
        let col = COLORS[*i % COLORS.len()];
        let mut pts = Vec::with_capacity(2 * BINS + 2);
        for (k, &n) in bars.iter().enumerate() {
            let y = (n as f64 / total * 100.0).max(1e-5);
            let x0 = (lo + k as f64 * bw) / unit_div;
            let x1 = (lo + (k + 1) as f64 * bw) / unit_div;
            pts.push((x0, y));
            pts.push((x1, y));
        }
        chart
            .draw_series(std::iter::once(PathElement::new(pts, col.stroke_width(2))))
            .map_err(err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(3)));
    }
    for mk in marks {
        let x = mk.at_ns / unit_div;
        let col = mk.color;
        if mk.at_ns >= lo && mk.at_ns <= hi {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    vec![(x, 1e-5), (x, 100.0)],
                    col.stroke_width(2),
                )))
                .map_err(err)?
                .label(mk.label.as_str())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2))
                });
        } else {
            let edge = if mk.at_ns > hi { hi } else { lo } / unit_div;
            let text = format!(
                "{} {} at {:.1} {unit}",
                if mk.at_ns > hi { "->" } else { "<-" },
                mk.label,
                x
            );
            chart
                .draw_series(std::iter::once(Text::new(
                    text,
                    (edge, 30.0),
                    ("sans-serif", 14).into_font().color(&col),
                )))
                .map_err(err)?;
        }
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(0xcc, 0xcc, 0xcc))
        .draw()
        .map_err(err)?;
    root.present().map_err(err)
}

/// Run 0 of every method over time as percentile bands, one panel each, on a shared y axis.
#[allow(clippy::too_many_arguments)]
fn bands<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
    which: usize,
    title: &str,
    unit_div: f64,
    unit: &str,
    marks: &[Mark],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let series: Vec<(usize, &String, &RunResult)> = order
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let m = c
                .scenario
                .methods
                .iter()
                .position(|x| x.name() == name.as_str())?;
            Some((i, name, c.results[m].first()?))
        })
        .collect();
    // The shared axis holds every method's 1st..99th band, widened; the extremes beyond it are
    // clipped (they are in the histograms).
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (_, _, r) in &series {
        for b in &r.series[which] {
            lo = lo.min(f64::from(b.p01));
            hi = hi.max(f64::from(b.p99));
        }
    }
    if !(lo.is_finite() && hi.is_finite()) {
        (lo, hi) = (-1.0, 1.0);
    }
    let pad = ((hi - lo) * 0.25).max(1.0);
    let (lo, hi) = (lo - pad, hi + pad);
    let cycle_s = f64::from(c.scenario.cycle_ns) * 1e-9;
    let (head, body) = root.split_vertically(30);
    head.titled(title, ("sans-serif", 18)).map_err(err)?;
    let rows = body.split_evenly((series.len().max(1), 1));
    for (k, (i, name, r)) in series.iter().enumerate() {
        let s: &[Band] = &r.series[which];
        let col = COLORS[*i % COLORS.len()];
        let block = r.series_block.max(1) as f64;
        let t_end = s.last().map_or(1.0, |b| b.cycle as f64 + block) * cycle_s;
        let mut chart = ChartBuilder::on(&rows[k])
            .caption(name.as_str(), ("sans-serif", 14))
            .margin(4)
            .x_label_area_size(24)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_end.max(cycle_s), lo / unit_div..hi / unit_div)
            .map_err(err)?;
        chart
            .configure_mesh()
            .y_desc(unit)
            .x_labels(8)
            .light_line_style(RGBColor(0xf0, 0xf0, 0xf0))
            .draw()
            .map_err(err)?;
        let clip = |v: f32| (f64::from(v).clamp(lo, hi)) / unit_div;
        let t = |b: &Band| b.cycle as f64 * cycle_s;
        let dt = block * cycle_s;
        // min..max, light; 1st..99th, darker; the median, a line. Each band is one polygon
        // (steps along its upper edge, back along its lower one): a few kilobytes whatever the
        // cycles.
        let band = |lo_of: fn(&Band) -> f32, hi_of: fn(&Band) -> f32| {
            let mut pts = Vec::with_capacity(4 * s.len());
            for b in s {
                pts.push((t(b), clip(hi_of(b))));
                pts.push((t(b) + dt, clip(hi_of(b))));
            }
            for b in s.iter().rev() {
                pts.push((t(b) + dt, clip(lo_of(b))));
                pts.push((t(b), clip(lo_of(b))));
            }
            pts
        };
        chart
            .draw_series(std::iter::once(Polygon::new(
                band(|b| b.min, |b| b.max),
                col.mix(0.18).filled(),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(Polygon::new(
                band(|b| b.p01, |b| b.p99),
                col.mix(0.5).filled(),
            )))
            .map_err(err)?;
        chart
            .draw_series(std::iter::once(PathElement::new(
                s.iter()
                    .map(|b| (t(b) + dt / 2.0, clip(b.p50)))
                    .collect::<Vec<_>>(),
                col.stroke_width(1),
            )))
            .map_err(err)?;
        for mk in marks {
            if mk.at_ns >= lo && mk.at_ns <= hi {
                let y = mk.at_ns / unit_div;
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(0.0, y), (t_end, y)],
                        mk.color.stroke_width(1),
                    )))
                    .map_err(err)?;
            }
        }
    }
    root.present().map_err(err)
}

/// Run 0's |0x092C| around each fault, every method on one panel per fault (log scale; a lost
/// cycle is a gap, a cycle whose reference time the master held is drawn light).
fn fault_windows<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let runs: Vec<(usize, &String, &crate::run::FaultsTruth)> = order
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let m = c
                .scenario
                .methods
                .iter()
                .position(|x| x.name() == name.as_str())?;
            Some((i, name, c.results[m].first()?.faults.as_ref()?))
        })
        .collect();
    let n = runs.iter().map(|r| r.2.windows.len()).max().unwrap_or(0);
    let (head, body) = root.split_vertically(30);
    head.titled(
        "|0x092C| around each fault (run 0; ms since the fault started; log scale)",
        ("sans-serif", 18),
    )
    .map_err(err)?;
    if n == 0 {
        return root.present().map_err(err);
    }
    let rows = body.split_evenly((n, 1));
    for (k, row) in rows.iter().enumerate() {
        let t_end = runs
            .iter()
            .filter_map(|r| r.2.windows.get(k)?.points.last().map(|p| f64::from(p.0)))
            .fold(1.0f64, f64::max);
        let kind = runs
            .iter()
            .find_map(|r| r.2.windows.get(k).map(|w| (w.fault, w.kind.as_str())))
            .unwrap_or((k, ""));
        let mut chart = ChartBuilder::on(row)
            .caption(format!("fault {}: {}", kind.0, kind.1), ("sans-serif", 14))
            .margin(4)
            .x_label_area_size(24)
            .y_label_area_size(60)
            .build_cartesian_2d(0.0..t_end, (1.0f64..3e9f64).log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .y_desc("ns")
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .x_labels(10)
            .light_line_style(RGBColor(0xf0, 0xf0, 0xf0))
            .draw()
            .map_err(err)?;
        for (i, name, f) in &runs {
            let Some(w) = f.windows.get(k) else { continue };
            let col = COLORS[*i % COLORS.len()];
            // Runs of cycles that came back, one path each: a lost cycle breaks the line.
            let mut path: Vec<(f64, f64)> = Vec::new();
            let mut paths = Vec::new();
            for &(t, v, _) in &w.points {
                if v.is_finite() {
                    path.push((f64::from(t), f64::from(v).max(1.0)));
                } else if !path.is_empty() {
                    paths.push(std::mem::take(&mut path));
                }
            }
            paths.push(path);
            let mut first = true;
            for p in paths.into_iter().filter(|p| !p.is_empty()) {
                let s = chart
                    .draw_series(std::iter::once(PathElement::new(p, col.stroke_width(1))))
                    .map_err(err)?;
                if std::mem::take(&mut first) && k == 0 {
                    let label = (*name).clone();
                    s.label(label).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2))
                    });
                }
            }
        }
        if k == 0 {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(err)?;
        }
        // The lock bound.
        chart
            .draw_series(std::iter::once(PathElement::new(
                vec![(0.0, 100.0), (t_end, 100.0)],
                RGBColor(0xc0, 0x00, 0x00).stroke_width(1),
            )))
            .map_err(err)?;
    }
    root.present().map_err(err)
}

fn fig4<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((order.len(), 2));
    for (i, name) in order.iter().enumerate() {
        let entries = c.scenario.entries();
        let Some(m) = entries.iter().position(|x| x.name() == *name) else {
            continue;
        };
        let e = entries[m];
        let letter = crate::letter::letter_name(e.kind);
        let label = if letter == "-" {
            name.clone()
        } else {
            format!("{letter} ({name})")
        };
        let col = COLORS[i % COLORS.len()];
        draw_hist(
            &rows[2 * i],
            &pooled(c, m, |r| &r.m_rs).dist,
            &format!("{label}: M-rS error"),
            1000.0,
            "us",
            col,
        )?;
        draw_hist(
            &rows[2 * i + 1],
            &pooled(c, m, |r| &r.rs_is).dist,
            &format!("{label}: rS-IS error |0x092C|"),
            1.0,
            "ns",
            col,
        )?;
    }
    root.present().map_err(err)
}

/// Draws a series of min..max envelopes (one per block of cycles) against seconds (the TSN
/// run's series).
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

type Draw<'a> = Box<dyn Fn(&Path, bool) -> io::Result<()> + 'a>;

/// A plot: file stem, caption, size, how to draw it.
struct Plot<'a> {
    name: &'static str,
    caption: String,
    draw: Draw<'a>,
}

/// Draws `$body` on an SVG (`$svg`) or PNG of `$size` at `$p`, the drawing area bound to
/// `$root`.
macro_rules! plot {
    ($p:expr, $svg:expr, $size:expr, |$root:ident| $body:expr) => {
        if $svg {
            let $root = SVGBackend::new($p, $size).into_drawing_area();
            $body
        } else {
            let $root = BitMapBackend::new($p, $size).into_drawing_area();
            $body
        }
    };
}

/// Writes every plot and report.html into `dir`: the faults (with a schedule), the
/// histograms, run 0's series and Fig. 4's layout, each as SVG and PNG.
pub fn write_all(c: &Comparison, out: &SummaryOut, order: &[String], dir: &Path) -> io::Result<()> {
    fonts();
    let lines = PhaseLines::of(c, out);
    let mut plots: Vec<Plot<'_>> = faults_plot(c, order).into_iter().collect();
    plots.extend(histograms(c, order, lines));
    plots.extend(series(c, order, lines));
    for pl in &plots {
        for (ext, svg) in [("svg", true), ("png", false)] {
            let fin = dir.join(format!("{}.{ext}", pl.name));
            let tmp = dir.join(format!("{}.tmp-ecsync.{ext}", pl.name));
            (pl.draw)(&tmp, svg)?;
            std::fs::rename(&tmp, &fin)?;
        }
    }
    let html = report_html(
        out,
        order,
        &plots
            .iter()
            .map(|p| (p.name, p.caption.as_str()))
            .collect::<Vec<_>>(),
    );
    write_atomic(&dir.join("report.html"), html.as_bytes())
}

/// Where the phase plots draw their lines, ns after the DC grid point.
#[derive(Debug, Clone, Copy)]
struct PhaseLines {
    /// The target every method aims at.
    target_ns: f64,
    /// A frame after this was late: SYNC0 minus the frame's transit to the worst slave.
    deadline_ns: f64,
    /// SYNC0.
    shift_ns: f64,
}

impl PhaseLines {
    /// The comparison's lines: its target, its SYNC0 and the margin the summary found.
    fn of(c: &Comparison, out: &SummaryOut) -> Self {
        let s = &c.scenario;
        let target_ns = s.target_phase_ns as f64;
        PhaseLines {
            target_ns,
            deadline_ns: out.margin_budget_ns + target_ns,
            shift_ns: f64::from(s.sync0_shift_ns()),
        }
    }

    /// The target (grey) and the late line (red).
    fn marks(self) -> Vec<Mark> {
        vec![
            Mark {
                at_ns: self.target_ns,
                label: "target".into(),
                color: GREY,
            },
            Mark {
                at_ns: self.deadline_ns,
                label: "late beyond (SYNC0 minus the frame's transit)".into(),
                color: RED,
            },
        ]
    }
}

/// The late line's red.
const RED: RGBColor = RGBColor(0xc0, 0x00, 0x00);
/// The target's grey.
const GREY: RGBColor = RGBColor(0x55, 0x55, 0x55);

/// SYNC0 (red) on the margin's axis.
fn margin_marks() -> Vec<Mark> {
    vec![Mark {
        at_ns: 0.0,
        label: "SYNC0 (late below 0)".into(),
        color: RED,
    }]
}

/// Each fault window of run 0, when the comparison played a schedule.
fn faults_plot<'a>(c: &'a Comparison, order: &'a [String]) -> Option<Plot<'a>> {
    let windows = c
        .results
        .iter()
        .flatten()
        .filter_map(|r| r.faults.as_ref())
        .map(|f| f.windows.len())
        .max()
        .unwrap_or(0);
    (windows > 0).then(|| {
        Plot {
            name: "faults",
            caption: "Each fault of the schedule in run 0: |0x092C| (the BRD's OR over every drive) from the fault's start to a second after its end, per method; a gap is a lost cycle; the red line is 100 ns, the lock band of every method that does not write the master's time into the reference. A master that brings a reset slave back shows the gap, the far values of the reset slave, and the way back under the line.".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 200 * windows as u32 + 40), |r| fault_windows(r, c, order))
            }),
        }
    })
}

/// Every method's distribution of each metric on shared axes: the true phase, the SYNC0
/// margin, the slave spread, M-rS and rS-IS.
fn histograms<'a>(c: &'a Comparison, order: &'a [String], lines: PhaseLines) -> Vec<Plot<'a>> {
    let s = &c.scenario;
    let runs = crate::scenario::plural(u64::from(s.runs), "run", "runs");
    let (target, deadline, shift) = (lines.target_ns, lines.deadline_ns, lines.shift_ns);
    vec![
        Plot {
            name: "hist_phase",
            caption: format!(
                "When each frame reached the reference, after the DC grid point (the frames of all {runs} pooled; log scale of the share of cycles). The grey line is the target every method aims at ({:.1} us); a frame to the right of the red line ({:.1} us: SYNC0 at {:.1} us minus the frame's transit to the worst slave) was late. The spread is the host's scheduling jitter, which no master-shift method can remove from the actual send.",
                target / 1000.0,
                deadline / 1000.0,
                shift / 1000.0
            ),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 520), |r| overlaid(
                    r,
                    c,
                    order,
                    |x| &x.phase,
                    "true phase: the frame's arrival at the reference after the DC grid point",
                    1000.0,
                    "us",
                    &lines.marks(),
                ))
            }),
        },
        Plot {
            name: "hist_margin",
            caption: format!(
                "SYNC0 minus the instant the frame's last bit passed the worst slave, per cycle: how much earlier than needed the outputs arrived. Below 0 (the red line) a drive met its SYNC0 without this cycle's outputs. SYNC0 is at {:.1} % of the cycle.",
                s.sync0_shift_pct
            ),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 520), |r| overlaid(
                    r,
                    c,
                    order,
                    |x| &x.margin,
                    "SYNC0 margin at the worst slave",
                    1000.0,
                    "us",
                    &margin_marks(),
                ))
            }),
        },
        Plot {
            name: "hist_spread",
            caption: "The largest difference between a drive's system time and the reference's at the same instant (every 8th cycle): how well the drives agree. Bus shift methods move the reference, and the others follow it.".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 480), |r| overlaid(
                    r,
                    c,
                    order,
                    |x| &x.slave_diff,
                    "slave spread: largest |drive - reference| system time",
                    1.0,
                    "ns",
                    &[],
                ))
            }),
        },
        Plot {
            name: "hist_m_rs",
            caption: "The letter's M-rS error: its eq. (10) phi for master-shift methods (the reference's time at the frame's arrival against the master's send timestamp, less the set point), t_ra - t_ms for bus shift. It is what the master sees; the true phase above is what happened.".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 480), |r| overlaid(
                    r,
                    c,
                    order,
                    |x| &x.m_rs,
                    "M-rS error (the letter's measurement)",
                    1000.0,
                    "us",
                    &[],
                ))
            }),
        },
        Plot {
            name: "hist_rs_is",
            caption: "The letter's rS-IS error: the magnitude of a BRD of 0x092C, the OR of every drive's filtered difference to the times it received. Bus shift's writes to the reference show here.".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 480), |r| overlaid(
                    r,
                    c,
                    order,
                    |x| &x.rs_is,
                    "rS-IS error |0x092C| (the letter's measurement)",
                    1.0,
                    "ns",
                    &[],
                ))
            }),
        },
    ]
}

/// Run 0 over time, a panel per method (the true phase, M-rS, rS-IS), and the letter's Fig. 4
/// layout.
fn series<'a>(c: &'a Comparison, order: &'a [String], lines: PhaseLines) -> Vec<Plot<'a>> {
    let n = order.len().max(1) as u32;
    let block = c
        .results
        .iter()
        .flatten()
        .next()
        .map_or(1, |r| r.series_block);
    vec![
        Plot {
            name: "series_true_phase",
            caption: format!(
                "Run 0's true phase over time: per block of {block} cycles the extremes (light), the 1st to 99th percentile (dark) and the median (line), with the target (grey) and the late line (red) where they fit the axis. The first seconds show how a method pulls in after its warm-up."
            ),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 150 * n + 40), |r| bands(
                    r,
                    c,
                    order,
                    2,
                    "true phase over time (run 0; s since recording started)",
                    1000.0,
                    "us",
                    &lines.marks(),
                ))
            }),
        },
        Plot {
            name: "series_m_rs",
            caption: format!("Run 0's M-rS error over time, bands as above (blocks of {block} cycles)."),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 150 * n + 40), |r| bands(
                    r,
                    c,
                    order,
                    0,
                    "M-rS error over time (run 0; s since recording started)",
                    1000.0,
                    "us",
                    &[],
                ))
            }),
        },
        Plot {
            name: "series_rs_is",
            caption: format!("Run 0's rS-IS error over time, bands as above (blocks of {block} cycles)."),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 150 * n + 40), |r| bands(
                    r,
                    c,
                    order,
                    1,
                    "rS-IS error |0x092C| over time (run 0; s since recording started)",
                    1.0,
                    "ns",
                    &[],
                ))
            }),
        },
        Plot {
            name: "fig4_histograms",
            caption: "The letter's Fig. 4 layout: each method's M-rS and rS-IS distributions on their own axes (linear scale).".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 220 * n), |r| fig4(r, c, order))
            }),
        },
    ]
}
