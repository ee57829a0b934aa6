//! What a comparison writes: summary.json, summary.csv, Table 1 as text, histograms like the
//! letter's Fig. 4 and time series as SVG and PNG, and report.html showing them all.

use crate::compare::Comparison;
use crate::letter::{self, Row};
use crate::stats::{Histogram, Summary, mean_of};
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io;
use std::path::Path;

/// The letter's four indicators of one error, means over runs, ns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Indicators {
    /// MMean.
    pub mean: f64,
    /// MStd.
    pub std: f64,
    /// MMax.
    pub max: f64,
    /// MMin.
    pub min: f64,
}

impl From<Summary> for Indicators {
    fn from(s: Summary) -> Self {
        Indicators {
            mean: s.mean,
            std: s.std,
            max: s.max,
            min: s.min,
        }
    }
}

/// Ground truth figures of one quantity, means over runs (max_abs: the largest).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Truth {
    /// Mean, ns.
    pub mean: f64,
    /// Standard deviation, ns.
    pub std: f64,
    /// Root mean square, ns.
    pub rms: f64,
    /// 99th percentile of |x|, ns.
    pub p99: f64,
    /// 99.9th percentile of |x|, ns.
    pub p999: f64,
    /// Largest |x| in any run, ns.
    pub max_abs: f64,
    /// Smallest value (mean over runs), ns.
    pub min: f64,
    /// Largest value (mean over runs), ns.
    pub max: f64,
}

impl From<Summary> for Truth {
    fn from(s: Summary) -> Self {
        Truth {
            mean: s.mean,
            std: s.std,
            rms: s.rms,
            p99: s.p99_abs,
            p999: s.p999_abs,
            max_abs: s.max_abs,
            min: s.min,
            max: s.max,
        }
    }
}

/// The ground truth of a method.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GroundTruth {
    /// The frame's arrival at the reference against its DC grid point, ns.
    pub phase: Truth,
    /// Largest |slave - reference| system time difference per frame, ns.
    pub slave_ref_diff: Truth,
    /// SYNC0 minus the frame's end at the last slave, ns.
    pub sync0_margin: Truth,
    /// Late frames (negative margin) at the scenario's SYNC0 shift, all runs.
    pub late_frames: u64,
    /// The scenario's SYNC0 shift, % of the cycle.
    pub sync0_shift_pct: f64,
    /// The smallest SYNC0 shift with no late frame in any run, % of the cycle (rounded up to
    /// 0.1 %).
    pub smallest_safe_shift_pct: f64,
    /// Frames lost, all runs.
    pub lost_frames: u64,
    /// Cycles with an unexpected LRW working counter, all runs.
    pub bad_wkc: u64,
}

/// One method's results.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct MethodOut {
    /// The letter's name for it.
    pub letter_name: &'static str,
    /// M-rS error (the letter's definition), ns.
    pub m_rs: Indicators,
    /// rS-IS error (|BRD of 0x092C|, as the letter reads it), ns.
    pub rs_is: Indicators,
    /// The letter's Table 1 values, ns, where it measured the method.
    pub letter: Option<LetterOut>,
    /// What only the simulator knows.
    pub ground_truth: GroundTruth,
    /// Per run: M-rS and rS-IS.
    pub runs: Vec<RunOut>,
    /// Time to DC lock in the bring-up, ms (mean over runs).
    pub lock_ms: f64,
    /// CPU time of this method's runs, s.
    pub wall_s: f64,
}

/// The letter's values of a method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LetterOut {
    /// M-rS, ns.
    pub m_rs: Row,
    /// rS-IS, ns.
    pub rs_is: Row,
}

/// One run of a method.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RunOut {
    /// M-rS, ns.
    pub m_rs: Indicators,
    /// rS-IS, ns.
    pub rs_is: Indicators,
}

