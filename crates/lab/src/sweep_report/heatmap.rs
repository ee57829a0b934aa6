//! `heatmap-<method>.svg`: one method's smallest safe SYNC0 shift over the two swept keys, a
//! cell per point, so that a reader sees where in the grid the method does well and how
//! sharply it falls off. Every method's map shares one colour scale (the colours compare
//! across files); a point that is not good is grey and hatched whatever its value, since its
//! shift is no shift a design could use.

use super::{Grid, Hot, HotShape, Row, Sweep};
use crate::plots::{
    BAD_GREY, HATCH_GREY, Key, Swatch, TARGET_BLACK, TICK, TITLE, err, font, hatch, legend,
    viridis, white_text_on, with_strip,
};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};
use std::io;

/// The colour scale, % of the cycle: the good points' smallest safe shifts over every method
/// (every point's when none is good), widened to a span of at least 1 %.
pub(super) fn scale(s: &Sweep) -> (f64, f64) {
    let range = |good_only: bool| {
        s.rows
            .iter()
            .filter(|r| r.safe_shift_pct.is_finite() && (r.good || !good_only))
            .map(|r| r.safe_shift_pct)
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
                (a.min(x), b.max(x))
            })
    };
    let (lo, hi) = match range(true) {
        (lo, hi) if lo.is_finite() => (lo, hi),
        _ => range(false),
    };
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi - lo < 1.0 {
        let lo = ((lo + hi) / 2.0 - 0.5).max(0.0);
        return (lo, lo + 1.0);
    }
    (lo, hi)
}

/// The figure's size: the cells' rows at 40 to 70 px, within 460 to 1000 px of height.
pub(super) fn size(g: &Grid) -> (u32, u32) {
    let rows = g.ys.len() as u32;
    (1100, (180 + 60 * rows).clamp(460, 1000))
}

/// Draws `method`'s (the sweep's method at `m`) heat map; returns each cell's region.
pub(super) fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    s: &Sweep,
    g: &Grid,
    m: usize,
    (lo, hi): (f64, f64),
) -> io::Result<Vec<Hot>> {
    let method = &s.methods[m];
    root.fill(&WHITE).map_err(err)?;
    let body = root
        .titled(
            &format!("{method}: smallest safe SYNC0 shift at each point"),
            font(TITLE),
        )
        .map_err(err)?;
    let (plot, strip) = with_strip(&body);
    let (nx, ny) = (g.xs.len() as i32, g.ys.len() as i32);
    let mut chart = ChartBuilder::on(&plot)
        .margin(10)
        .margin_right(24)
        .x_label_area_size(56)
        .y_label_area_size(110)
        // 0..n-1 segmented: n segments, the value k's from Exact(k) to Exact(k + 1).
        .build_cartesian_2d((0..nx - 1).into_segmented(), (0..ny - 1).into_segmented())
        .map_err(err)?;
    let label_of = |values: &[String], v: &SegmentValue<i32>| match v {
        SegmentValue::CenterOf(i) => values.get(*i as usize).cloned().unwrap_or_default(),
        _ => String::new(),
    };
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(g.xs.len().min(24))
        .y_labels(g.ys.len().min(24))
        .x_label_formatter(&|v| label_of(&g.xs, v))
        .y_label_formatter(&|v| label_of(&g.ys, v))
        .x_desc(s.keys[g.x_key].as_str())
        .y_desc(s.keys[g.y_key].as_str())
        .label_style(font(TICK))
        .axis_desc_style(font(TICK))
        .draw()
        .map_err(err)?;
    let mut hots = Vec::new();
    for r in s.rows.iter().filter(|r| r.method == *method) {
        let Some(&(c, row)) = g.cells.get(r.point) else {
            continue;
        };
        let (c, row) = (c as i32, row as i32);
        let corner =
            |dc: i32, dr: i32| (SegmentValue::Exact(c + dc), SegmentValue::Exact(row + dr));
        // Pixel corners: top left, bottom right.
        let (a, b) = (
            chart.backend_coord(&corner(0, 1)),
            chart.backend_coord(&corner(1, 0)),
        );
        let fill = if r.good {
            viridis((r.safe_shift_pct - lo) / (hi - lo))
        } else {
            BAD_GREY
        };
        root.draw(&Rectangle::new([a, b], fill.filled()))
            .map_err(err)?;
        if !r.good {
            for (p, q) in hatch(a, b, 9) {
                root.draw(&PathElement::new(vec![p, q], HATCH_GREY.stroke_width(1)))
                    .map_err(err)?;
            }
        }
        root.draw(&Rectangle::new([a, b], WHITE.stroke_width(1)))
            .map_err(err)?;
        let best = s.is_method_best(r);
        if best {
            let inset = [(a.0 + 3, a.1 + 3), (b.0 - 3, b.1 - 3)];
            root.draw(&Rectangle::new(inset, TARGET_BLACK.stroke_width(4)))
                .map_err(err)?;
        }
        cell_text(&root, r, (a, b), fill, best)?;
        hots.push(Hot {
            shape: HotShape::Rect(a.0, a.1, b.0 - a.0, b.1 - a.1),
            point: r.point,
            method: r.method.clone(),
            good: r.good,
            best,
            title: s.row_title(r),
        });
    }
    let missing = hots.len() < g.cells.len();
    color_bar(&strip, (lo, hi), missing)?;
    root.present().map_err(err)?;
    Ok(hots)
}

