//! tradeoff.svg: every point of the sweep per method, its smallest safe SYNC0 shift against
//! its phase error, so that a reader sees what a smaller shift costs in jitter and which
//! points are out of the running (hollow), and finds the answer's point ringed and named.

use super::{Hot, HotShape, Row, Sweep};
use crate::plots::{
    Key, LATE_RED, Swatch, TARGET_BLACK, TICK, TITLE, cover, decade, err, font, legend,
    series_color, with_strip,
};
use crate::report::SHIFT_TIE_PCT;
use plotters::coord::Shift;
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::io;
use std::ops::Range;

/// The grey of the legend's "not good" entry (the plot draws such a point hollow in its
/// method's colour).
const NOT_GOOD_GREY: RGBColor = RGBColor(0x80, 0x80, 0x80);

/// The points drawn: both figures finite.
fn drawn(s: &Sweep) -> impl Iterator<Item = &Row> {
    s.rows
        .iter()
        .filter(|r| r.safe_shift_pct.is_finite() && r.phase_error_p999_ns.is_finite())
}

/// The y axis (phase error p99.9, ns): linear over every point with 5 % to spare (not from 0:
/// the differences between points are what the plot is for, and the tick values tell the
/// scale), or logarithmic when the largest is more than a hundred times the smallest (an
/// unstable method's microseconds would flatten every other point onto the floor).
enum YAxis {
    Linear(f64, f64),
    Log(f64, f64),
}

fn y_axis(s: &Sweep) -> YAxis {
    let ys = drawn(s).map(|r| r.phase_error_p999_ns);
    let (lo, hi) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), y| {
        (a.min(y), b.max(y))
    });
    let lo_pos = drawn(s)
        .map(|r| r.phase_error_p999_ns)
        .filter(|y| *y > 0.0)
        .fold(f64::INFINITY, f64::min);
    if lo_pos.is_finite() && hi > 100.0 * lo_pos {
        YAxis::Log(lo_pos / 1.5, hi * 1.5)
    } else {
        let (a, b) = cover(lo, hi, false);
        YAxis::Linear(a.max(0.0), b)
    }
}

/// The x axis (smallest safe shift, %): every point and the answer's tie band, with 5 % of
/// the span to spare (at least a tenth of a percent), not below 0.
fn x_axis(s: &Sweep) -> (f64, f64) {
    let xs = drawn(s)
        .map(|r| r.safe_shift_pct)
        .chain(tie_band(s).map(|(_, b)| b));
    let (lo, hi) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
        (a.min(x), b.max(x))
    });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(0.1);
    ((lo - pad).max(0.0), hi + pad)
}

/// The shifts as good as the answer's: from its smallest safe shift to [`SHIFT_TIE_PCT`]
/// more, the comparison's tie step, which the answer counts as no difference (a point in
/// the band is "as good" in its words).
fn tie_band(s: &Sweep) -> Option<(f64, f64)> {
    let r = drawn(s).find(|r| s.is_best(r))?;
    Some((r.safe_shift_pct, r.safe_shift_pct + SHIFT_TIE_PCT))
}

/// The tie band's colour: the verdict box's green, light enough to lie under the markers.
const TIE_GREEN: RGBColor = RGBColor(0xdd, 0xf0, 0xdd);

/// Draws the trade-off; returns each marker's region.
pub(super) fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    s: &Sweep,
) -> io::Result<Vec<Hot>> {
    root.fill(&WHITE).map_err(err)?;
    let body = root
        .titled(
            "Every point: smallest safe SYNC0 shift against phase error p99.9",
            font(TITLE),
        )
        .map_err(err)?;
    let (plot, strip) = with_strip(&body);
    let (x_lo, x_hi) = x_axis(s);
    let hots = match y_axis(s) {
        YAxis::Linear(a, b) => {
            scatter(&plot, s, (x_lo..x_hi, a..b), ("ns", &|v| format!("{v:.0}")))?
        }
        YAxis::Log(a, b) => scatter(
            &plot,
            s,
            (x_lo..x_hi, (a..b).log_scale()),
            ("ns (log)", &decade),
        )?,
    };
    legend(&strip, &keys(s), 10)?;
    root.present().map_err(err)?;
    Ok(hots)
}

/// The legend: each method's colour, then what hollow and ringed mean.
fn keys(s: &Sweep) -> Vec<Key> {
    let mut keys: Vec<Key> = s
        .methods
        .iter()
        .filter(|m| s.rows.iter().any(|r| r.method == **m))
        .map(|m| Key {
            label: m.clone(),
            color: series_color(s.color_index(m)),
            swatch: Swatch::Dot { filled: true },
        })
        .collect();
    keys.push(Key {
        label: "hollow: late or lost\nframes, not ranked or\noff its target".into(),
        color: NOT_GOOD_GREY,
        swatch: Swatch::Dot { filled: false },
    });
    keys.push(Key {
        label: "ringed: the answer".into(),
        color: TARGET_BLACK,
        swatch: Swatch::Ring,
    });
    if tie_band(s).is_some() {
        keys.push(Key {
            label: format!(
                "as good as the answer\n(within {SHIFT_TIE_PCT} % of\nthe cycle, the tie step)"
            ),
            color: TIE_GREEN,
            swatch: Swatch::Cell { hatched: false },
        });
    }
    let hidden = s.rows.len() - drawn(s).count();
    if hidden > 0 {
        keys.push(Key {
            label: format!("{hidden} without a figure,\nnot drawn"),
            color: LATE_RED,
            swatch: Swatch::Dot { filled: false },
        });
    }
    keys
}

