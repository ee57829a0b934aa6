//! sweep.html: the answer first (the words `ecsync sweep` prints), then the plots inline (the
//! file alone shows them, as compare's report.html does), then every point and method in a
//! table, the answer's row marked.

use super::{Row, Sweep, Written};
use crate::html::{CSS, Figure, esc, figure_html};
use std::fmt::Write as _;

/// A figure, or "-" when there is none (NULL in the database).
fn fig(x: f64, places: usize) -> String {
    if x.is_finite() {
        format!("{x:.places$}")
    } else {
        "-".into()
    }
}

/// sweep.html of `s` with its `plots`; `no_heat` says why there is no heat map.
pub(super) fn html(s: &Sweep, plots: &[Written], no_heat: Option<&str>) -> String {
    let mut h = String::new();
    let _ = write!(
        h,
        "<!doctype html><html><head><meta charset=\"utf-8\"><title>ecsync sweep: {}</title><style>{CSS}tr.bad td{{color:#888}}.verdict pre{{white-space:pre-wrap;background:none;font-size:14px;padding:0}}</style></head><body>",
        esc(&s.scenario)
    );
    let done: std::collections::BTreeSet<usize> = s.rows.iter().map(|r| r.point).collect();
    let missing = s.points.len() - done.len();
    let _ = write!(
        h,
        "<h1>ecsync sweep</h1><p>{}: {} of {} over {}; methods {}.{}</p>",
        esc(&s.scenario),
        done.len(),
        crate::scenario::plural(s.points.len() as u64, "point", "points"),
        esc(&s.keys.join(", ")),
        esc(&s.methods.join(", ")),
        if missing > 0 {
            format!(
                " <b>{} not in the database yet</b>: the figures are of the points done.",
                if missing == 1 {
                    "1 point is".to_string()
                } else {
                    format!("{missing} points are")
                }
            )
        } else {
            String::new()
        }
    );
    let _ = write!(
        h,
        "<div class=verdict><h2>The answer</h2><pre>{}</pre></div>",
        esc(&s.answer)
    );
    let _ = write!(h, "<h2>Plots</h2>");
    for p in plots {
        figure_html(
            &mut h,
            &Figure {
                name: &p.name,
                caption: &p.caption,
                svg: p.svg.clone(),
            },
        );
    }
    if let Some(why) = no_heat {
        let _ = write!(h, "<p>No heat maps: {}.</p>", esc(why));
    }
    table(&mut h, s);
    h.push_str("</body></html>\n");
    h
}

/// Every point and method: the swept values, the figures the answer reads, the rank.
fn table(h: &mut String, s: &Sweep) {
    let _ = write!(
        h,
        "<h2>Every point</h2><p>One row per point and method, in point order; the answer's row is green, a row that is not good (late or lost frames, not ranked, or off its target) grey. The database's view sweep_results has these and every other figure (<code>sqlite3 sweep.db 'select * from sweep_results'</code>).</p><table><tr><th>point</th>"
    );
    for k in &s.keys {
        let _ = write!(h, "<th class=l>{}</th>", esc(k));
    }
    let _ = write!(
        h,
        "<th class=l>method</th><th>late frames</th><th>lost frames</th><th>smallest safe shift (%)</th><th>phase error p99.9 (ns)</th><th>slave spread p99.9 (ns)</th><th>rank</th><th>good</th></tr>"
    );
    let mut rows: Vec<&Row> = s.rows.iter().collect();
    rows.sort_by_key(|r| (r.point, s.color_index(&r.method), r.method.clone()));
    for r in rows {
        let class = if s.is_best(r) {
            " style=\"background:#eef8ee\""
        } else if !r.good {
            " class=bad"
        } else {
            ""
        };
        let _ = write!(h, "<tr{class}><td>{}</td>", r.point);
        for v in s.points.get(r.point).into_iter().flatten() {
            let _ = write!(h, "<td class=l>{}</td>", esc(v));
        }
        let _ = write!(
            h,
            "<td class=l>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>{}<td>{}</td></tr>",
            esc(&r.method),
            r.late_frames,
            r.lost_frames,
            fig(r.safe_shift_pct, 1),
            fig(r.phase_error_p999_ns, 0),
            fig(r.slave_spread_p999_ns, 0),
            match (&r.not_ranked, r.rank) {
                (Some(why), _) => format!("<td class=l>not ranked: {}</td>", esc(why)),
                (None, Some(k)) => format!("<td>{k}</td>"),
                (None, None) => "<td>-</td>".to_string(),
            },
            if r.good { "yes" } else { "no" }
        );
    }
    let _ = write!(h, "</table>");
}
