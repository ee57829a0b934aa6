//! Plots (SVG and PNG, drawn with plotters), each with a caption in words, and report.html
//! around them (the `html` module), which holds the SVGs inline so that the file alone shows
//! them.
//!
//! * `hist_<metric>`: one histogram per metric with every method overlaid on shared axes (all
//!   runs pooled; log scale of the share of cycles, so the tails show); the phase and the SYNC0
//!   margin carry the deadline;
//! * `series_<metric>`: run 0 over time as percentile bands (min..max, 1st..99th percentile,
//!   median) over at most [`crate::run::BAND_POINTS`] blocks, one panel per method on a shared
//!   axis: the files are as large at a billion cycles as at a thousand;
//! * `fig4_histograms`: the letter's Fig. 4 layout (M-rS and rS-IS of each method).
//!
//! What a reader is promised (`axis` holds the decisions and their tests, `draw` the layouts):
//! every axis covers all of its data (a magnitude's from 0), nothing is piled on an edge bin,
//! legends sit beside the plot, each method has a colour of its own that no marker has (the
//! markers are dashed black and red), and the type is at least 14.5 px at the figure's width.

mod axis;
mod draw;

pub(crate) use axis::COLORS;
pub(crate) use axis::{TICK, TITLE, cover, hatch, series_color, viridis, white_text_on};
pub(crate) use draw::{
    BAD_GREY, HATCH_GREY, Key, Metric, Swatch, band_panel, decade, draw_envelopes, draw_hist, err,
    font, legend, with_strip,
};

use crate::compare::Comparison;
use crate::html::{Figure, report_html};
use crate::output::write_atomic;
use crate::report::SummaryOut;
pub(crate) use axis::{LATE_RED, Mark, TARGET_BLACK};
use draw::{bands, fault_windows, fig4, overlaid};
use plotters::prelude::*;
use std::io;
use std::path::Path;
use std::sync::Once;

/// The colour of the method at `i` in the report's order, as red, green, blue: what a reader
/// (or a test looking at a rendering of report.html) finds it drawn in.
pub fn method_rgb(i: usize) -> [u8; 3] {
    let c = axis::series_color(i);
    [c.0, c.1, c.2]
}

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
    let mut figures = Vec::with_capacity(plots.len());
    for pl in &plots {
        // report.html holds the SVG itself: a link would show nothing when the file is
        // mailed, attached or opened away from its folder.
        figures.push(Figure {
            name: pl.name,
            caption: &pl.caption,
            svg: write_svg_png(dir, pl.name, &pl.draw)?,
        });
    }
    let html = report_html(out, order, &figures);
    write_atomic(&dir.join("report.html"), html.as_bytes())
}

/// Writes plot `name` into `dir` as SVG and PNG, each drawn (`draw(path, svg)`) to a temporary
/// file and renamed over the old one, so that a reader, or a run stopped mid-write, never
/// meets half a plot; returns the SVG's text, which the reports hold inline. Every report's
/// plots are written here (compare's, the TSN run's, the sweep's).
pub(crate) fn write_svg_png(
    dir: &Path,
    name: &str,
    draw: &dyn Fn(&Path, bool) -> io::Result<()>,
) -> io::Result<String> {
    for (ext, svg) in [("svg", true), ("png", false)] {
        let fin = dir.join(format!("{name}.{ext}"));
        let tmp = dir.join(format!("{name}.tmp-ecsync.{ext}"));
        draw(&tmp, svg)?;
        std::fs::rename(&tmp, &fin)?;
    }
    std::fs::read_to_string(dir.join(format!("{name}.svg")))
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

    /// The target (dashed black) and the late line (dashed red).
    fn marks(self) -> Vec<Mark> {
        vec![
            Mark {
                at_ns: self.target_ns,
                label: "target".into(),
                color: TARGET_BLACK,
            },
            Mark {
                at_ns: self.deadline_ns,
                label: "late line".into(),
                color: LATE_RED,
            },
        ]
    }
}

