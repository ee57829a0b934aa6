//! Run-to-run noise: whether two methods differ on a ranking key by more than their runs'
//! spread says they could by chance, and whether a comparison has cycles enough for the
//! percentiles it quotes.
//!
//! Every method of a run meets the same noise (one draw per run, see `compare`), so two methods
//! are compared run by run: the paired differences' mean against its 95 % confidence interval
//! (Student's t with runs - 1 degrees of freedom). A difference inside the interval is noise:
//! the verdict says so rather than rank on it. With one run there is no spread to measure, and
//! the verdict says that too.

use super::{MethodOut, RunKeys};

/// Two-sided 95 % quantiles of Student's t for 1..=30 degrees of freedom (beyond: 1.96).
const T95: [f64; 30] = [
    12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160,
    2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056,
    2.052, 2.048, 2.045, 2.042,
];

/// Student's t for a two-sided 95 % interval with `df` degrees of freedom.
fn t95(df: usize) -> f64 {
    match df {
        0 => f64::INFINITY,
        1..=30 => T95[df - 1],
        _ => 1.96,
    }
}

/// Measured cycles per method below which a p99.9 is the maximum of fewer than a thousand
/// samples: the verdict does not rank on it.
pub const MIN_RANKED_CYCLES: u64 = 1_000;
/// Measured cycles per method below which fewer than ten samples lie beyond a p99.9: the
/// figures are quoted, with a warning.
pub const FEW_CYCLES: u64 = 10_000;

/// One key's paired difference between two methods over their runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Difference {
    /// Mean over the runs of a's value minus b's.
    pub mean: f64,
    /// Half the width of its 95 % confidence interval.
    pub half_width: f64,
    /// Runs paired.
    pub runs: usize,
}

impl Difference {
    /// The difference is more than run-to-run noise.
    pub fn significant(&self) -> bool {
        self.mean.abs() > self.half_width
    }
}

/// Key `i` (the order of the ranking's keys; 1, holding the target, has no per-run value) of
/// one run.
/// (`lost`: the first key counts lost frames, as with no fault schedule.)
fn key(k: &RunKeys, i: usize, lost: bool) -> Option<f64> {
    match i {
        0 if lost => Some(k.late_or_lost_frames as f64),
        0 => Some(k.late_frames as f64),
        2 => Some(k.smallest_safe_shift_pct),
        3 => Some(k.slave_spread_p999_ns),
        4 => Some(k.phase_error_p999_ns),
        _ => None,
    }
}

/// The paired difference of key `i` between `a` and `b`, run by run; `None` with fewer than two
/// runs paired or a key with no per-run value.
pub fn paired(a: &MethodOut, b: &MethodOut, i: usize) -> Option<Difference> {
    let d: Vec<f64> = a
        .runs
        .iter()
        .zip(&b.runs)
        .filter_map(|(x, y)| {
            Some(key(&x.keys, i, a.faults.is_empty())? - key(&y.keys, i, b.faults.is_empty())?)
        })
        .filter(|d| d.is_finite())
        .collect();
    difference(&d)
}

/// The mean of the differences `d` and its 95 % interval; `None` for fewer than two.
fn difference(d: &[f64]) -> Option<Difference> {
    let n = d.len();
    if n < 2 {
        return None;
    }
    let mean = d.iter().sum::<f64>() / n as f64;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    Some(Difference {
        mean,
        half_width: t95(n - 1) * (var / n as f64).sqrt(),
        runs: n,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn student_t_matches_the_tables() {
        // Two-sided 95 %: 12.706 for 1 degree of freedom, 2.776 for 4, 2.042 for 30.
        assert_eq!(t95(1), 12.706);
        assert_eq!(t95(4), 2.776);
        assert_eq!(t95(30), 2.042);
        assert_eq!(t95(1000), 1.96);
        assert!(t95(0).is_infinite());
    }

    #[test]
    fn a_constant_difference_is_significant_and_a_wandering_one_is_not() {
        // By hand: differences 1, 1, 1: mean 1, no spread: significant. Differences 3, -1, 1,
        // -2, 4: mean 1, s = sqrt(((2)^2+(-2)^2+0+(-3)^2+3^2)/4) = sqrt(6.5) = 2.55; half
        // width 2.776 * 2.55 / sqrt(5) = 3.17 > 1: noise.
        let d = |v: &[f64]| difference(v).unwrap();
        assert!(d(&[1.0, 1.0, 1.0]).significant());
        let w = d(&[3.0, -1.0, 1.0, -2.0, 4.0]);
        assert!((w.half_width - 3.165).abs() < 0.01, "{w:?}");
        assert!(!w.significant());
        assert!(difference(&[2.0]).is_none());
    }
}
