//! The points of a sweep: parameters named by their place in the scenario file
//! (`run.sync0_shift_pct`, `methods.median-fit.gain`, `segment.slave.2.ppm`), each with its
//! values, crossed into a grid or listed row by row, and each point's scenario as TOML text.
//!
//! A point's scenario is the base file with the point's values written into it, read by the
//! same parser as `compare --config`: every check and every error message is the file's.

use anyhow::{Context, Result, bail};
use std::fmt::Write as _;
use toml::{Table, Value};

/// One swept parameter: where it sits in the scenario and the values it takes.
#[derive(Debug, Clone, PartialEq)]
pub struct Param {
    /// As given: `run.sync0_shift_pct`.
    pub key: String,
    /// Its values, in the order given.
    pub values: Vec<Value>,
}

/// The points: a grid (every combination of the parameters' values, the last parameter
/// changing fastest) or a list (the rows of a CSV file).
#[derive(Debug, Clone, PartialEq)]
pub struct Points {
    /// The parameters' keys, in column order.
    pub keys: Vec<String>,
    /// Every point's values, in the keys' order; the index is the point's number.
    pub rows: Vec<Vec<Value>>,
}

/// The most points a sweep takes (a typo in a range should not ask for a billion runs).
pub const MAX_POINTS: usize = 1_000_000;

impl Points {
    /// Every combination of `params`' values.
    pub fn grid(params: &[Param]) -> Result<Points> {
        let mut rows: Vec<Vec<Value>> = vec![Vec::new()];
        for p in params {
            if rows.len().saturating_mul(p.values.len()) > MAX_POINTS {
                bail!(
                    "--grid: more than {MAX_POINTS} points; fix: give fewer values or split the sweep"
                );
            }
            rows = rows
                .into_iter()
                .flat_map(|r| {
                    p.values.iter().map(move |v| {
                        let mut r = r.clone();
                        r.push(v.clone());
                        r
                    })
                })
                .collect();
        }
        let keys: Vec<String> = params.iter().map(|p| p.key.clone()).collect();
        check_keys(&keys, "--grid")?;
        Ok(Points { keys, rows })
    }

    /// The rows of a CSV list: a header of keys, then one point per line, values as in
    /// `--grid` (a value holding a comma in double quotes, as CSV quotes it).
    pub fn list(file: &str, text: &str) -> Result<Points> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty() && !l.trim_start().starts_with('#'));
        let Some((_, header)) = lines.next() else {
            bail!(
                "{file}: no header line; fix: give the keys first, e.g. run.sync0_shift_pct,methods.median.gain"
            );
        };
        let keys: Vec<String> = split_csv(header)
            .into_iter()
            .map(|k| k.trim().to_string())
            .collect();
        check_keys(&keys, file)?;
        let mut rows = Vec::new();
        for (n, line) in lines {
            let cells = split_csv(line);
            if cells.len() != keys.len() {
                bail!(
                    "{file}, line {}: {} values for {} keys; fix: give one value per key",
                    n + 1,
                    cells.len(),
                    keys.len()
                );
            }
            rows.push(
                cells
                    .iter()
                    .map(|c| value_of(&csv_unquote(c.trim())))
                    .collect(),
            );
        }
        if rows.is_empty() {
            bail!("{file}: no point; fix: give one line of values per point after the header");
        }
        if rows.len() > MAX_POINTS {
            bail!("{file}: more than {MAX_POINTS} points; fix: split the list");
        }
        Ok(Points { keys, rows })
    }

    /// The point's values as `key=value` pairs, for messages and logs.
    pub fn describe(&self, point: usize) -> String {
        let mut s = String::new();
        for (k, v) in self.keys.iter().zip(&self.rows[point]) {
            if !s.is_empty() {
                s.push_str(", ");
            }
            let _ = write!(s, "{k}={}", show(v));
        }
        s
    }

    /// A canonical text of the points (keys and every row), stored with a sweep so that a
    /// database is only ever extended by the same sweep.
    pub fn canonical(&self) -> String {
        let mut s = self.keys.join("\u{1f}");
        for r in &self.rows {
            s.push('\n');
            let cells: Vec<String> = r.iter().map(show).collect();
            s.push_str(&cells.join("\u{1f}"));
        }
        s
    }
}

