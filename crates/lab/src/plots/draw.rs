//! The drawing: each figure's layout on a plotters area. Every legend sits in a strip of its
//! own beside the plot (it never covers data), every axis covers all of its data (`axis`), and
//! every text is at least [`TICK`] (14.5 px at the figure's own width).

use super::axis::{
    LATE_RED, LEGEND, Mark, PANEL_TITLE, TICK, TITLE, cover, cover_dists, dashed_series, hatch,
    rebin, series_color, with_marks,
};
use crate::compare::Comparison;
use crate::run::{Band, RunResult};
use crate::stats::{Dist, Stats};
use plotters::coord::Shift;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::io;

pub(crate) fn err<E: std::fmt::Display>(e: E) -> io::Error {
    io::Error::other(e.to_string())
}

/// The width of the legend strip right of a plot, px: room for "dcm-master-shift+txtime" at
/// [`LEGEND`].
const STRIP: u32 = 250;

/// A legend entry: its label (a second line after `\n`), its colour, what it shows.
pub(crate) struct Key {
    pub label: String,
    pub color: RGBColor,
    pub swatch: Swatch,
}

/// How a legend entry shows what it names: the same shape the plot draws it with, so that a
/// reader matches them by eye.
#[derive(Debug, Clone, Copy)]
pub(crate) enum Swatch {
    /// A line (a series or a marker), dashed or solid.
    Line { dashed: bool },
    /// A dot, filled or hollow (an outline): the sweep's points.
    Dot { filled: bool },
    /// A ring: the sweep's best point.
    Ring,
    /// A heat map's cell, plain or hatched (a point that is not good).
    Cell { hatched: bool },
    /// A cell's outline: the heat map's best point.
    Frame,
}

/// The grey a heat map draws a cell that is not good in, and its hatching.
pub(crate) const BAD_GREY: RGBColor = RGBColor(0xd9, 0xd9, 0xd9);
pub(crate) const HATCH_GREY: RGBColor = RGBColor(0x80, 0x80, 0x80);

pub(crate) fn font(size: u32) -> TextStyle<'static> {
    TextStyle::from(("sans-serif", size).into_font())
}

/// A log axis's tick (a power of ten) as a plain number from 0.001 to 1000 (100, 1, 0.001),
/// beyond as a power (1e6): short enough for the label area.
pub(crate) fn decade(v: &f64) -> String {
    let exp = v.log10().round();
    if exp.abs() > 3.0 {
        format!("1e{exp:.0}")
    } else {
        let places = (-exp).max(0.0) as usize;
        format!("{v:.places$}")
    }
}

/// A dashed line through `pts` in data coordinates, or a plain one.
fn line<DB, C>(pts: Vec<C>, color: RGBColor, width: u32, dashed: bool) -> DynElement<'static, DB, C>
where
    DB: DrawingBackend,
    C: Clone + 'static,
{
    let style = color.stroke_width(width);
    if dashed {
        DashedPathElement::new(pts, 8, 5, style).into_dyn()
    } else {
        PathElement::new(pts, style).into_dyn()
    }
}

/// Draws `keys` one under the other in `area` from `top` px down.
pub(crate) fn legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    keys: &[Key],
    top: i32,
) -> io::Result<()> {
    let row = (f64::from(LEGEND) * 1.35) as i32;
    let mut y = top;
    for key in keys {
        for (n, text) in key.label.lines().enumerate() {
            let mid = y + row / 2;
            if n == 0 {
                swatch(area, key, mid)?;
            }
            let style = font(LEGEND).pos(Pos::new(HPos::Left, VPos::Center));
            area.draw(&Text::new(text.to_string(), (48, mid), style))
                .map_err(err)?;
            y += row;
        }
    }
    Ok(())
}

