//! A twin of a real host: traces recorded by `ecsync host record` (or `ecsync run --csv`), and a
//! trace replayed in blocks instead of the model ([`Replay`]); the host model fitted to one is
//! [`crate::host_fit`].
//!
//! A trace is a CSV file with a header naming its columns; lines starting with `#` are comments.
//! The columns read (others, such as `ecsync run`'s, are skipped):
//!
//! * `wake_latency_ns` (required): the cyclic task's wake-up minus its scheduled instant;
//! * `exec_ns` (required): from the wake-up to the send timestamp (the cycle's work);
//! * `tx_delay_ns` (optional, may be empty): from the send timestamp to the kernel's (or NIC's)
//!   TX timestamp; empty where none was taken.
//!
//! The model the fit writes ([`HostParams`](crate::host::HostParams)): the wake-up latency is a floor plus j_s (a folded
//! Gaussian, exponential pulses, bursts in which it is scaled); the floor is counted in e_m, since
//! the simulator's host only uses j_s + e_m (the wake-up to the send). Replay resamples blocks of
//! consecutive cycles (a moving-block bootstrap), each block's start a hash of (seed, block), so
//! the trace's bursts stay bursts and a run is a pure function of its seed.
//!
//! ```
//! use ecsync_sim::host_trace::HostTrace;
//!
//! let t = HostTrace::parse("t.csv", "cycle,wake_latency_ns,exec_ns,tx_delay_ns\n0,52000,900,\n1,51000,950,12000\n").unwrap();
//! assert_eq!(t.rows.len(), 2);
//! assert_eq!(t.rows[1].tx_delay_ns, Some(12_000.0));
//! let e = HostTrace::parse("t.csv", "cycle,wake_latency_ns,exec_ns\n0,52000,x\n").unwrap_err();
//! assert_eq!((e.line, e.field.as_str()), (Some(2), "exec_ns"));
//! ```

use crate::config::ConfigError;
use crate::rng::splitmix64;

/// The header `ecsync host record` writes.
pub const TRACE_HEADER: &str = "cycle,scheduled_ns,wake_latency_ns,exec_ns,tx_delay_ns";

/// Cycles per replayed block unless told otherwise: a second at 1 ms, longer than the bursts
/// a loaded host shows, short enough that a minute's trace gives dozens of blocks.
pub const DEFAULT_BLOCK_CYCLES: u64 = 1_000;

/// One recorded cycle, ns.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraceRow {
    /// Wake-up latency.
    pub wake_latency_ns: f64,
    /// Wake-up to send timestamp.
    pub exec_ns: f64,
    /// Send timestamp to the TX timestamp, where one was taken.
    pub tx_delay_ns: Option<f64>,
}

/// A recorded host trace.
#[derive(Debug, Clone, PartialEq)]
pub struct HostTrace {
    /// The file it was read from.
    pub file: String,
    /// Its cycles in order.
    pub rows: Vec<TraceRow>,
}

fn error(file: &str, line: usize, field: &str, message: String, fix: &str) -> ConfigError {
    ConfigError {
        file: file.to_string(),
        line: Some(line),
        field: field.to_string(),
        message,
        fix: fix.to_string(),
    }
}

