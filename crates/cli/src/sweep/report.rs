//! The sweep's report (`ecsync sweep --report DIR`, `ecsync sweep report --db F --out DIR`):
//! tradeoff.svg, a heat map per method when two keys are swept, sweep.html. Read from the
//! database alone, so that a merged database gives the same files as the sweep run whole;
//! drawn by `ecsync_lab::sweep_report` with compare's plot helpers. Which points are good and
//! which is best is the answer's own decision ([`answer::best`]), so the report's marks and
//! the answer's words name the same points.

use super::answer;
use super::db::{Meta, ResultRow, Store};
use super::grid::show;
use anyhow::{Result, anyhow};
use ecsync_lab::sweep_report::Sweep;
use std::path::Path;

/// Makes `dir` and checks that a file can be written into it: before any point runs, so that
/// a report that cannot be written fails at once, not after the sweep's hours.
pub fn check_dir(flag: &str, dir: &Path) -> Result<()> {
    ecsync_lab::output::ensure_writable_dir(dir).map_err(|e| {
        anyhow!(
            "{flag}: cannot write into {}: {e}; fix: give a folder you can write to",
            dir.display()
        )
    })
}

/// The methods in the order that colours them: the base scenario's (compare's order, so a
/// method has the colour it has in compare's report), then any other the rows hold, by name.
fn method_order(meta: &Meta, rows: &[ResultRow]) -> Vec<String> {
    let mut order: Vec<String> = ecsync_lab::parse(&meta.base_name, &meta.base_toml)
        .map(|s| s.entries().iter().map(|e| e.name()).collect())
        .unwrap_or_default();
    let mut rest: Vec<String> = rows
        .iter()
        .map(|r| r.method.clone())
        .filter(|m| !order.contains(m))
        .collect();
    rest.sort();
    rest.dedup();
    order.extend(rest);
    order
}

/// What the report shows, read from `store`.
fn sweep(store: &Store, meta: &Meta) -> Result<Sweep> {
    let mut rows = store.rows()?;
    for r in &mut rows {
        r.good = answer::good(r);
    }
    let mut best = answer::best(&rows);
    // Over the seed alone no point is a design's best: none is marked, as the answer names
    // none.
    if answer::seed_only(store, &meta.points)? {
        best.overall = None;
        best.per_method.clear();
    }
    Ok(Sweep {
        scenario: meta.base_name.clone(),
        keys: meta.points.keys.clone(),
        points: meta
            .points
            .rows
            .iter()
            .map(|p| p.iter().map(show).collect())
            .collect(),
        methods: method_order(meta, &rows),
        best: best.overall.map(|r| (r.method.clone(), r.point)),
        method_best: best
            .per_method
            .values()
            .flatten()
            .map(|r| (r.method.clone(), r.point))
            .collect(),
        answer: answer::text(store, &meta.points)?,
        rows,
    })
}

/// Writes the report of the sweep in `store` into `dir` (given as `flag`); returns the
/// files' names.
pub fn write(store: &Store, meta: &Meta, flag: &str, dir: &Path) -> Result<Vec<String>> {
    let s = sweep(store, meta)?;
    ecsync_lab::sweep_report::write(&s, dir).map_err(|e| {
        anyhow!(
            "{flag}: cannot write the report into {}: {e}; fix: give a folder you can write to (`ecsync sweep report --db F --out DIR` writes it again from the database)",
            dir.display()
        )
    })
}