/// Draws `key`'s swatch in the legend's first 40 px, centred on row `mid`.
fn swatch<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    key: &Key,
    mid: i32,
) -> io::Result<()> {
    let c = key.color;
    match key.swatch {
        Swatch::Line { dashed } => area.draw(&line(vec![(6, mid), (40, mid)], c, 3, dashed)),
        Swatch::Dot { filled } => {
            let style = if filled {
                c.filled()
            } else {
                c.stroke_width(2)
            };
            // As the sweep's trade-off draws them: a hollow ring wider than a dot.
            area.draw(&Circle::new((23, mid), if filled { 6 } else { 8 }, style))
        }
        Swatch::Ring => area.draw(&Circle::new((23, mid), 10, c.stroke_width(3))),
        Swatch::Cell { hatched } => {
            let (a, b) = ((10, mid - 9), (36, mid + 9));
            area.draw(&Rectangle::new([a, b], c.filled()))
                .map_err(err)?;
            if hatched {
                for (p, q) in hatch(a, b, 6) {
                    area.draw(&PathElement::new(vec![p, q], HATCH_GREY.stroke_width(1)))
                        .map_err(err)?;
                }
            }
            area.draw(&Rectangle::new([a, b], HATCH_GREY.stroke_width(1)))
        }
        Swatch::Frame => area.draw(&Rectangle::new(
            [(10, mid - 9), (36, mid + 9)],
            c.stroke_width(3),
        )),
    }
    .map_err(err)
}

/// Splits `area` into the plot (left) and the legend strip (right).
pub(crate) fn with_strip<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
) -> (DrawingArea<DB, Shift>, DrawingArea<DB, Shift>) {
    let w = area.dim_in_pixel().0;
    area.split_horizontally(w.saturating_sub(STRIP))
}

/// The comparison's entries in the report's order: position (for the colour), name, index
/// into the results.
fn entries<'a>(c: &Comparison, order: &'a [String]) -> Vec<(usize, &'a String, usize)> {
    let entries = c.scenario.entries();
    order
        .iter()
        .enumerate()
        .filter_map(|(i, name)| {
            let m = entries.iter().position(|e| e.name() == *name)?;
            Some((i, name, m))
        })
        .collect()
}

pub(crate) fn pooled(c: &Comparison, m: usize, pick: fn(&RunResult) -> &Stats) -> Stats {
    let mut s = Stats::new();
    for r in &c.results[m] {
        s.merge(pick(r));
    }
    s
}

/// What a histogram or a series shows: a metric of each run, its unit, whether it is a
/// magnitude (its axis starts at 0), and its markers.
pub(crate) struct Metric {
    pub title: &'static str,
    pub unit_div: f64,
    pub unit: &'static str,
    pub magnitude: bool,
    pub marks: Vec<Mark>,
}

/// The legend entry of a marker: drawn where it is, or named with where it is when it is off
/// the axis (far beyond the data).
fn mark_key(mk: &Mark, lo: f64, hi: f64, unit_div: f64, unit: &str) -> Key {
    let label = if mk.at_ns < lo || mk.at_ns > hi {
        let side = if mk.at_ns > hi { "right" } else { "left" };
        format!(
            "{}\n(at {:.1} {unit}, off the\naxis to the {side})",
            mk.label,
            mk.at_ns / unit_div
        )
    } else {
        mk.label.clone()
    };
    Key {
        label,
        color: mk.color,
        swatch: Swatch::Line { dashed: true },
    }
}

