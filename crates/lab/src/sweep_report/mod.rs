//! The report of a parameter sweep (`ecsync sweep --report`, `ecsync sweep report`): the
//! trade-off of every point (smallest safe SYNC0 shift against phase error), a heat map per
//! method when the sweep crosses two parameters, and sweep.html around them, in compare's look
//! (its method colours, type sizes, legend strip and style sheet; the helpers are the plots').
//!
//! The report is drawn from what the caller read out of the sweep's database and nothing
//! else, so that a merged database gives the same bytes as the sweep run whole, and one
//! database the same bytes every time: no time, no path, no hash-ordered map goes in.
//!
//! Which point is good and which is best is the caller's (the sweep's answer decides it, and
//! the report must name the point the answer names); the report only draws it.

mod heatmap;
mod page;
mod tradeoff;

use crate::output::write_atomic;
use crate::plots::{fonts, write_svg_png};
use plotters::prelude::*;
use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// One method at one point of the sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// The point's number (its place in the sweep's grid or list).
    pub point: usize,
    /// The method, with its send mode.
    pub method: String,
    /// Frames after a drive's SYNC0.
    pub late_frames: u64,
    /// Frames lost.
    pub lost_frames: u64,
    /// The smallest SYNC0 shift without a late frame, % of the cycle (NaN: none).
    pub safe_shift_pct: f64,
    /// p99.9 of |phase - target|, ns (NaN: none).
    pub phase_error_p999_ns: f64,
    /// p99.9 of |slave - reference| system time, ns (NaN: none).
    pub slave_spread_p999_ns: f64,
    /// Its place in the point's ranking, 1 best (`None`: not ranked).
    pub rank: Option<u32>,
    /// Why the verdict left it out of the ranking, in `compare`'s words (`None`: ranked, or
    /// the point has no ranking).
    pub not_ranked: Option<String>,
    /// Whether its mean phase held the target.
    pub holds_target: bool,
    /// Whether compare warned that it was still settling as the recording began: its figures
    /// hold the pull-in.
    pub settling: bool,
    /// Whether the sweep's answer counts the point for this method: drawn filled (else
    /// hollow on the trade-off, grey and hatched on a heat map).
    pub good: bool,
}

/// What a sweep's report shows.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// The base scenario's name.
    pub scenario: String,
    /// The swept keys, in the database's column order.
    pub keys: Vec<String>,
    /// Every point of the sweep (done or not): its values as text, in the keys' order. The
    /// heat maps' axes take the values in this order.
    pub points: Vec<Vec<String>>,
    /// The methods in the order that gives their colours (compare's: the scenario's).
    pub methods: Vec<String>,
    /// Every point done, per method.
    pub rows: Vec<Row>,
    /// The answer's point: (method, point).
    pub best: Option<(String, usize)>,
    /// Each method's best point, as the answer names it (a method absent has none).
    pub method_best: Vec<(String, usize)>,
    /// The sweep's answer in words, as `ecsync sweep` prints it.
    pub answer: String,
}

impl Sweep {
    /// The point's values as `key=value` pairs.
    pub fn describe(&self, point: usize) -> String {
        let Some(values) = self.points.get(point) else {
            return String::new();
        };
        let pairs: Vec<String> = self
            .keys
            .iter()
            .zip(values)
            .map(|(k, v)| format!("{k}={v}"))
            .collect();
        pairs.join(", ")
    }

    /// The colour position of `method` (past the list: after it).
    fn color_index(&self, method: &str) -> usize {
        self.methods
            .iter()
            .position(|m| m == method)
            .unwrap_or(self.methods.len())
    }

    fn is_best(&self, r: &Row) -> bool {
        self.best
            .as_ref()
            .is_some_and(|(m, p)| *m == r.method && *p == r.point)
    }

    fn is_method_best(&self, r: &Row) -> bool {
        self.method_best
            .iter()
            .any(|(m, p)| *m == r.method && *p == r.point)
    }

    /// Every row's figures in one line, the tooltip of its marker or cell.
    fn row_title(&self, r: &Row) -> String {
        format!(
            "{} at point {} ({}): smallest safe shift {:.1} %, phase error p99.9 {:.0} ns, {} late, {} lost, rank {}{}",
            r.method,
            r.point,
            self.describe(r.point),
            r.safe_shift_pct,
            r.phase_error_p999_ns,
            r.late_frames,
            r.lost_frames,
            r.rank.map_or("-".to_string(), |k| k.to_string()),
            if r.good { "" } else { " (not good)" }
        )
    }
}

/// The heat maps' layout: which two keys are the axes, their values in grid order, and each
/// point's cell.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Grid {
    /// The key across (the later of the two: in a grid it changes faster).
    pub x_key: usize,
    /// The key up.
    pub y_key: usize,
    /// The values across and up, in grid order.
    pub xs: Vec<String>,
    pub ys: Vec<String>,
    /// Each point's cell: (column, row).
    pub cells: Vec<(usize, usize)>,
}

