//! `--expect`: thresholds on the judge's figures, `key=value`, `key<=value`, `key>=value`,
//! `key<value` or `key>value`, comma-separated, each broken one said in words.

use super::JudgeOut;
use std::fmt;
use std::str::FromStr;

/// A comparison of a figure against a value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Op {
    Eq,
    Le,
    Ge,
    Lt,
    Gt,
}

impl Op {
    fn as_str(self) -> &'static str {
        match self {
            Op::Eq => "=",
            Op::Le => "<=",
            Op::Ge => ">=",
            Op::Lt => "<",
            Op::Gt => ">",
        }
    }

    fn holds(self, x: f64, v: f64) -> bool {
        match self {
            Op::Eq => x == v,
            Op::Le => x <= v,
            Op::Ge => x >= v,
            Op::Lt => x < v,
            Op::Gt => x > v,
        }
    }
}

/// A key: its name, what it is, and the figure of a [`JudgeOut`] (None: not measured).
struct Key {
    name: &'static str,
    what: &'static str,
    get: fn(&JudgeOut) -> Option<f64>,
}

const US: f64 = 1000.0;

const KEYS: &[Key] = &[
    Key {
        name: "late",
        what: "frames that reached a drive after the SYNC0 pulse they were meant for",
        get: |o| Some(o.late as f64),
    },
    Key {
        name: "missed",
        what: "SYNC0 pulses with no new outputs since the previous pulse",
        get: |o| Some(o.missed as f64),
    },
    Key {
        name: "lost",
        what: "frames lost",
        get: |o| Some(o.lost as f64),
    },
    Key {
        name: "dup",
        what: "retried frames",
        get: |o| Some(o.duplicates as f64),
    },
    Key {
        name: "late_replies",
        what: "replies the serving host sent late",
        get: |o| Some(o.late_replies as f64),
    },
    Key {
        name: "al_errors",
        what: "AL errors raised",
        get: |o| Some(o.al_errors as f64),
    },
    Key {
        name: "al_errors_read",
        what: "AL errors the master read",
        get: |o| Some(o.al_errors_read as f64),
    },
    Key {
        name: "wkc_errors",
        what: "frames with an unusual or zero working counter",
        get: |o| Some(o.wkc_errors as f64),
    },
    Key {
        name: "frames",
        what: "frames with process data",
        get: |o| Some(o.pd_frames as f64),
    },
    Key {
        name: "phase_p999_us",
        what: "99.9th percentile of |phase - mean phase|, us",
        get: |o| o.phase.dev_p999_ns.map(|v| v / US),
    },
    Key {
        name: "phase_std_us",
        what: "standard deviation of the phase, us",
        get: |o| o.phase.std_ns.map(|v| v / US),
    },
    Key {
        name: "phase_mean_us",
        what: "mean phase (before SYNC0 negative), us",
        get: |o| o.phase.mean_ns.map(|v| v / US),
    },
    Key {
        name: "drift_ns_per_s",
        what: "|drift of the phase|, ns/s",
        get: |o| o.phase.drift_ns_per_s.map(f64::abs),
    },
    Key {
        name: "margin_min_us",
        what: "smallest SYNC0 margin of any drive, us",
        get: |o| o.margin_min_ns.map(|v| v / US),
    },
    Key {
        name: "spread_p999_ns",
        what: "99.9th percentile of the drives' spread, ns",
        get: |o| o.spread_p999_ns,
    },
    Key {
        name: "recovery_ms",
        what: "the longest way back to OP after a fault (never: infinite), ms",
        get: |o| Some(o.recovery_max_ms().unwrap_or(0.0)),
    },
];

/// One threshold.
#[derive(Debug, Clone, PartialEq)]
struct Clause {
    key: usize,
    op: Op,
    value: f64,
}

/// Thresholds on a [`JudgeOut`], parsed from `late=0,missed=0,phase_p999_us<=50`.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Expect {
    clauses: Vec<Clause>,
}

/// Why an `--expect` text does not parse.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExpectError(pub String);

impl fmt::Display for ExpectError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ExpectError {}

