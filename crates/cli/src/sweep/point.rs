//! One point of a search: a scenario's TOML text with values written in, compared; shared by
//! `sweep` and `tune`.

use super::grid;
use anyhow::{Context, Result, bail};
use ecsync_lab::compare::{Options, compare_with};
use ecsync_lab::report::{SummaryOut, summarize};
use ecsync_lab::run::RunError;
use std::sync::atomic::{AtomicBool, AtomicU64};
use toml::{Table, Value};

/// The base scenario (`name`, TOML `text`) as a table, checked as `compare` reads it, with
/// `run` fields set (`runs`, `cycles`, `warmup_s`, `methods`, each from its option: a value
/// the scenario refuses is named by the option).
pub fn base_table(name: &str, text: &str, run: &[(&str, Value)]) -> Result<Table> {
    ecsync_lab::parse(name, text).map_err(anyhow::Error::msg)?;
    let mut t: Table = text.parse().with_context(|| name.to_string())?;
    let entry = t.entry("run").or_insert_with(|| Value::Table(Table::new()));
    let Value::Table(r) = entry else {
        bail!("{name}: [run] is not a table");
    };
    for (k, v) in run {
        r.insert((*k).to_string(), v.clone());
    }
    // A value the command line set is refused naming its option (`--runs 0`), not a point or
    // a line of the text made here.
    if let Err(e) = ecsync_lab::parse(name, &toml::to_string(&t)?) {
        match run.iter().find(|(k, _)| e.field == format!("run.{k}")) {
            Some((k, _)) => bail!("--{}: {}; fix: {}", k.replace('_', "-"), e.message, e.fix),
            None => return Err(anyhow::Error::msg(e)),
        }
    }
    Ok(t)
}

/// The TOML text of `base` with `keys` set to `values`, checked as a scenario file and against
/// the cycle its network needs (the error names `what`, the point, and the file `name`: not a
/// line, since the text checked is the one made here, without the file's comments and in
/// another order, and the base file itself was checked first: the point's values are the cause).
pub fn scenario_text(
    name: &str,
    base: &Table,
    keys: &[String],
    values: &[Value],
    what: &str,
) -> Result<String> {
    let text = grid::apply(base, keys, values)?;
    let s = ecsync_lab::parse(name, &text).map_err(|mut e| {
        e.line = None;
        anyhow::anyhow!("{what}: {e}")
    })?;
    ecsync_lab::run::check_cycle_fits(&s).map_err(|e| anyhow::anyhow!("{what}: {e}"))?;
    Ok(text)
}

/// Compares the scenario `text` on `threads` threads: `None` when `stop` was set before it
/// ended (a point is kept whole or not at all).
pub fn run(
    name: &str,
    text: &str,
    threads: usize,
    stop: &AtomicBool,
) -> Result<Option<SummaryOut>> {
    let s = ecsync_lab::parse(name, text).map_err(anyhow::Error::msg)?;
    let opts = Options {
        stop: Some(stop),
        ..Default::default()
    };
    match compare_with(&s, threads, &AtomicU64::new(0), &opts) {
        Ok(c) if !c.interrupted => Ok(Some(summarize(&c))),
        Ok(_) | Err(RunError::Interrupted) => Ok(None),
        Err(e) => Err(anyhow::anyhow!("{name}: {e}")),
    }
}