/// Every method's distribution of one metric on shared axes, as outlines on a log scale.
pub(crate) fn overlaid<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
    pick: fn(&RunResult) -> &Stats,
    m: &Metric,
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let body = root.titled(m.title, font(TITLE)).map_err(err)?;
    let (plot, strip) = with_strip(&body);
    let dists: Vec<(usize, &String, Stats)> = entries(c, order)
        .into_iter()
        .map(|(i, name, k)| (i, name, pooled(c, k, pick)))
        .collect();
    let (lo, hi) = cover_dists(dists.iter().map(|d| &d.2.dist), m.magnitude);
    let (lo, hi) = with_marks(lo, hi, &m.marks);
    // The y axis reaches a decade below one cycle's share, so a single far cycle shows
    // however many cycles were pooled; an empty bin is drawn on the floor.
    let most = dists.iter().map(|d| d.2.count()).max().unwrap_or(1).max(1);
    let floor = 10f64.powf((100.0 / most as f64).log10().floor() - 1.0);
    const BINS: usize = 160;
    let bw = (hi - lo) / BINS as f64;
    let mut chart = ChartBuilder::on(&plot)
        .margin(10)
        .margin_right(24)
        .x_label_area_size(48)
        .y_label_area_size(90)
        .build_cartesian_2d(lo / m.unit_div..hi / m.unit_div, (floor..100.0).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(m.unit)
        .y_desc("% of cycles (log)")
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .y_label_formatter(&decade)
        .light_line_style(RGBColor(0xee, 0xee, 0xee))
        .draw()
        .map_err(err)?;
    let mut keys = Vec::new();
    for (i, name, s) in &dists {
        let total = s.count().max(1) as f64;
        let bars = rebin(&s.dist, lo, hi, BINS);
        let (col, dashed) = (series_color(*i), dashed_series(*i));
        let mut pts = Vec::with_capacity(2 * BINS + 2);
        for (k, &n) in bars.iter().enumerate() {
            let y = (n as f64 / total * 100.0).max(floor);
            let x0 = (lo + k as f64 * bw) / m.unit_div;
            let x1 = (lo + (k + 1) as f64 * bw) / m.unit_div;
            pts.push((x0, y));
            pts.push((x1, y));
        }
        chart
            .draw_series(std::iter::once(line(pts, col, 2, dashed)))
            .map_err(err)?;
        keys.push(Key {
            label: (*name).clone(),
            color: col,
            swatch: Swatch::Line { dashed },
        });
    }
    for mk in &m.marks {
        if mk.at_ns >= lo && mk.at_ns <= hi {
            let x = mk.at_ns / m.unit_div;
            chart
                .draw_series(std::iter::once(line(
                    vec![(x, floor), (x, 100.0)],
                    mk.color,
                    2,
                    true,
                )))
                .map_err(err)?;
        }
        keys.push(mark_key(mk, lo, hi, m.unit_div, m.unit));
    }
    legend(&strip, &keys, 10)?;
    root.present().map_err(err)
}

/// The y axis of run 0's bands of every method: from their smallest minimum to their largest
/// maximum (nothing clipped), from 0 for a magnitude.
fn bands_axis(
    series: &[(usize, &String, &RunResult)],
    which: usize,
    magnitude: bool,
) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for b in series.iter().flat_map(|s| &s.2.series[which]) {
        let (a, z) = (f64::from(b.min), f64::from(b.max));
        if a.is_finite() && z.is_finite() {
            lo = lo.min(a);
            hi = hi.max(z);
        }
    }
    cover(lo, hi, magnitude)
}