/// summary.json.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SummaryOut {
    /// The scenario file or preset.
    pub scenario: String,
    /// Host preset.
    pub host: String,
    /// Base seed.
    pub seed: u64,
    /// Runs.
    pub runs: u32,
    /// Recorded cycles per run.
    pub cycles: u64,
    /// Warm-up cycles per run.
    pub warmup_cycles: u64,
    /// Cycle time, ns.
    pub cycle_ns: u32,
    /// SYNC0 shift, %.
    pub sync0_shift_pct: f64,
    /// Slaves.
    pub slaves: usize,
    /// Results by method.
    pub methods: BTreeMap<String, MethodOut>,
    /// Wall time of the comparison, s.
    pub wall_s: f64,
    /// Threads.
    pub threads: usize,
}

/// Builds summary.json's content.
pub fn summarize(c: &Comparison) -> SummaryOut {
    let s = &c.scenario;
    let period = f64::from(s.cycle_ns);
    let mut methods = BTreeMap::new();
    for (m, name) in s.methods.iter().enumerate() {
        let rs = &c.results[m];
        let sums: Vec<[Summary; 5]> = rs.iter().map(|r| r.summaries()).collect();
        let col = |k: usize| mean_of(&sums.iter().map(|x| x[k]).collect::<Vec<_>>());
        let latest = rs
            .iter()
            .map(|r| r.latest_end_ns)
            .fold(f64::NEG_INFINITY, f64::max);
        let smallest = ((latest / period * 1000.0).ceil() / 10.0).max(0.0);
        let lock: Vec<f64> = rs.iter().filter_map(|r| r.lock_ms).collect();
        methods.insert(
            name.clone(),
            MethodOut {
                letter_name: letter::letter_name(name),
                m_rs: col(0).into(),
                rs_is: col(1).into(),
                letter: letter::table1(name).map(|(m_rs, rs_is)| LetterOut { m_rs, rs_is }),
                ground_truth: GroundTruth {
                    phase: col(2).into(),
                    slave_ref_diff: col(3).into(),
                    sync0_margin: col(4).into(),
                    late_frames: rs.iter().map(|r| r.late_frames).sum(),
                    sync0_shift_pct: s.sync0_shift_pct,
                    smallest_safe_shift_pct: smallest,
                    lost_frames: rs.iter().map(|r| r.lost_frames).sum(),
                    bad_wkc: rs.iter().map(|r| r.bad_wkc).sum(),
                },
                runs: sums
                    .iter()
                    .map(|x| RunOut {
                        m_rs: x[0].into(),
                        rs_is: x[1].into(),
                    })
                    .collect(),
                lock_ms: lock.iter().sum::<f64>() / lock.len().max(1) as f64,
                wall_s: c.method_wall_s[m],
            },
        );
    }
    SummaryOut {
        scenario: s.name.clone(),
        host: s.host_name.clone(),
        seed: s.seed,
        runs: s.runs,
        cycles: s.cycles,
        warmup_cycles: s.warmup_cycles,
        cycle_ns: s.cycle_ns,
        sync0_shift_pct: s.sync0_shift_pct,
        slaves: s.slaves.len(),
        methods,
        wall_s: c.wall_s,
        threads: c.threads,
    }
}