/// SYNC0 (dashed red) on the margin's axis.
fn margin_marks() -> Vec<Mark> {
    vec![Mark {
        at_ns: 0.0,
        label: "SYNC0 (late below)".into(),
        color: LATE_RED,
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
            caption: "Each fault of the schedule in run 0: |0x092C| (the BRD's OR over every drive) from the fault's start to a second after its end, one line per method in its colour (legend on the right); a gap is a lost cycle, a light dot a cycle whose reference time the master held over; the dashed red line is 100 ns, the lock band of every method that does not write the master's time into the reference. A master that brings a reset slave back shows the gap, the far values of the reset slave, and the way back under the line.".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 220 * windows as u32 + 40), |r| fault_windows(r, c, order))
            }),
        }
    })
}

/// What every histogram's caption says about its axes and colours.
const HIST_NOTE: &str = "Each method is an outline in its own colour (legend on the right); the x axis runs over every cycle's value, the y axis down to a tenth of one cycle's share (an empty bin lies on the floor).";

/// A histogram of every method: `pick`'s metric, drawn by [`overlaid`].
fn hist<'a>(
    c: &'a Comparison,
    order: &'a [String],
    name: &'static str,
    caption: String,
    pick: fn(&crate::run::RunResult) -> &crate::stats::Stats,
    metric: Metric,
) -> Plot<'a> {
    Plot {
        name,
        caption,
        draw: Box::new(move |p, svg| {
            plot!(p, svg, (1100, 540), |r| overlaid(
                r, c, order, pick, &metric
            ))
        }),
    }
}

/// Every method's distribution of each metric on shared axes: the true phase, the SYNC0
/// margin, the slave spread, M-rS and rS-IS.
fn histograms<'a>(c: &'a Comparison, order: &'a [String], lines: PhaseLines) -> Vec<Plot<'a>> {
    let s = &c.scenario;
    let runs = crate::scenario::plural(u64::from(s.runs), "run", "runs");
    let (target, deadline, shift) = (lines.target_ns, lines.deadline_ns, lines.shift_ns);
    let (us, ns) = ((1000.0, "us"), (1.0, "ns"));
    let metric = |title, (unit_div, unit), magnitude, marks| Metric {
        title,
        unit_div,
        unit,
        magnitude,
        marks,
    };
    vec![
        hist(
            c,
            order,
            "hist_phase",
            format!(
                "When each frame reached the reference, after the DC grid point (the frames of {runs} pooled; log scale of the share of cycles). The dashed black line is the target every method aims at ({:.1} us); a frame to the right of the dashed red line ({:.1} us: SYNC0 at {:.1} us minus the frame's transit to the worst slave) was late. The spread is the host's scheduling jitter, which no master-shift method can remove from the actual send. {HIST_NOTE}",
                target / 1000.0,
                deadline / 1000.0,
                shift / 1000.0
            ),
            |x| &x.phase,
            metric(
                "true phase: the frame's arrival at the reference after the DC grid point",
                us,
                false,
                lines.marks(),
            ),
        ),
        hist(
            c,
            order,
            "hist_margin",
            format!(
                "SYNC0 minus the instant the frame's last bit passed the worst slave, per cycle: how much earlier than needed the outputs arrived. Below 0 (the dashed red line) a drive met its SYNC0 without this cycle's outputs. SYNC0 is at {:.1} % of the cycle. {HIST_NOTE}",
                s.sync0_shift_pct
            ),
            |x| &x.margin,
            metric("SYNC0 margin at the worst slave", us, false, margin_marks()),
        ),
        hist(
            c,
            order,
            "hist_spread",
            format!(
                "The largest difference between a drive's system time and the reference's at the same instant (every 8th cycle): how well the drives agree. Bus shift methods move the reference, and the others follow it. A magnitude: its axis starts at 0. {HIST_NOTE}"
            ),
            |x| &x.slave_diff,
            metric(
                "slave spread: largest |drive - reference| system time",
                ns,
                true,
                Vec::new(),
            ),
        ),
        hist(
            c,
            order,
            "hist_m_rs",
            format!(
                "The letter's M-rS error: its eq. (10) phi for master-shift methods (the reference's time at the frame's arrival against the master's send timestamp, less the set point), t_ra - t_ms for bus shift. It is what the master sees; the true phase above is what happened. {HIST_NOTE}"
            ),
            |x| &x.m_rs,
            metric(
                "M-rS error (the letter's measurement)",
                us,
                false,
                Vec::new(),
            ),
        ),
        hist(
            c,
            order,
            "hist_rs_is",
            format!(
                "The letter's rS-IS error: the magnitude of a BRD of 0x092C, the OR of every drive's filtered difference to the times it received (its axis starts at 0). Bus shift's writes to the reference show here. {HIST_NOTE}"
            ),
            |x| &x.rs_is,
            metric(
                "rS-IS error |0x092C| (the letter's measurement)",
                ns,
                true,
                Vec::new(),
            ),
        ),
    ]
}