impl Expect {
    /// The keys, each with what it is, one a line (for messages and `--help`).
    pub fn keys() -> String {
        KEYS.iter()
            .map(|k| format!("  {}: {}", k.name, k.what))
            .collect::<Vec<_>>()
            .join("\n")
    }

    /// Each broken threshold, in words (`late = 3, expected 0`); empty when all hold.
    pub fn check(&self, out: &JudgeOut) -> Vec<String> {
        let mut broken = Vec::new();
        for c in &self.clauses {
            let k = &KEYS[c.key];
            let want = match c.op {
                Op::Eq => fmt_num(c.value),
                op => format!("{} {}", op.as_str(), fmt_num(c.value)),
            };
            match (k.get)(out) {
                None => broken.push(format!(
                    "{}: not measured (no frame with process data judged), expected {want}",
                    k.name
                )),
                Some(x) if !c.op.holds(x, c.value) => {
                    broken.push(format!("{} = {}, expected {want}", k.name, fmt_num(x)));
                }
                Some(_) => {}
            }
        }
        broken
    }

    /// Whether there are no thresholds.
    pub fn is_empty(&self) -> bool {
        self.clauses.is_empty()
    }
}

fn fmt_num(x: f64) -> String {
    if x.is_infinite() {
        "never".into()
    } else if x == x.trunc() && x.abs() < 1e15 {
        format!("{x:.0}")
    } else {
        let s = format!("{x:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

impl FromStr for Expect {
    type Err = ExpectError;

    fn from_str(s: &str) -> Result<Self, ExpectError> {
        let mut clauses = Vec::new();
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            let (at, op) = [("<=", Op::Le), (">=", Op::Ge), ("<", Op::Lt), (">", Op::Gt), ("=", Op::Eq)]
                .iter()
                .filter_map(|(t, op)| part.find(t).map(|i| ((i, t.len()), *op)))
                .min_by_key(|((i, l), _)| (*i, usize::MAX - l))
                .ok_or_else(|| {
                    ExpectError(format!(
                        "`{part}`: no comparison; write key=value, key<=value, key>=value, key<value or key>value"
                    ))
                })?;
            let key = part[..at.0].trim();
            let val = part[at.0 + at.1..].trim();
            let Some(k) = KEYS.iter().position(|k| k.name == key) else {
                return Err(ExpectError(format!(
                    "`{part}`: unknown key `{key}`; the keys are:\n{}",
                    Expect::keys()
                )));
            };
            let value = match val {
                "never" | "inf" | "infinity" => f64::INFINITY,
                v => v
                    .parse::<f64>()
                    .ok()
                    .filter(|x| !x.is_nan())
                    .ok_or_else(|| ExpectError(format!("`{part}`: `{v}` is not a number")))?,
            };
            clauses.push(Clause { key: k, op, value });
        }
        if clauses.is_empty() {
            return Err(ExpectError(format!(
                "no thresholds in `{s}`; e.g. late=0,missed=0,phase_p999_us<=50; the keys are:\n{}",
                Expect::keys()
            )));
        }
        Ok(Expect { clauses })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_operator() {
        let e: Expect = "late=0, missed<=1,phase_p999_us<50.5,frames>=100,recovery_ms<never,dup>0"
            .parse()
            .unwrap();
        let ops: Vec<Op> = e.clauses.iter().map(|c| c.op).collect();
        assert_eq!(ops, [Op::Eq, Op::Le, Op::Lt, Op::Ge, Op::Lt, Op::Gt]);
        assert_eq!(e.clauses[2].value, 50.5);
        assert_eq!(e.clauses[4].value, f64::INFINITY);
    }

    #[test]
    fn refuses_what_it_cannot_read() {
        let e = "lateness=0".parse::<Expect>().unwrap_err();
        assert!(e.0.contains("unknown key `lateness`"), "{e}");
        assert!(
            e.0.contains("phase_p999_us") && e.0.contains("recovery_ms"),
            "{e}"
        );
        assert!(
            "late"
                .parse::<Expect>()
                .unwrap_err()
                .0
                .contains("no comparison")
        );
        assert!(
            "late=x"
                .parse::<Expect>()
                .unwrap_err()
                .0
                .contains("not a number")
        );
        assert!("".parse::<Expect>().is_err());
    }
}