/// Table 1's layout with the letter's values beside ours, in microseconds.
pub fn table1_text(out: &SummaryOut, order: &[String]) -> String {
    let mut t = String::new();
    let us = |v: f64| format!("{:>9.3}", v / 1000.0);
    let _ = writeln!(
        t,
        "Table 1: statistics of clock synchronization errors (us), means over {} runs of {} cycles",
        out.runs, out.cycles
    );
    let _ = write!(t, "{:<18}", "");
    for m in order {
        let mo = &out.methods[m];
        let head = if mo.letter_name == "-" {
            m.clone()
        } else {
            format!("{} ({m})", mo.letter_name)
        };
        let _ = write!(t, "| {:<21}", head);
    }
    let _ = writeln!(t);
    let _ = write!(t, "{:<18}", "Indicator");
    for _ in order {
        let _ = write!(t, "| {:>9} {:>9}  ", "M-rS", "rS-IS");
    }
    let _ = writeln!(t);
    type Row4 = (&'static str, fn(&Indicators) -> f64, fn(&Row) -> f64);
    let rows: [Row4; 4] = [
        ("MMean", |i| i.mean, |r| r.mean),
        ("MStd", |i| i.std, |r| r.std),
        ("MMax", |i| i.max, |r| r.max),
        ("MMin", |i| i.min, |r| r.min),
    ];
    for (label, ours, theirs) in rows {
        let _ = write!(t, "{:<18}", format!("{label} ecsync"));
        for m in order {
            let mo = &out.methods[m];
            let _ = write!(t, "| {} {}  ", us(ours(&mo.m_rs)), us(ours(&mo.rs_is)));
        }
        let _ = writeln!(t);
        let _ = write!(t, "{:<18}", format!("{label} letter"));
        for m in order {
            let mo = &out.methods[m];
            match &mo.letter {
                Some(l) => {
                    let _ = write!(t, "| {} {}  ", us(theirs(&l.m_rs)), us(theirs(&l.rs_is)));
                }
                None => {
                    let _ = write!(t, "| {:>9} {:>9}  ", "-", "-");
                }
            }
        }
        let _ = writeln!(t);
    }
    let _ = writeln!(t);
    let _ = writeln!(t, "Ground truth (only a simulator has it), us:");
    let _ = writeln!(
        t,
        "{:<22}{:>12}{:>12}{:>12}{:>14}{:>12}{:>14}{:>13}",
        "method",
        "phase RMS",
        "phase p99.9",
        "|s-ref| p99",
        "|s-ref| max",
        "late@shift",
        "safe shift %",
        "lock ms"
    );
    for m in order {
        let g = &out.methods[m].ground_truth;
        let _ = writeln!(
            t,
            "{:<22}{:>12.3}{:>12.3}{:>12.3}{:>14.3}{:>12}{:>14.1}{:>13.1}",
            m,
            g.phase.std / 1000.0,
            g.phase.p999 / 1000.0,
            g.slave_ref_diff.p99 / 1000.0,
            g.slave_ref_diff.max_abs / 1000.0,
            g.late_frames,
            g.smallest_safe_shift_pct,
            out.methods[m].lock_ms,
        );
    }
    t
}

/// summary.csv: one row per method and quantity.
pub fn csv(out: &SummaryOut, order: &[String]) -> String {
    let mut t = String::from(
        "method,quantity,mean_ns,std_ns,max_ns,min_ns,letter_mean_ns,letter_std_ns,letter_max_ns,letter_min_ns\n",
    );
    for m in order {
        let mo = &out.methods[m];
        for (q, ind, lt) in [
            ("m_rs", mo.m_rs, mo.letter.map(|l| l.m_rs)),
            ("rs_is", mo.rs_is, mo.letter.map(|l| l.rs_is)),
        ] {
            let l = lt.map_or(",,,".to_string(), |r| {
                format!("{},{},{},{}", r.mean, r.std, r.max, r.min)
            });
            let _ = writeln!(
                t,
                "{m},{q},{},{},{},{},{l}",
                ind.mean, ind.std, ind.max, ind.min
            );
        }
        let g = &mo.ground_truth;
        for (q, tr) in [
            ("true_phase", g.phase),
            ("true_slave_ref_diff", g.slave_ref_diff),
            ("sync0_margin", g.sync0_margin),
        ] {
            let _ = writeln!(
                t,
                "{m},{q},{},{},{},{},,,,",
                tr.mean, tr.std, tr.max_abs, -tr.max_abs
            );
        }
    }
    t
}

/// Writes `text` to `path` atomically (temporary file, then rename).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let tmp = path.with_extension("tmp-ecsync");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

/// Merged histograms of a quantity over runs, per method (in `order`).
pub fn merged(
    c: &Comparison,
    order: &[String],
    pick: fn(&crate::run::RunResult) -> &Histogram,
) -> Vec<(String, Histogram)> {
    order
        .iter()
        .filter_map(|name| {
            let m = c.scenario.methods.iter().position(|x| x == name)?;
            let mut it = c.results[m].iter();
            let mut h = pick(it.next()?).clone();
            for r in it {
                h.merge(pick(r));
            }
            Some((name.clone(), h))
        })
        .collect()
}

/// Writes the plots and report.html.
pub fn write_report(
    c: &Comparison,
    out: &SummaryOut,
    order: &[String],
    dir: &Path,
) -> io::Result<()> {
    crate::plots::write_all(c, out, order, dir)
}