/// Distinct values in order of first appearance.
fn distinct<'a>(values: impl Iterator<Item = &'a String>) -> Vec<String> {
    let mut out: Vec<String> = Vec::new();
    for v in values {
        if !out.contains(v) {
            out.push(v.clone());
        }
    }
    out
}

/// The heat maps' grid when exactly two keys take more than one value and no two points share
/// a cell (a list may repeat a combination; a cell then would hide a point); else why not.
pub(crate) fn grid(s: &Sweep) -> Result<Grid, String> {
    let columns: Vec<Vec<String>> = (0..s.keys.len())
        .map(|k| distinct(s.points.iter().filter_map(|p| p.get(k))))
        .collect();
    let swept: Vec<usize> = (0..s.keys.len())
        .filter(|&k| columns[k].len() > 1)
        .collect();
    let [y_key, x_key] = swept[..] else {
        return Err(format!(
            "a heat map needs exactly two swept keys with more than one value; this sweep has {}",
            swept.len()
        ));
    };
    let (xs, ys) = (columns[x_key].clone(), columns[y_key].clone());
    let mut cells = Vec::with_capacity(s.points.len());
    for (i, p) in s.points.iter().enumerate() {
        let col = xs.iter().position(|v| *v == p[x_key]).unwrap_or(0);
        let row = ys.iter().position(|v| *v == p[y_key]).unwrap_or(0);
        if let Some(j) = cells.iter().position(|c| *c == (col, row)) {
            return Err(format!(
                "points {j} and {i} have the same {} and {} (a list that repeats a combination)",
                s.keys[x_key], s.keys[y_key]
            ));
        }
        cells.push((col, row));
    }
    Ok(Grid {
        x_key,
        y_key,
        xs,
        ys,
        cells,
    })
}

/// A region of a drawn plot that stands for one row: invisible in the SVG, with the row's
/// figures as its `<title>` (a browser's tooltip over the marker or cell) and its point,
/// method and standing as data attributes (what a script, or a test, reads off the plot).
#[derive(Debug, Clone)]
pub(crate) struct Hot {
    /// A circle (cx, cy, r) or a rectangle (x, y, w, h), px.
    pub shape: HotShape,
    pub point: usize,
    pub method: String,
    pub good: bool,
    pub best: bool,
    pub title: String,
}

#[derive(Debug, Clone, Copy)]
pub(crate) enum HotShape {
    Circle(i32, i32, i32),
    Rect(i32, i32, i32, i32),
}

/// An attribute value: `esc` and the quote.
fn attr(s: &str) -> String {
    crate::html::esc(s).replace('"', "&quot;")
}

/// `svg` with `hots` as a last group of invisible shapes (on top, so they take the pointer).
pub(crate) fn with_hots(svg: &str, kind: &str, hots: &[Hot]) -> String {
    let mut g = format!("<g class=\"ecsync-{kind}\" fill=\"none\" pointer-events=\"all\">\n");
    for h in hots {
        let shape = match h.shape {
            HotShape::Circle(x, y, r) => format!("circle cx=\"{x}\" cy=\"{y}\" r=\"{r}\""),
            HotShape::Rect(x, y, w, hh) => {
                format!("rect x=\"{x}\" y=\"{y}\" width=\"{w}\" height=\"{hh}\"")
            }
        };
        let tag = shape.split(' ').next().unwrap_or("rect");
        let _ = writeln!(
            g,
            "<{shape} data-point=\"{}\" data-method=\"{}\" data-good=\"{}\" data-best=\"{}\"><title>{}</title></{tag}>",
            h.point,
            attr(&h.method),
            u8::from(h.good),
            u8::from(h.best),
            crate::html::esc(&h.title)
        );
    }
    g.push_str("</g>\n");
    match svg.rfind("</svg>") {
        Some(k) => format!("{}{g}{}", &svg[..k], &svg[k..]),
        None => svg.to_string(),
    }
}

