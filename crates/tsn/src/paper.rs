//! The paper's Tables I and II, and ours computed from the explored models the same way.
//!
//! The paper: "the first row shows the difference between values measured in the M2 model and
//! the M1 model as a percentage, while the second row does the same with respect to the M3
//! model. This value is calculated by dividing the absolute value of the subtraction of the
//! results obtained in the corresponding models by the result obtained by the M1 model. [...]
//! the third row show the improvement that the M3 model supposes with respect to the M2 model
//! [...] dividing the percentage obtained in the first row by the one obtained in the second."
//!
//! Table I compares the largest measured delays. Table II compares "the maximum difference
//! between the different clocks"; its figures are reproduced by the width of the range of each
//! difference (largest `a - b` plus largest `b - a`), which is what the pairs of one-sided
//! `A[] Num_period > 0 imply a - b <= c` queries in the XML files bound. The largest `|a - b|`
//! does not reproduce them (M-S2, M2 vs M1 would be (120 - 30) / 30 = 300 %, not 217 %).

use crate::{ModelReport, Pair};

/// Table I as printed: rows M1 vs M2, M1 vs M3, improvement; columns Delay S1, Delay S2.
pub const TABLE_I: [[&str; 2]; 3] = [["100%", "67%"], ["25%", "0%"], ["x4", "x 67/0"]];

/// Table II as printed: columns M-S1, M-S2, S1-S2 clock diff.
pub const TABLE_II: [[&str; 3]; 3] = [
    ["200%", "217%", "171%"],
    ["60%", "33%", "29%"],
    ["x3.3", "x6.5", "x6"],
];

/// Row titles of both tables.
pub const ROWS: [&str; 3] = [
    "No TSN (M1) vs No Sync TSN (M2)",
    "No TSN (M1) vs Sync TSN (M3)",
    "Improvement M3 vs M2",
];

/// The bounds the XML files' queries state, per model: `Delay[0]`, `Delay[1]`, and per pair
/// (M-S1, M-S2, S1-S2) the bounds of `a - b` and `b - a`.
pub struct XmlBounds {
    /// `A[] Delay[0] <= c`, `A[] Delay[1] <= c`.
    pub delay: [i32; 2],
    /// Per pair, (`a - b <= c`, `b - a <= c`).
    pub diff: [(i32, i32); 3],
}

/// The query constants of M1.xml, M2.xml and M3.xml.
pub const XML_BOUNDS: [XmlBounds; 3] = [
    XmlBounds {
        delay: [40, 60],
        diff: [(30, 20), (30, 30), (30, 40)],
    },
    XmlBounds {
        delay: [80, 100],
        diff: [(90, 60), (70, 120), (50, 140)],
    },
    XmlBounds {
        delay: [30, 60],
        diff: [(40, 40), (40, 40), (40, 50)],
    },
];

/// One cell: the paper's text, ours as a number, ours formatted like the paper.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Cell {
    /// As printed in the paper.
    pub paper: &'static str,
    /// Ours (a percentage in rows 1-2, a ratio in row 3; `None`: division by zero).
    pub ours: Option<f64>,
    /// Ours formatted as the paper does.
    pub ours_text: String,
    /// Ours, formatted, equals the paper's cell.
    pub matches: bool,
}

/// A table: per row, per column.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Table {
    /// Column titles.
    pub columns: Vec<&'static str>,
    /// Row titles.
    pub rows: Vec<&'static str>,
    /// The cells.
    pub cells: Vec<Vec<Cell>>,
}

fn pct(m1: f64, other: f64) -> f64 {
    (other - m1).abs() / m1 * 100.0
}

fn column(m1: f64, m2: f64, m3: f64, paper: [&'static str; 3]) -> [Cell; 3] {
    let r1 = pct(m1, m2);
    let r2 = pct(m1, m3);
    let pct_text = |x: f64| format!("{:.0}%", x);
    let ratio = (r2 > 0.0).then(|| r1 / r2);
    let ratio_text = match ratio {
        // The paper prints one decimal where it is not whole (x3.3, x6.5), none otherwise.
        Some(x) if (x - x.round()).abs() < 0.05 => format!("x{:.0}", x),
        Some(x) => format!("x{:.1}", x),
        None => format!("x {:.0}/0", r1),
    };
    let cell = |paper: &'static str, ours: Option<f64>, text: String| Cell {
        paper,
        matches: paper == text,
        ours,
        ours_text: text,
    };
    [
        cell(paper[0], Some(r1), pct_text(r1)),
        cell(paper[1], Some(r2), pct_text(r2)),
        cell(paper[2], ratio, ratio_text),
    ]
}

/// Table I from the three reports (M1, M2, M3 in that order).
pub fn table_i(r: &[ModelReport; 3]) -> Table {
    let cols: Vec<[Cell; 3]> = (0..2)
        .map(|i| {
            column(
                f64::from(r[0].delay_max[i]),
                f64::from(r[1].delay_max[i]),
                f64::from(r[2].delay_max[i]),
                [TABLE_I[0][i], TABLE_I[1][i], TABLE_I[2][i]],
            )
        })
        .collect();
    transpose(vec!["Delay S1", "Delay S2"], cols)
}

/// Table II from the three reports.
pub fn table_ii(r: &[ModelReport; 3]) -> Table {
    let span = |m: &ModelReport, p: Pair| {
        f64::from(m.diff.iter().find(|d| d.0 == p).map_or(0, |d| d.1.span()))
    };
    let cols: Vec<[Cell; 3]> = Pair::ALL
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            column(
                span(&r[0], p),
                span(&r[1], p),
                span(&r[2], p),
                [TABLE_II[0][i], TABLE_II[1][i], TABLE_II[2][i]],
            )
        })
        .collect();
    transpose(Pair::ALL.iter().map(|p| p.title()).collect(), cols)
}

fn transpose(columns: Vec<&'static str>, cols: Vec<[Cell; 3]>) -> Table {
    let cells = (0..3)
        .map(|row| cols.iter().map(|c| c[row].clone()).collect())
        .collect();
    Table {
        columns,
        rows: ROWS.to_vec(),
        cells,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{DiffRange, Model};

    fn report(model: Model, delay: [i32; 2], diff: [(i32, i32); 3]) -> ModelReport {
        ModelReport {
            model,
            states: 0,
            delay_max: delay,
            delay_min: [0; 2],
            diff: Pair::ALL
                .iter()
                .zip(diff)
                .map(|(&p, (ab, ba))| {
                    (
                        p,
                        DiffRange {
                            max_a_minus_b: ab,
                            max_b_minus_a: ba,
                        },
                    )
                })
                .collect(),
            blocked: None,
            deadlock: true,
        }
    }

    /// The XML's query constants, put through the paper's arithmetic, give every printed cell:
    /// the reading of both tables is pinned independently of the explorer.
    #[test]
    fn the_xml_bounds_reproduce_both_tables_by_the_papers_arithmetic() {
        let r = [Model::M1, Model::M2, Model::M3].map(|m| {
            let b = &XML_BOUNDS[m as usize];
            report(m, b.delay, b.diff)
        });
        for t in [table_i(&r), table_ii(&r)] {
            for row in &t.cells {
                for c in row {
                    assert!(c.matches, "{} vs {}", c.paper, c.ours_text);
                }
            }
        }
    }
}