/// The markers on a chart of x `xr` (%) and y `yr` (ns, labelled by `y_label`): every point not good first (hollow,
/// under the others), then the good ones, then the answer's ring and label.
fn scatter<DB, Y>(
    plot: &DrawingArea<DB, Shift>,
    s: &Sweep,
    (xr, yr): (Range<f64>, Y),
    (y_unit, y_label): (&str, &dyn Fn(&f64) -> String),
) -> io::Result<Vec<Hot>>
where
    DB: DrawingBackend,
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let mut chart = ChartBuilder::on(plot)
        .margin(10)
        .margin_right(24)
        .x_label_area_size(56)
        .y_label_area_size(96)
        .build_cartesian_2d(xr, yr)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("smallest safe SYNC0 shift, % of the cycle (smaller is better)")
        .y_desc(format!("phase error p99.9, {y_unit}"))
        .y_label_formatter(y_label)
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .light_line_style(RGBColor(0xee, 0xee, 0xee))
        .draw()
        .map_err(err)?;
    if let Some((a, b)) = tie_band(s) {
        let (y0, y1) = {
            let r = chart.y_range();
            (r.start, r.end)
        };
        chart
            .draw_series(std::iter::once(Rectangle::new(
                [(a, y0), (b, y1)],
                TIE_GREEN.mix(0.75).filled(),
            )))
            .map_err(err)?;
    }
    let mut hots = Vec::new();
    for good in [false, true] {
        for r in drawn(s).filter(|r| r.good == good) {
            let c = series_color(s.color_index(&r.method));
            let at = (r.safe_shift_pct, r.phase_error_p999_ns);
            // A hollow ring is wider than a dot: where a bad point has the same figures as a
            // good one (the same noise at another parameter), it shows around it.
            let (radius, style) = if good {
                (6, c.filled())
            } else {
                (9, c.mix(0.6).stroke_width(2))
            };
            chart
                .draw_series(std::iter::once(Circle::new(at, radius, style)))
                .map_err(err)?;
            let (x, y) = chart.backend_coord(&at);
            hots.push(Hot {
                shape: HotShape::Circle(x, y, radius + 2),
                point: r.point,
                method: r.method.clone(),
                good: r.good,
                best: s.is_best(r),
                title: s.row_title(r),
            });
        }
    }
    if let Some(r) = drawn(s).find(|r| s.is_best(r)) {
        let at = (r.safe_shift_pct, r.phase_error_p999_ns);
        let label = format!("best: {} at point {}", r.method, r.point);
        let px = chart.backend_coord(&at);
        let (x0, y0) = plot.get_base_pixel();
        let (w, h) = plot.dim_in_pixel();
        // The label beside the ring, on the side with room: left of it in the plot's right
        // half, below it near the top.
        let style = font(TICK);
        let (tw, th) = plot.estimate_text_size(&label, &style).map_err(err)?;
        let (tw, th) = (tw as i32, th as i32);
        let right = px.0 - x0 < w as i32 / 2;
        let below = px.1 - y0 < h as i32 / 4;
        let dx = if right { 16 } else { -16 - tw };
        let dy = if below { 16 } else { -16 - th };
        let label_el = EmptyElement::at(at)
            + Circle::new((0, 0), 12, TARGET_BLACK.stroke_width(3))
            + Rectangle::new(
                [(dx - 4, dy - 2), (dx + tw + 4, dy + th + 2)],
                WHITE.mix(0.85).filled(),
            )
            + Text::new(label, (dx, dy), style.pos(Pos::new(HPos::Left, VPos::Top)));
        chart.draw_series(std::iter::once(label_el)).map_err(err)?;
    }
    Ok(hots)
}

/// What the trade-off shows, in words (sweep.html's caption).
pub(super) fn caption(s: &Sweep) -> String {
    let hidden = s.rows.len() - drawn(s).count();
    let hidden = if hidden > 0 {
        format!(
            " {} without a safe shift or a phase error (NULL in the database) {} not drawn.",
            crate::scenario::plural(hidden as u64, "point", "points"),
            if hidden == 1 { "is" } else { "are" }
        )
    } else {
        String::new()
    };
    // The axis as drawn: linear over the points' own range (not from 0), or a log scale.
    let y = match y_axis(s) {
        YAxis::Linear(lo, hi) => format!(
            "linear from {lo:.0} to {hi:.0} ns, the points' range, not from 0: read the differences on the tick values"
        ),
        YAxis::Log(..) => {
            "on a log scale, as the largest is more than a hundred times the smallest".to_string()
        }
    };
    format!(
        "Every point of the sweep, one marker per method in its colour (legend on the right): across, its smallest safe SYNC0 shift (the earliest SYNC0, % of the cycle, that no frame of the run came after); up, its phase error p99.9 ({y}). Down and to the left is better. Filled: a good point (no late or lost frame, ranked by its comparison, its mean phase on the target); hollow: not. Ringed and labelled: the answer, the good point with the smallest safe shift, then the smallest phase error; the green band right of it holds the shifts within {SHIFT_TIE_PCT} % of the cycle of the answer's, which the answer counts as as good (the comparison's tie step). Hover a marker for its point's values.{hidden}"
    )
}