/// Run 0 of every method over time as percentile bands, one panel each, on a shared y axis
/// (each its own when the methods' ranges differ more than tenfold).
pub(crate) fn bands<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
    which: usize,
    m: &Metric,
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let series: Vec<(usize, &String, &RunResult)> = entries(c, order)
        .into_iter()
        .filter_map(|(i, name, k)| Some((i, name, c.results[k].first()?)))
        .collect();
    let (lo, hi) = bands_axis(&series, which, m.magnitude);
    let (lo, hi) = with_marks(lo, hi, &m.marks);
    // One axis for all panels, unless the methods' ranges differ more than tenfold: a shared
    // axis would then draw every method but the widest as a flat line at its edge, so each
    // panel gets its own (and says so in its title).
    let own: Vec<(f64, f64)> = series
        .iter()
        .map(|s| {
            let (a, z) = bands_axis(std::slice::from_ref(s), which, m.magnitude);
            with_marks(a, z, &m.marks)
        })
        .collect();
    let per_panel = ranges_differ_tenfold(&own);
    let cycle_s = f64::from(c.scenario.cycle_ns) * 1e-9;
    let (head, body) = root.split_vertically(40);
    head.titled(m.title, font(TITLE)).map_err(err)?;
    let (panels, strip) = if m.marks.is_empty() {
        (body, None)
    } else {
        let (p, s) = with_strip(&body);
        (p, Some(s))
    };
    if let Some(strip) = strip {
        let keys: Vec<Key> = m
            .marks
            .iter()
            .map(|mk| mark_key(mk, lo, hi, m.unit_div, m.unit))
            .collect();
        legend(&strip, &keys, 30)?;
    }
    let rows = panels.split_evenly((series.len().max(1), 1));
    for (k, (i, name, r)) in series.iter().enumerate() {
        let (title, axis) = if per_panel {
            (format!("{name} (its own y axis)"), own[k])
        } else {
            (name.to_string(), (lo, hi))
        };
        band_panel(
            &rows[k],
            &title,
            &r.series[which],
            r.series_block,
            cycle_s,
            *i,
            axis,
            m,
        )?;
    }
    root.present().map_err(err)
}

/// Whether the widest of the `ranges` spans more than ten times the narrowest (then panels on
/// one axis would draw the narrow ones flat).
pub(crate) fn ranges_differ_tenfold(ranges: &[(f64, f64)]) -> bool {
    let spans = ranges.iter().map(|(a, z)| z - a);
    let widest = spans.clone().fold(0.0, f64::max);
    let narrowest = spans.fold(f64::INFINITY, f64::min);
    narrowest > 0.0 && widest > 10.0 * narrowest
}

/// One method's panel of [`bands`].
#[allow(clippy::too_many_arguments)]
pub(crate) fn band_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    name: &str,
    s: &[Band],
    block: u64,
    cycle_s: f64,
    i: usize,
    (lo, hi): (f64, f64),
    m: &Metric,
) -> io::Result<()> {
    let col = series_color(i);
    let block = block.max(1) as f64;
    let t_end = s.last().map_or(1.0, |b| b.cycle as f64 + block) * cycle_s;
    let mut chart = ChartBuilder::on(area)
        .caption(name, font(PANEL_TITLE))
        .margin(4)
        .margin_right(24)
        .x_label_area_size(30)
        .y_label_area_size(90)
        .build_cartesian_2d(0.0..t_end.max(cycle_s), lo / m.unit_div..hi / m.unit_div)
        .map_err(err)?;
    chart
        .configure_mesh()
        .y_desc(m.unit)
        .x_labels(8)
        .y_labels(5)
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .light_line_style(RGBColor(0xf0, 0xf0, 0xf0))
        .draw()
        .map_err(err)?;
    let y = |v: f32| f64::from(v) / m.unit_div;
    let t = |b: &Band| b.cycle as f64 * cycle_s;
    let dt = block * cycle_s;
    // min..max, light; 1st..99th, darker; the median, a line. Each band is one polygon
    // (steps along its upper edge, back along its lower one): a few kilobytes whatever the
    // cycles.
    let band = |lo_of: fn(&Band) -> f32, hi_of: fn(&Band) -> f32| {
        let mut pts = Vec::with_capacity(4 * s.len());
        for b in s {
            pts.push((t(b), y(hi_of(b))));
            pts.push((t(b) + dt, y(hi_of(b))));
        }
        for b in s.iter().rev() {
            pts.push((t(b) + dt, y(lo_of(b))));
            pts.push((t(b), y(lo_of(b))));
        }
        pts
    };
    chart
        .draw_series(std::iter::once(Polygon::new(
            band(|b| b.min, |b| b.max),
            col.mix(0.25).filled(),
        )))
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(Polygon::new(
            band(|b| b.p01, |b| b.p99),
            col.mix(0.6).filled(),
        )))
        .map_err(err)?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            s.iter()
                .map(|b| (t(b) + dt / 2.0, y(b.p50)))
                .collect::<Vec<_>>(),
            // The method's colour darkened, so the median shows on its own band.
            RGBColor(col.0 / 2, col.1 / 2, col.2 / 2).stroke_width(2),
        )))
        .map_err(err)?;
    for mk in &m.marks {
        if mk.at_ns >= lo && mk.at_ns <= hi {
            let v = mk.at_ns / m.unit_div;
            chart
                .draw_series(std::iter::once(line(
                    vec![(0.0, v), (t_end, v)],
                    mk.color,
                    2,
                    true,
                )))
                .map_err(err)?;
        }
    }
    Ok(())
}

