//! Streaming statistics: mean, standard deviation, extremes (the letter's), RMS and quantiles of
//! the absolute value from a fixed-bin histogram (p99, p99.9), without keeping the samples.

use serde::Serialize;

/// A histogram of signed values with fixed bins; values outside the range land in the first
/// or last bin (and are counted as such).
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram {
    lo: f64,
    bin: f64,
    inv_bin: f64,
    counts: Vec<u64>,
    below: u64,
    above: u64,
}

impl Histogram {
    /// `bins` bins of width `bin` starting at `lo`.
    pub fn new(lo: f64, bin: f64, bins: usize) -> Self {
        Histogram {
            lo,
            bin,
            inv_bin: 1.0 / bin,
            counts: vec![0; bins.max(1)],
            below: 0,
            above: 0,
        }
    }

    /// Adds a value.
    #[inline]
    pub fn add(&mut self, x: f64) {
        let k = (x - self.lo) * self.inv_bin;
        let n = self.counts.len();
        if k >= 0.0 && k < n as f64 {
            // 0 <= k < n: truncation is the floor, and the signed conversion is one
            // instruction (the unsigned one saturates in several).
            self.counts[k as i64 as usize] += 1;
        } else if k >= 0.0 {
            self.above += 1;
            self.counts[n - 1] += 1;
        } else {
            // Negative or NaN.
            self.below += 1;
            self.counts[0] += 1;
        }
    }

    /// Adds another histogram of the same shape.
    pub fn merge(&mut self, o: &Histogram) {
        for (a, b) in self.counts.iter_mut().zip(&o.counts) {
            *a += b;
        }
        self.below += o.below;
        self.above += o.above;
    }

    /// Total count.
    pub fn total(&self) -> u64 {
        self.counts.iter().sum()
    }

    /// The value below which a fraction `q` of the samples lie (upper edge of the bin).
    pub fn quantile(&self, q: f64) -> f64 {
        let n = self.total();
        if n == 0 {
            return f64::NAN;
        }
        let target = (q * n as f64).ceil().max(1.0) as u64;
        let mut acc = 0;
        for (i, c) in self.counts.iter().enumerate() {
            acc += c;
            if acc >= target {
                return self.lo + (i as f64 + 1.0) * self.bin;
            }
        }
        self.lo + self.counts.len() as f64 * self.bin
    }

    /// Bin centres and counts.
    pub fn bins(&self) -> impl Iterator<Item = (f64, u64)> + '_ {
        self.counts
            .iter()
            .enumerate()
            .map(|(i, &c)| (self.lo + (i as f64 + 0.5) * self.bin, c))
    }

    /// Samples outside the range (below, above).
    pub fn outside(&self) -> (u64, u64) {
        (self.below, self.above)
    }
}

/// Mean, standard deviation, extremes, RMS and the histogram of one quantity. The histogram's
/// range should be symmetric around 0 (or start at 0 for magnitudes): quantiles of |x| are read
/// from it by folding.
#[derive(Debug, Clone, PartialEq)]
pub struct Stats {
    n: u64,
    sum: f64,
    sum_sq: f64,
    min: f64,
    max: f64,
    /// Histogram of the values.
    pub hist: Histogram,
}

impl Stats {
    /// Statistics with a histogram of `bins` bins of width `bin` from `lo`.
    pub fn new(lo: f64, bin: f64, bins: usize) -> Self {
        Stats {
            n: 0,
            sum: 0.0,
            sum_sq: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            hist: Histogram::new(lo, bin, bins),
        }
    }

    /// Adds a sample.
    #[inline]
    pub fn add(&mut self, x: f64) {
        self.n += 1;
        self.sum += x;
        self.sum_sq += x * x;
        // Plain comparisons: a NaN sample leaves the extremes alone (and lands in the
        // histogram's first bin) without the NaN handling of `f64::min`.
        if x < self.min {
            self.min = x;
        }
        if x > self.max {
            self.max = x;
        }
        self.hist.add(x);
    }