/// Run 0's `which` series of every method, drawn by [`bands`].
fn band_plot<'a>(
    c: &'a Comparison,
    order: &'a [String],
    name: &'static str,
    caption: String,
    which: usize,
    metric: Metric,
) -> Plot<'a> {
    let n = order.len().max(1) as u32;
    Plot {
        name,
        caption,
        draw: Box::new(move |p, svg| {
            plot!(p, svg, (1100, 170 * n + 40), |r| bands(
                r, c, order, which, &metric
            ))
        }),
    }
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
        band_plot(
            c,
            order,
            "series_true_phase",
            format!(
                "Run 0's true phase over time, one panel per method in its colour: per block of {block} cycles the extremes (light), the 1st to 99th percentile (darker) and the median (a dark line of the same hue), with the target (dashed black) and the late line (dashed red). The panels share one y axis, which runs over every block's extremes (each panel its own when the methods' ranges differ more than tenfold, as its title says). The first seconds show how a method pulls in after its warm-up."
            ),
            2,
            Metric {
                title: "true phase over time (run 0; s since recording started)",
                unit_div: 1000.0,
                unit: "us",
                magnitude: false,
                marks: lines.marks(),
            },
        ),
        band_plot(
            c,
            order,
            "series_m_rs",
            format!("Run 0's M-rS error over time, bands as above (blocks of {block} cycles; one y axis over every block's extremes, each panel its own when the ranges differ more than tenfold)."),
            0,
            Metric {
                title: "M-rS error over time (run 0; s since recording started)",
                unit_div: 1000.0,
                unit: "us",
                magnitude: false,
                marks: Vec::new(),
            },
        ),
        band_plot(
            c,
            order,
            "series_rs_is",
            format!("Run 0's rS-IS error over time, bands as above (blocks of {block} cycles). A magnitude: the y axis runs from 0 over every block's extremes, one axis for all panels unless the methods' ranges differ more than tenfold; then each panel has its own (its title says so) and the tick values tell the scale (the distributions side by side: the rS-IS histogram, on a log scale)."),
            1,
            Metric {
                title: "rS-IS error |0x092C| over time (run 0; s since recording started)",
                unit_div: 1.0,
                unit: "ns",
                magnitude: true,
                marks: Vec::new(),
            },
        ),
        Plot {
            name: "fig4_histograms",
            caption: "The letter's Fig. 4 layout: each method's M-rS and rS-IS distributions in its colour on their own axes (linear scale; each axis over all of its values, rS-IS from 0).".into(),
            draw: Box::new(move |p, svg| {
                plot!(p, svg, (1100, 240 * n), |r| fig4(r, c, order))
            }),
        },
    ]
}