/// Keys are not empty and not given twice.
fn check_keys(keys: &[String], what: &str) -> Result<()> {
    for (i, k) in keys.iter().enumerate() {
        if k.is_empty() || k.split('.').any(str::is_empty) {
            bail!(
                "{what}: the key \"{k}\" has an empty part; fix: name a field as the scenario file does, e.g. run.sync0_shift_pct"
            );
        }
        if keys[..i].contains(k) {
            bail!("{what}: {k} is given twice; fix: give each parameter once, with all its values");
        }
    }
    Ok(())
}

/// A value as the grid and the database show it: strings bare, the rest as TOML writes it.
pub fn show(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        v => v.to_string(),
    }
}

/// `KEY=V1,V2,...` or `KEY=START:STOP:STEP` (numbers, both ends included).
pub fn parse_param(arg: &str) -> Result<Param> {
    let Some((key, values)) = arg.split_once('=') else {
        bail!(
            "--grid {arg}: no '='; fix: give KEY=V1,V2,... or KEY=START:STOP:STEP, e.g. run.sync0_shift_pct=10:50:10"
        );
    };
    let key = key.trim().to_string();
    let values = values.trim();
    let range: Vec<&str> = values.split(':').collect();
    let values = if range.len() == 3 && !values.contains(',') && !values.contains('"') {
        range_values(&key, range[0], range[1], range[2])?
    } else {
        split_csv(values)
            .iter()
            .map(|v| value_of(v.trim()))
            .collect()
    };
    if values.is_empty()
        || values
            .iter()
            .any(|v| matches!(v, Value::String(s) if s.is_empty()))
    {
        bail!("--grid {arg}: an empty value; fix: give KEY=V1,V2,...");
    }
    Ok(Param { key, values })
}

/// START:STOP:STEP as integers when all three are, else as decimals rounded to the step's
/// decimals (so 0.1 steps give 0.3, not 0.30000000000000004).
fn range_values(key: &str, a: &str, b: &str, step: &str) -> Result<Vec<Value>> {
    let bad = |why: &str| {
        anyhow::anyhow!(
            "--grid {key}={a}:{b}:{step}: {why}; fix: give START:STOP:STEP with a positive STEP, e.g. 10:50:10"
        )
    };
    let too_many = |n: f64| {
        anyhow::anyhow!(
            "--grid {key}={a}:{b}:{step}: {n:.0} values, more than the {MAX_POINTS} points a sweep takes; fix: a larger STEP or a shorter range"
        )
    };
    if let (Ok(a), Ok(b), Ok(s)) = (a.parse::<i64>(), b.parse::<i64>(), step.parse::<i64>()) {
        if s <= 0 || b < a {
            return Err(bad("STEP must be above 0 and STOP not below START"));
        }
        // In i128: STOP - START of two i64 does not overflow there.
        let n = (i128::from(b) - i128::from(a)) / i128::from(s) + 1;
        if n > MAX_POINTS as i128 {
            return Err(too_many(n as f64));
        }
        let n = n as i64;
        return Ok((0..n).map(|i| Value::Integer(a + i * s)).collect());
    }
    let (Ok(x), Ok(y), Ok(s)) = (a.parse::<f64>(), b.parse::<f64>(), step.parse::<f64>()) else {
        return Err(bad("not numbers"));
    };
    if !(s > 0.0 && x.is_finite() && y.is_finite() && y >= x) {
        return Err(bad("STEP must be above 0 and STOP not below START"));
    }
    let n = ((y - x) / s + 1e-9).floor() + 1.0;
    if n > MAX_POINTS as f64 {
        return Err(too_many(n));
    }
    let n = n as usize;
    let decimals = [a, b, step]
        .iter()
        .map(|t| t.split_once('.').map_or(0, |(_, d)| d.len()))
        .max()
        .unwrap_or(0) as i32;
    let scale = 10f64.powi(decimals);
    Ok((0..n)
        .map(|i| Value::Float(((x + i as f64 * s) * scale).round() / scale))
        .collect())
}