impl HostTrace {
    /// Parses a trace; an error names the file, the line and the column.
    pub fn parse(file: &str, text: &str) -> Result<HostTrace, ConfigError> {
        let mut lines = text
            .lines()
            .enumerate()
            .map(|(i, l)| (i + 1, l.trim()))
            .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
        let Some((header_line, header)) = lines.next() else {
            return Err(ConfigError {
                file: file.to_string(),
                line: None,
                field: "header".to_string(),
                message: "no header and no cycles".to_string(),
                fix: format!("record one with `ecsync host record`; its header is {TRACE_HEADER}"),
            });
        };
        let cols: Vec<&str> = header.split(',').map(str::trim).collect();
        let col = |name: &str| cols.iter().position(|c| *c == name);
        let need = |name: &str| {
            col(name).ok_or_else(|| {
                error(
                    file,
                    header_line,
                    name,
                    format!("the header has no column {name}"),
                    &format!("a trace's header names at least wake_latency_ns and exec_ns, as {TRACE_HEADER}"),
                )
            })
        };
        let (wake_c, exec_c) = (need("wake_latency_ns")?, need("exec_ns")?);
        let tx_c = col("tx_delay_ns");
        let mut rows = Vec::new();
        for (n, l) in lines {
            let fields: Vec<&str> = l.split(',').map(str::trim).collect();
            if fields.len() != cols.len() {
                return Err(error(
                    file,
                    n,
                    cols.get(fields.len().min(cols.len().saturating_sub(1)))
                        .copied()
                        .unwrap_or("row"),
                    format!("{} fields, the header has {}", fields.len(), cols.len()),
                    "give every row the header's columns, separated by commas",
                ));
            }
            let num = |c: usize, min_ns: f64| -> Result<Option<f64>, ConfigError> {
                let v = fields[c];
                if v.is_empty() {
                    return Ok(None);
                }
                match v.parse::<f64>() {
                    Ok(x) if x.is_finite() && x >= min_ns && x < 1e12 => Ok(Some(x)),
                    _ => Err(error(
                        file,
                        n,
                        cols[c],
                        format!("\"{v}\" is not a time in ns"),
                        &format!("give a number of ns >= {min_ns} (or leave tx_delay_ns empty)"),
                    )),
                }
            };
            let required = |c: usize, min_ns: f64| {
                num(c, min_ns)?.ok_or_else(|| {
                    error(
                        file,
                        n,
                        cols[c],
                        "empty".to_string(),
                        "give a number of ns: only tx_delay_ns may be empty",
                    )
                })
            };
            rows.push(TraceRow {
                // A wake-up before its instant would be a clock error, but a few ns of rounding
                // are harmless.
                wake_latency_ns: required(wake_c, -1_000.0)?,
                exec_ns: required(exec_c, 0.0)?,
                tx_delay_ns: match tx_c {
                    Some(c) => num(c, 0.0)?,
                    None => None,
                },
            });
        }
        if rows.len() < 2 {
            return Err(error(
                file,
                header_line,
                "rows",
                format!("{} cycles", rows.len()),
                "record at least a few seconds (ecsync host record --duration 60)",
            ));
        }
        Ok(HostTrace {
            file: file.to_string(),
            rows,
        })
    }

    /// The first half and the second half of the cycles.
    pub fn halves(&self) -> (&[TraceRow], &[TraceRow]) {
        self.rows.split_at(self.rows.len() / 2)
    }
}

/// A trace replayed in blocks of consecutive cycles.
#[derive(Debug, Clone, PartialEq)]
pub struct Replay {
    trace: HostTrace,
    block_cycles: u64,
}

/// Salt of the block choice's hash.
const REPLAY_SALT: u64 = 0x7ace_b10c_5eed_0002;

impl Replay {
    /// Replays `trace` in blocks of `block_cycles` (at most the trace's length).
    pub fn new(trace: HostTrace, block_cycles: u64) -> Result<Replay, String> {
        let n = trace.rows.len() as u64;
        if block_cycles == 0 || block_cycles > n {
            return Err(format!(
                "a block of {block_cycles} cycles does not fit {}'s {n} cycles; give between 1 and {n}",
                trace.file
            ));
        }
        Ok(Replay {
            trace,
            block_cycles,
        })
    }

    /// The trace.
    pub fn trace(&self) -> &HostTrace {
        &self.trace
    }

    /// Cycles per block.
    pub fn block_cycles(&self) -> u64 {
        self.block_cycles
    }

    /// Where block `block` of a run seeded `seed` starts in the trace: a pure function of both.
    pub fn block_start(&self, seed: u64, block: u64) -> u64 {
        let starts = self.trace.rows.len() as u64 - self.block_cycles + 1;
        splitmix64(seed ^ REPLAY_SALT ^ splitmix64(block ^ REPLAY_SALT)) % starts
    }

    /// The recorded cycle that plays cycle `cycle` of a run seeded `seed`.
    pub fn row(&self, seed: u64, cycle: u64) -> &TraceRow {
        let (b, o) = (cycle / self.block_cycles, cycle % self.block_cycles);
        let i = (self.block_start(seed, b) + o) as usize;
        // `new` keeps every block inside the trace.
        &self.trace.rows[i.min(self.trace.rows.len() - 1)]
    }
}