/// The lock band of |0x092C| the fault windows draw, ns.
const LOCK_BAND_NS: f64 = 100.0;

/// Run 0's |0x092C| around each fault, every method on one panel per fault (log scale; a lost
/// cycle is a gap, a cycle whose reference time the master held is a light dot).
pub(crate) fn fault_windows<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let runs: Vec<(usize, &String, &crate::run::FaultsTruth)> = entries(c, order)
        .into_iter()
        .filter_map(|(i, name, k)| Some((i, name, c.results[k].first()?.faults.as_ref()?)))
        .collect();
    let n = runs.iter().map(|r| r.2.windows.len()).max().unwrap_or(0);
    let (head, body) = root.split_vertically(40);
    head.titled(
        "|0x092C| around each fault (run 0; ms since the fault started; log scale)",
        font(TITLE),
    )
    .map_err(err)?;
    if n == 0 {
        return root.present().map_err(err);
    }
    let (panels, strip) = with_strip(&body);
    let mut keys: Vec<Key> = runs
        .iter()
        .map(|(i, name, _)| Key {
            label: (*name).clone(),
            color: series_color(*i),
            swatch: Swatch::Line {
                dashed: dashed_series(*i),
            },
        })
        .collect();
    keys.push(Key {
        label: "lock band, 100 ns".into(),
        color: LATE_RED,
        swatch: Swatch::Line { dashed: true },
    });
    legend(&strip, &keys, 30)?;
    let rows = panels.split_evenly((n, 1));
    for (k, row) in rows.iter().enumerate() {
        fault_panel(row, &runs, k)?;
    }
    root.present().map_err(err)
}