/// One value: a TOML value when it reads as one (`10`, `0.5`, `true`, `"plain"`,
/// `["plain", "txtime"]`), else the text as a string (`median-fit`, `vanilla-linux`).
pub fn value_of(text: &str) -> Value {
    match format!("v = {text}").parse::<Table>() {
        Ok(mut t) => t.remove("v").unwrap_or(Value::String(text.to_string())),
        Err(_) => Value::String(text.to_string()),
    }
}

/// Splits on commas outside double quotes and brackets.
fn split_csv(s: &str) -> Vec<String> {
    let mut out = vec![String::new()];
    let (mut depth, mut quoted) = (0i32, false);
    for c in s.chars() {
        match c {
            '"' => quoted = !quoted,
            '[' | '{' if !quoted => depth += 1,
            ']' | '}' if !quoted => depth -= 1,
            ',' if !quoted && depth == 0 => {
                out.push(String::new());
                continue;
            }
            _ => {}
        }
        out.last_mut().expect("one").push(c);
    }
    out
}

/// A CSV cell as its text: a cell wholly in double quotes is CSV's quoting (RFC 4180: what a
/// spreadsheet, Python's csv or pandas writes around a value holding a comma or a quote, its
/// quotes doubled), taken off before the text is read as TOML: `"[""plain"", ""spin""]"` is
/// the list `["plain", "spin"]`, `"0.5"` the number. A TOML string needs its own quotes inside
/// CSV's (`"""text"""`), or none where the text is not TOML (`vanilla-linux`).
fn csv_unquote(cell: &str) -> String {
    match cell.strip_prefix('"').and_then(|c| c.strip_suffix('"')) {
        Some(inner) if !inner.replace("\"\"", "").contains('"') => inner.replace("\"\"", "\""),
        _ => cell.to_string(),
    }
}

/// The base scenario with `keys` set to `values`: the TOML text of the point's scenario.
/// A key's parts name tables (created when absent) and, as a number, an element of an array
/// of tables (`segment.slave.2.ppm`: the third slave).
pub fn apply(base: &Table, keys: &[String], values: &[Value]) -> Result<String> {
    let mut t = base.clone();
    for (key, v) in keys.iter().zip(values) {
        set(&mut t, key, v.clone()).with_context(|| format!("--grid {key}"))?;
    }
    Ok(toml::to_string(&t)?)
}

fn set(t: &mut Table, key: &str, v: Value) -> Result<()> {
    let parts: Vec<&str> = key.split('.').collect();
    let (last, path) = parts.split_last().expect("a key has a part");
    let mut root = Value::Table(std::mem::take(t));
    let result = set_in(&mut root, path, last, key, v);
    if let Value::Table(tab) = root {
        *t = tab;
    }
    result
}

fn set_in(root: &mut Value, path: &[&str], last: &str, key: &str, v: Value) -> Result<()> {
    let mut here = root;
    for p in path {
        here = step(here, p, key)?;
    }
    match here {
        Value::Table(tab) => {
            tab.insert(last.to_string(), v);
            Ok(())
        }
        Value::Array(a) => {
            let i = index(last, a.len(), key)?;
            a[i] = v;
            Ok(())
        }
        _ => bail!(
            "{key}: {} is a value, not a table; fix: name a field of the scenario file",
            path.join(".")
        ),
    }
}

fn step<'a>(here: &'a mut Value, part: &str, key: &str) -> Result<&'a mut Value> {
    match here {
        Value::Table(tab) => Ok(tab
            .entry(part.to_string())
            .or_insert_with(|| Value::Table(Table::new()))),
        Value::Array(a) => {
            let i = index(part, a.len(), key)?;
            Ok(&mut a[i])
        }
        _ => bail!(
            "{key}: {part} is inside a value, not a table; fix: name a field of the scenario file"
        ),
    }
}

fn index(part: &str, len: usize, key: &str) -> Result<usize> {
    match part.parse::<usize>() {
        Ok(i) if i < len => Ok(i),
        _ => bail!(
            "{key}: \"{part}\" does not name one of the {len} elements (0 to {}); fix: give an index",
            len.saturating_sub(1)
        ),
    }
}