    /// Samples so far.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// Quantile `q` of |x|, from the histogram folded at 0 (upper edge of the bin).
    pub fn abs_quantile(&self, q: f64) -> f64 {
        let h = &self.hist;
        let n = h.total();
        if n == 0 {
            return f64::NAN;
        }
        // Bin i covers [lo + i b, lo + (i+1) b); its |x| is at most max(|edges|).
        let mut mags: Vec<(f64, u64)> = h
            .counts
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(i, &c)| {
                let a = h.lo + i as f64 * h.bin;
                (a.abs().max((a + h.bin).abs()), c)
            })
            .collect();
        mags.sort_by(|a, b| a.0.total_cmp(&b.0));
        let target = (q * n as f64).ceil().max(1.0) as u64;
        let mut acc = 0;
        for (m, c) in mags {
            acc += c;
            if acc >= target {
                return m;
            }
        }
        f64::NAN
    }

    /// The summary.
    pub fn summary(&self) -> Summary {
        if self.n == 0 {
            return Summary::default();
        }
        let n = self.n as f64;
        let mean = self.sum / n;
        let max_abs = self.max.abs().max(self.min.abs());
        Summary {
            n: self.n,
            mean,
            std: (self.sum_sq / n - mean * mean).max(0.0).sqrt(),
            max: self.max,
            min: self.min,
            rms: (self.sum_sq / n).sqrt(),
            // The histogram gives a bin's upper edge: never beyond the largest sample.
            p99_abs: self.abs_quantile(0.99).min(max_abs),
            p999_abs: self.abs_quantile(0.999).min(max_abs),
            max_abs,
        }
    }
}

/// What a run reports for one quantity.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Summary {
    /// Samples.
    pub n: u64,
    /// Mean, ns.
    pub mean: f64,
    /// Standard deviation, ns.
    pub std: f64,
    /// Maximum, ns.
    pub max: f64,
    /// Minimum, ns.
    pub min: f64,
    /// Root mean square, ns.
    pub rms: f64,
    /// 99th percentile of |x|, ns.
    pub p99_abs: f64,
    /// 99.9th percentile of |x|, ns.
    pub p999_abs: f64,
    /// Largest |x|, ns.
    pub max_abs: f64,
}

/// The mean of each statistic over runs (the letter's MMean, MStd, MMax, MMin, and the same for
/// the ground-truth figures).
pub fn mean_of(summaries: &[Summary]) -> Summary {
    let k = summaries.len().max(1) as f64;
    let f = |g: fn(&Summary) -> f64| summaries.iter().map(g).sum::<f64>() / k;
    Summary {
        n: summaries.iter().map(|s| s.n).sum(),
        mean: f(|s| s.mean),
        std: f(|s| s.std),
        max: f(|s| s.max),
        min: f(|s| s.min),
        rms: f(|s| s.rms),
        p99_abs: f(|s| s.p99_abs),
        p999_abs: f(|s| s.p999_abs),
        max_abs: summaries.iter().map(|s| s.max_abs).fold(0.0, f64::max),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moments_and_quantiles_by_hand() {
        let mut s = Stats::new(-100.0, 1.0, 200);
        for x in [1.0, 2.0, 3.0, 4.0, -10.0] {
            s.add(x);
        }
        let m = s.summary();
        assert_eq!(m.mean, 0.0);
        // Population variance: (1 + 4 + 9 + 16 + 100) / 5 = 26.
        assert!((m.std - 26f64.sqrt()).abs() < 1e-12);
        assert_eq!((m.min, m.max, m.max_abs), (-10.0, 4.0, 10.0));
        assert!((m.rms - 26f64.sqrt()).abs() < 1e-12);
        // |x| = 1, 2, 3, 4, 10: the 99th percentile is -10's bin [-10, -9), whose largest |x|
        // is 10; the 50th is 3's bin [3, 4): 4.
        assert_eq!(m.p99_abs, 10.0);
        assert_eq!(s.abs_quantile(0.5), 4.0);
    }

    #[test]
    fn out_of_range_values_are_kept() {
        let mut h = Histogram::new(0.0, 1.0, 10);
        h.add(-5.0);
        h.add(50.0);
        h.add(3.5);
        assert_eq!(h.total(), 3);
        assert_eq!(h.outside(), (1, 1));
        assert_eq!(h.quantile(0.5), 4.0);
    }

    #[test]
    fn mean_over_runs() {
        let a = Summary {
            mean: 1.0,
            std: 2.0,
            max: 3.0,
            min: -4.0,
            ..Summary::default()
        };
        let b = Summary {
            mean: 3.0,
            std: 4.0,
            max: 5.0,
            min: -6.0,
            ..Summary::default()
        };
        let m = mean_of(&[a, b]);
        assert_eq!((m.mean, m.std, m.max, m.min), (2.0, 3.0, 4.0, -5.0));
    }
}