/// A method's name as part of a file name: letters, digits and `-+._` kept, the rest `_`.
pub fn file_stem(method: &str) -> String {
    method
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-+._".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// Draws `$draw(root) -> io::Result<Vec<Hot>>` at `$p` as an SVG (with the hot regions, kind
/// `$kind`) or a PNG of `$size`.
macro_rules! hot_plot {
    ($p:expr, $svg:expr, $size:expr, $kind:expr, |$root:ident| $draw:expr) => {
        if $svg {
            let mut text = String::new();
            let hots = {
                let $root = SVGBackend::with_string(&mut text, $size).into_drawing_area();
                $draw?
            };
            std::fs::write($p, with_hots(&text, $kind, &hots))
        } else {
            let $root = BitMapBackend::new($p, $size).into_drawing_area();
            $draw.map(drop)
        }
    };
}

/// A plot of the report: file stem, caption, SVG text.
pub(crate) struct Written {
    pub name: String,
    pub caption: String,
    pub svg: String,
}

/// Writes the report into `dir` (which must exist): tradeoff.svg/.png, a heat map per method
/// when the sweep crosses two keys, sweep.html. Returns the files' names.
pub fn write(s: &Sweep, dir: &Path) -> io::Result<Vec<String>> {
    fonts();
    let mut plots = Vec::new();
    let size = (1100, 620);
    let svg = write_svg_png(dir, "tradeoff", &|p: &Path, svg: bool| {
        hot_plot!(p, svg, size, "points", |root| tradeoff::draw(root, s))
    })?;
    plots.push(Written {
        name: "tradeoff".into(),
        caption: tradeoff::caption(s),
        svg,
    });
    let grid = grid(s);
    if let Ok(g) = &grid {
        let scale = heatmap::scale(s);
        let size = heatmap::size(g);
        for (i, m) in s.methods.iter().enumerate() {
            if !s.rows.iter().any(|r| r.method == *m) {
                continue;
            }
            let name = format!("heatmap-{}", file_stem(m));
            let svg = write_svg_png(dir, &name, &|p: &Path, svg: bool| {
                hot_plot!(p, svg, size, "cells", |root| heatmap::draw(
                    root, s, g, i, scale
                ))
            })?;
            plots.push(Written {
                name,
                caption: heatmap::caption(s, g, m, scale),
                svg,
            });
        }
    }
    let html = page::html(s, &plots, grid.as_ref().err().map(String::as_str));
    write_atomic(&dir.join("sweep.html"), html.as_bytes())?;
    let mut files: Vec<String> = plots
        .iter()
        .flat_map(|p| [format!("{}.svg", p.name), format!("{}.png", p.name)])
        .collect();
    files.push("sweep.html".into());
    Ok(files)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sweep(points: &[[&str; 3]]) -> Sweep {
        Sweep {
            scenario: "t".into(),
            keys: vec!["a".into(), "b".into(), "c".into()],
            points: points
                .iter()
                .map(|p| p.iter().map(|v| v.to_string()).collect())
                .collect(),
            methods: vec!["m".into()],
            rows: Vec::new(),
            best: None,
            method_best: Vec::new(),
            answer: String::new(),
        }
    }

    #[test]
    fn two_swept_keys_make_a_grid_in_grid_order_and_a_constant_key_is_no_axis() {
        let s = sweep(&[
            ["0.01", "k", "30"],
            ["0.01", "k", "10"],
            ["0.02", "k", "30"],
            ["0.02", "k", "10"],
        ]);
        let g = grid(&s).unwrap();
        assert_eq!((g.y_key, g.x_key), (0, 2));
        // Values as the grid gave them, not sorted.
        assert_eq!(g.xs, ["30", "10"]);
        assert_eq!(g.ys, ["0.01", "0.02"]);
        assert_eq!(g.cells, [(0, 0), (1, 0), (0, 1), (1, 1)]);
    }

    #[test]
    fn one_or_three_swept_keys_or_a_repeated_cell_make_no_grid() {
        assert!(grid(&sweep(&[["1", "k", "x"], ["2", "k", "x"]])).is_err());
        assert!(grid(&sweep(&[["1", "k", "x"], ["2", "l", "y"]])).is_err());
        let e = grid(&sweep(&[["1", "k", "x"], ["2", "k", "y"], ["1", "k", "x"]])).unwrap_err();
        assert!(e.contains("points 0 and 2"), "{e}");
    }

    #[test]
    fn hot_regions_go_last_in_the_svg_with_escaped_text() {
        let hots = [Hot {
            shape: HotShape::Rect(1, 2, 3, 4),
            point: 7,
            method: "a\"b".into(),
            good: false,
            best: true,
            title: "x < y".into(),
        }];
        let svg = with_hots("<svg>\n<rect/>\n</svg>\n", "cells", &hots);
        assert!(
            svg.starts_with("<svg>\n<rect/>\n<g class=\"ecsync-cells\""),
            "{svg}"
        );
        assert!(svg.contains("<rect x=\"1\" y=\"2\" width=\"3\" height=\"4\" data-point=\"7\" data-method=\"a&quot;b\" data-good=\"0\" data-best=\"1\"><title>x &lt; y</title></rect>"), "{svg}");
        assert!(svg.ends_with("</g>\n</svg>\n"));
        assert_eq!(
            file_stem("dcm master/shift+txtime"),
            "dcm_master_shift+txtime"
        );
    }
}