/// A cell's value (its smallest safe shift, %; "best" above it in the best cell), when the
/// cell has room for it.
fn cell_text<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    r: &Row,
    (a, b): ((i32, i32), (i32, i32)),
    fill: RGBColor,
    best: bool,
) -> io::Result<()> {
    let (w, h) = (b.0 - a.0, b.1 - a.1);
    if w < 52 || h < 24 {
        return Ok(());
    }
    let ink = if white_text_on(fill) { WHITE } else { BLACK };
    let text = if r.safe_shift_pct.is_finite() {
        format!("{:.1}", r.safe_shift_pct)
    } else {
        "-".into()
    };
    let mid = ((a.0 + b.0) / 2, (a.1 + b.1) / 2);
    let lines: Vec<String> = if best && h >= 48 {
        vec!["best".into(), text]
    } else {
        vec![text]
    };
    let row = 20;
    let top = mid.1 - row * (lines.len() as i32 - 1) / 2;
    for (k, line) in lines.into_iter().enumerate() {
        let style = font(TICK)
            .color(&ink)
            .pos(Pos::new(HPos::Center, VPos::Center));
        root.draw(&Text::new(line, (mid.0, top + row * k as i32), style))
            .map_err(err)?;
    }
    Ok(())
}

/// The colour bar (top of the legend strip), with its unit, and the legend of the cells
/// below it.
fn color_bar<DB: DrawingBackend>(
    strip: &DrawingArea<DB, Shift>,
    (lo, hi): (f64, f64),
    missing: bool,
) -> io::Result<()> {
    let (w, h) = strip.dim_in_pixel();
    let (bar, rest) = strip.split_vertically((h as i32 - 150).clamp(120, 320));
    let (bar, _) = bar.split_horizontally((w as i32).min(150));
    let mut chart = ChartBuilder::on(&bar)
        .caption("safe shift, %", font(TICK))
        .margin(8)
        .margin_right(44)
        .y_label_area_size(64)
        .build_cartesian_2d(0.0..1.0, lo..hi)
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_labels(0)
        .y_labels(5)
        .set_all_tick_mark_size(6)
        .y_label_formatter(&|v| format!("{v:.1}"))
        .label_style(font(TICK))
        .draw()
        .map_err(err)?;
    const STEPS: usize = 64;
    let step = (hi - lo) / STEPS as f64;
    chart
        .draw_series((0..STEPS).map(|k| {
            let y0 = lo + k as f64 * step;
            Rectangle::new(
                [(0.0, y0), (1.0, y0 + step)],
                viridis((k as f64 + 0.5) / STEPS as f64).filled(),
            )
        }))
        .map_err(err)?;
    let mut keys = vec![
        Key {
            label: "not good: late or\nlost frames, not ranked\nor off its target".into(),
            color: BAD_GREY,
            swatch: Swatch::Cell { hatched: true },
        },
        Key {
            label: "outlined: the\nmethod's best point".into(),
            color: TARGET_BLACK,
            swatch: Swatch::Frame,
        },
    ];
    if missing {
        keys.push(Key {
            label: "empty: not run yet".into(),
            color: WHITE,
            swatch: Swatch::Cell { hatched: false },
        });
    }
    legend(&rest, &keys, 6)
}

/// What a heat map shows, in words (sweep.html's caption).
pub(super) fn caption(s: &Sweep, g: &Grid, method: &str, (lo, hi): (f64, f64)) -> String {
    let best = s
        .method_best
        .iter()
        .find(|(m, _)| m == method)
        .map_or("it has no good point".to_string(), |(_, p)| {
            format!("its best is point {p} ({})", s.describe(*p))
        });
    format!(
        "{method}'s smallest safe SYNC0 shift (% of the cycle) at each point, {} across and {} up, the values in the sweep's order; one cell per point. The colour scale runs from {lo:.1} to {hi:.1} % (dark is smaller, better) and is the same in every method's map. Grey and hatched: not good there (late or lost frames, not ranked, or off its target), whatever its value. Outlined: {best}. Hover a cell for its figures.",
        s.keys[g.x_key], s.keys[g.y_key]
    )
}