/// Fault `k`'s panel of [`fault_windows`].
fn fault_panel<DB: DrawingBackend>(
    row: &DrawingArea<DB, Shift>,
    runs: &[(usize, &String, &crate::run::FaultsTruth)],
    k: usize,
) -> io::Result<()> {
    let t_end = runs
        .iter()
        .filter_map(|r| r.2.windows.get(k)?.points.last().map(|p| f64::from(p.0)))
        .fold(1.0f64, f64::max);
    let kind = runs
        .iter()
        .find_map(|r| r.2.windows.get(k).map(|w| (w.fault, w.kind.as_str())))
        .unwrap_or((k, ""));
    let mut chart = ChartBuilder::on(row)
        .caption(format!("fault {}: {}", kind.0, kind.1), font(PANEL_TITLE))
        .margin(4)
        .margin_right(24)
        .x_label_area_size(30)
        .y_label_area_size(90)
        .build_cartesian_2d(0.0..t_end, (1.0f64..3e9f64).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .y_desc("ns")
        .y_label_formatter(&decade)
        .x_labels(10)
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .light_line_style(RGBColor(0xf0, 0xf0, 0xf0))
        .draw()
        .map_err(err)?;
    for (i, _, f) in runs {
        let Some(w) = f.windows.get(k) else { continue };
        let (col, dashed) = (series_color(*i), dashed_series(*i));
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
        for p in paths.into_iter().filter(|p| !p.is_empty()) {
            chart
                .draw_series(std::iter::once(line(p, col, 1, dashed)))
                .map_err(err)?;
        }
        let held = w.points.iter().filter(|p| p.2 && p.1.is_finite());
        chart
            .draw_series(held.map(|&(t, v, _)| {
                Circle::new(
                    (f64::from(t), f64::from(v).max(1.0)),
                    3,
                    col.mix(0.35).filled(),
                )
            }))
            .map_err(err)?;
    }
    chart
        .draw_series(std::iter::once(line(
            vec![(0.0, LOCK_BAND_NS), (t_end, LOCK_BAND_NS)],
            LATE_RED,
            1,
            true,
        )))
        .map_err(err)?;
    Ok(())
}

/// The letter's Fig. 4 layout: each method's M-rS and rS-IS on their own axes.
pub(crate) fn fig4<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    c: &Comparison,
    order: &[String],
) -> io::Result<()> {
    root.fill(&WHITE).map_err(err)?;
    let rows = root.split_evenly((order.len().max(1), 2));
    let kinds = c.scenario.entries();
    for (i, name, m) in entries(c, order) {
        let letter = crate::letter::letter_name(kinds[m].kind);
        let label = if letter == "-" {
            name.clone()
        } else {
            format!("{letter} ({name})")
        };
        let col = series_color(i);
        hist_on(
            &rows[2 * i],
            &pooled(c, m, |r| &r.m_rs).dist,
            &format!("{label}: M-rS error"),
            (1000.0, "us", false),
            col,
        )?;
        hist_on(
            &rows[2 * i + 1],
            &pooled(c, m, |r| &r.rs_is).dist,
            &format!("{label}: rS-IS error |0x092C|"),
            (1.0, "ns", true),
            col,
        )?;
    }
    root.present().map_err(err)
}

/// One distribution as bars (the TSN run's plots): a signed quantity's axis.
pub(crate) fn draw_hist<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    h: &Dist,
    title: &str,
    unit_div: f64,
    unit: &str,
    color: RGBColor,
) -> io::Result<()> {
    hist_on(area, h, title, (unit_div, unit, false), color)
}

/// One distribution as bars over its full support (`unit`: the divisor, its name, whether a
/// magnitude).
fn hist_on<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    h: &Dist,
    title: &str,
    (unit_div, unit, magnitude): (f64, &str, bool),
    color: RGBColor,
) -> io::Result<()> {
    const BINS: usize = 200;
    let (lo, hi) = cover_dists([h], magnitude);
    let bars = rebin(h, lo, hi, BINS);
    let width = (hi - lo) / BINS as f64;
    let total: u64 = h.total().max(1);
    let ymax = bars.iter().copied().max().unwrap_or(1) as f64 / total as f64 * 100.0;
    let mut chart = ChartBuilder::on(area)
        .caption(title, font(PANEL_TITLE))
        .margin(8)
        .margin_right(24)
        .x_label_area_size(44)
        .y_label_area_size(70)
        .build_cartesian_2d(lo / unit_div..hi / unit_div, 0.0..ymax.max(1e-9) * 1.1)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc(unit)
        .y_desc("% of samples")
        .x_labels(6)
        .y_labels(5)
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .light_line_style(WHITE)
        .draw()
        .map_err(err)?;
    chart
        .draw_series(bars.iter().enumerate().filter(|b| *b.1 > 0).map(|(k, &c)| {
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
    let (lo, hi) = cover(lo, hi, false);
    let t_end = s.last().map_or(1.0, |e| e.cycle as f64) * cycle_s;
    let mut chart = ChartBuilder::on(area)
        .caption(title, font(PANEL_TITLE))
        .margin(6)
        .margin_right(24)
        .x_label_area_size(40)
        .y_label_area_size(80)
        .build_cartesian_2d(0.0..t_end.max(cycle_s), lo / unit_div..hi / unit_div)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("s since the start of recording")
        .y_desc(unit)
        .y_labels(5)
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
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
