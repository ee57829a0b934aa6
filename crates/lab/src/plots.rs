//! Plots (SVG and PNG, drawn with plotters) and report.html: the verdict and the tables first,
//! then the plots, each with a caption in words.
//!
//! * `hist_<metric>`: one histogram per metric with every method overlaid on shared axes (all
//!   runs pooled; log scale of the share of cycles, so the tails show); the phase and the SYNC0
//!   margin carry the deadline;
//! * `series_<metric>`: run 0 over time as percentile bands (min..max, 1st..99th percentile,
//!   median) over at most [`crate::run::BAND_POINTS`] blocks, one panel per method on a shared
//!   axis: the files are as large at a billion cycles as at a thousand;
//! * `fig4_histograms`: the letter's Fig. 4 layout (M-rS and rS-IS of each method).

use crate::compare::Comparison;
use crate::output::write_atomic;
use crate::report::{SummaryOut, verdict_text};
use crate::run::{Band, RunResult};
use crate::stats::{Dist, Stats};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt::Write as _;
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

/// Writes every plot and report.html into `dir`.
pub fn write_all(c: &Comparison, out: &SummaryOut, order: &[String], dir: &Path) -> io::Result<()> {
    fonts();
    let n = order.len().max(1) as u32;
    let s = &c.scenario;
    let shift = f64::from(s.sync0_shift_ns());
    let target = s.target_phase_ns as f64;
    let deadline = out.margin_budget_ns + target;
    let red = RGBColor(0xc0, 0x00, 0x00);
    let grey = RGBColor(0x55, 0x55, 0x55);
    let phase_marks = || {
        vec![
            Mark {
                at_ns: target,
                label: "target".into(),
                color: grey,
            },
            Mark {
                at_ns: deadline,
                label: "late beyond (SYNC0 minus the frame's transit)".into(),
                color: red,
            },
        ]
    };
    let margin_marks = || {
        vec![Mark {
            at_ns: 0.0,
            label: "SYNC0 (late below 0)".into(),
            color: red,
        }]
    };
    let runs = crate::scenario::plural(u64::from(s.runs), "run", "runs");
    let block = c
        .results
        .iter()
        .flatten()
        .next()
        .map_or(1, |r| r.series_block);
    let plots: Vec<Plot<'_>> = vec![
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
                    &phase_marks(),
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
                    &phase_marks(),
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
    ];
    let mut plots = plots;
    let windows = c
        .results
        .iter()
        .flatten()
        .filter_map(|r| r.faults.as_ref())
        .map(|f| f.windows.len())
        .max()
        .unwrap_or(0);
    if windows > 0 {
        plots.insert(
            0,
            Plot {
                name: "faults",
                caption: "Each fault of the schedule in run 0: |0x092C| (the BRD's OR over every drive) from the fault's start to a second after its end, per method; a gap is a lost cycle; the red line is 100 ns, the lock band of every method that does not write the master's time into the reference. A master that brings a reset slave back shows the gap, the far values of the reset slave, and the way back under the line.".into(),
                draw: Box::new(move |p, svg| {
                    plot!(p, svg, (1100, 200 * windows as u32 + 40), |r| fault_windows(r, c, order))
                }),
            },
        );
    }
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

pub(crate) fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn report_html(out: &SummaryOut, order: &[String], plots: &[(&str, &str)]) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync compare: {}</title>\
<style>body{{font-family:sans-serif;margin:2em;max-width:1200px;color:#222}}table{{border-collapse:collapse;margin:1em 0}}\
td,th{{border:1px solid #ccc;padding:3px 8px;text-align:right}}td.l{{white-space:nowrap}}th{{background:#eee}}td.l,th.l{{text-align:left}}\
.verdict{{border:2px solid #2c7a2c;background:#f3faf3;padding:0.8em 1.2em;margin:1em 0}}.verdict h2{{margin-top:0}}\
.warn{{border-left:4px solid #c77700;background:#fff8ec;padding:0.4em 0.8em;margin:0.4em 0}}\
.interrupted{{border:2px solid #c00;background:#fff0f0;padding:0.5em 1em}}tr.letter td{{color:#888}}\
pre{{background:#f7f7f7;padding:0.6em;overflow-x:auto;font-size:12px}}\
figure{{margin:1.5em 0}}figcaption{{color:#444;max-width:1100px}}img{{max-width:100%;border:1px solid #ddd}}</style></head><body>",
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
    for (name, caption) in plots {
        let _ = write!(
            h,
            "<figure><img src=\"{name}.svg\" alt=\"{name}\"><figcaption>{}</figcaption></figure>",
            esc(caption)
        );
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
        "<h3>Per drive, with {}</h3><p>SYNC0 minus the instant the frame's last bit passed the drive, and the smallest SYNC0 shift each drive needs. Late frames: frames after the drive's SYNC0. SYNC0 missed: pulses with no new outputs since the one before (the ground truth of what a drive counts: a late frame right after a late one is not one more, its outputs are the next pulse's as far as the drive can tell). Drive's count: its SM-event-missed counter 0x1C32:0B over the same cycles (- for a drive without CoE DC mode).</p><table><tr><th>position</th><th>margin min (us)</th><th>margin p0.1 (us)</th><th>margin mean (us)</th><th>late frames</th><th>SYNC0 missed</th><th>drive's count</th><th>smallest safe shift (%)</th></tr>",
        esc(m)
    );
    for s in &mo.ground_truth.per_slave {
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{:.1}</td></tr>",
            s.position,
            us3(s.margin_min_ns),
            us3(s.margin_p001_ns),
            us3(s.margin_mean_ns),
            s.late_frames,
            s.sync0_missed,
            s.drive_sm_events_missed
                .map_or("-".to_string(), |d| d.to_string()),
            s.smallest_safe_shift_pct
        );
    }
    let _ = write!(h, "</table>");
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
}
