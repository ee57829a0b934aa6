//! Streaming statistics without ceilings: count, mean, standard deviation, RMS, the exact
//! minimum and maximum, and quantiles of bounded error, without keeping the samples.
//!
//! Quantiles come from two histograms in the layout of HDR histograms of 3 significant digits
//! (the `hdrhistogram` crate's, which a test holds them to), one for the magnitudes of negative
//! values and one for the rest, on a grid of
//! [`RESOLUTION_NS`]. Every value lands in a bucket whose width is at most 2^-10 of the
//! values it holds (exact below 2048 grid steps, 32 ns); a quantile is read as the middle of
//! its bucket and clamped to the exact extremes, so it lies within [`quantile_error_bound`] of
//! the sample of that rank: 2^-11 of its magnitude plus one grid step. The histograms grow
//! with the values (no range to choose, nothing clamped): a value of any size is kept.
//!
//! A quantile `q` is the sample of rank `max(1, ceil(q n))` in ascending order (the lower,
//! "inverted CDF" definition): sort the samples and take index `ceil(q n) - 1` to recompute it.

use serde::Serialize;

/// The grid values are recorded on, ns.
pub const RESOLUTION_NS: f64 = 1.0 / 64.0;
const SCALE: f64 = 64.0;
/// Relative part of the error bound of every quantile.
pub const QUANTILE_REL_ERROR: f64 = 1.0 / 2048.0;
/// Largest magnitude kept exactly in the histograms, in grid steps (about 7e16 ns, two years);
/// larger ones land in the last bucket (the extremes stay exact).
const MAX_STEPS: u64 = 1 << 62;

/// How far a reported quantile can be from the sample of its rank, ns.
pub fn quantile_error_bound(value_ns: f64) -> f64 {
    value_ns.abs() * QUANTILE_REL_ERROR + RESOLUTION_NS
}

/// Counts in the bucket layout of an HDR histogram of 3 significant digits (HdrHistogram's
/// layout, as the `hdrhistogram` crate has it): values below 2048 each in their own bucket,
/// then 1024 buckets per power of two, each 2^b wide.
///
/// The crate's `record` keeps extremes, a total and resize checks on every call; here a value
/// costs an index computation and an increment (the per-cycle hot path records a dozen values
/// per method), and [`Stats`] keeps the exact extremes itself. The layout, and so every
/// quantile, is the crate's: a test compares the two on random values.
#[derive(Debug, Clone, Default)]
struct Buckets {
    /// The counts in chunks of 1024 buckets (a power of two each, but the first two), each
    /// allocated when a value lands in it: a quantity that spans a few powers of two (a
    /// drive's SYNC0 margin, 200 to 280 us) takes a few chunks, not all below its values.
    chunks: Vec<Option<Box<[u64; CHUNK_LEN]>>>,
    total: u64,
}

/// log2 of the half count of sub-buckets (1024).
const HALF_MAGNITUDE: u32 = 10;
/// Values below 2048 are exact.
const SUB_BUCKET_MASK: u64 = 2047;
/// Buckets per chunk (the half count), and the mask of a bucket's place in its chunk.
const CHUNK_LEN: usize = 1 << HALF_MAGNITUDE;
const CHUNK_MASK: usize = CHUNK_LEN - 1;
/// 64 minus the bits of the sub-bucket count.
const LEADING_ZERO_BASE: u32 = 53;

/// The bucket holding `v` and its power-of-two exponent.
#[inline]
fn bucket_of(v: u64) -> u32 {
    LEADING_ZERO_BASE - (v | SUB_BUCKET_MASK).leading_zeros()
}

/// The index of the bucket holding `v`.
#[inline]
fn index_of(v: u64) -> usize {
    let b = bucket_of(v);
    ((b as usize) << HALF_MAGNITUDE) + (v >> b) as usize
}

/// The middle (rounded up) of bucket `i`, the value a quantile in it reads.
fn median_of(i: usize) -> u64 {
    let mut b = (i >> HALF_MAGNITUDE) as i64 - 1;
    let mut sub = (i as u64 & ((1 << HALF_MAGNITUDE) - 1)) + (1 << HALF_MAGNITUDE);
    if b < 0 {
        sub -= 1 << HALF_MAGNITUDE;
        b = 0;
    }
    let low = sub << b;
    low + ((1u64 << b) >> 1)
}

impl Buckets {
    #[inline]
    fn record(&mut self, v: u64) {
        let i = index_of(v);
        let (c, k) = (i >> HALF_MAGNITUDE, i & CHUNK_MASK);
        match self.chunks.get_mut(c) {
            Some(Some(chunk)) => chunk[k] += 1,
            _ => self.grow(c)[k] += 1,
        }
        self.total += 1;
    }

    /// Chunk `c`, allocated.
    #[cold]
    fn grow(&mut self, c: usize) -> &mut [u64; CHUNK_LEN] {
        if self.chunks.len() <= c {
            self.chunks.resize_with(c + 1, || None);
        }
        self.chunks[c].get_or_insert_with(|| Box::new([0; CHUNK_LEN]))
    }

    fn add(&mut self, o: &Buckets) {
        for (c, chunk) in o.chunks.iter().enumerate() {
            let Some(chunk) = chunk else { continue };
            let mine = self.grow(c);
            for (a, &b) in mine.iter_mut().zip(chunk.iter()) {
                *a += b;
            }
        }
        self.total += o.total;
    }

    /// (middle of the bucket, count) of every bucket that holds values, ascending.
    fn recorded(&self) -> impl DoubleEndedIterator<Item = (u64, u64)> + '_ {
        self.chunks
            .iter()
            .enumerate()
            .filter_map(|(c, chunk)| chunk.as_ref().map(|b| (c, b)))
            .flat_map(|(c, chunk)| {
                chunk
                    .iter()
                    .enumerate()
                    .filter(|&(_, &n)| n > 0)
                    .map(move |(k, &n)| (median_of((c << HALF_MAGNITUDE) + k), n))
            })
    }

    /// The value (grid steps, middle of its bucket) of rank `r` (1-based, ascending).
    fn at_rank(&self, r: u64) -> u64 {
        let mut acc = 0;
        let mut last = 0;
        for (v, c) in self.recorded() {
            acc += c;
            last = v;
            if acc >= r {
                return v;
            }
        }
        last
    }
}

/// The distribution of a signed quantity: two HDR-layout histograms, negatives by magnitude
/// and the rest.
#[derive(Debug, Clone, Default)]
pub struct Dist {
    pos: Buckets,
    neg: Buckets,
}

#[inline]
fn steps(magnitude_ns: f64) -> u64 {
    let m = magnitude_ns * SCALE + 0.5;
    if m < MAX_STEPS as f64 {
        m as u64
    } else {
        MAX_STEPS
    }
}

impl Dist {
    /// An empty distribution.
    pub fn new() -> Self {
        Dist::default()
    }

    /// Adds a value, ns (NaN is not counted).
    #[inline]
    pub fn add(&mut self, x: f64) {
        if x < 0.0 {
            self.neg.record(steps(-x));
        } else if x >= 0.0 {
            self.pos.record(steps(x));
        }
    }

    /// Adds another distribution.
    pub fn merge(&mut self, o: &Dist) {
        self.pos.add(&o.pos);
        self.neg.add(&o.neg);
    }

    /// Number of values.
    pub fn total(&self) -> u64 {
        self.pos.total + self.neg.total
    }

    /// The value of rank `r` (1-based, ascending), ns; NaN when empty.
    pub fn at_rank(&self, r: u64) -> f64 {
        let n_neg = self.neg.total;
        let n = n_neg + self.pos.total;
        if n == 0 {
            return f64::NAN;
        }
        let r = r.clamp(1, n);
        if r <= n_neg {
            -(self.neg.at_rank(n_neg - r + 1) as f64) / SCALE
        } else {
            self.pos.at_rank(r - n_neg) as f64 / SCALE
        }
    }

    /// Quantile `q` of the values, ns (see the module documentation for the definition).
    pub fn quantile(&self, q: f64) -> f64 {
        let n = self.total();
        self.at_rank(((q * n as f64).ceil() as u64).max(1))
    }

    /// Quantile `q` of |x|, ns.
    pub fn abs_quantile(&self, q: f64) -> f64 {
        let mut m = self.pos.clone();
        m.add(&self.neg);
        let n = m.total;
        if n == 0 {
            return f64::NAN;
        }
        m.at_rank(((q * n as f64).ceil() as u64).clamp(1, n)) as f64 / SCALE
    }

    /// The recorded values in ascending order as (value ns, count), one per bucket (the
    /// bucket's middle).
    pub fn bins(&self) -> Vec<(f64, u64)> {
        let mut v: Vec<(f64, u64)> = self
            .neg
            .recorded()
            .rev()
            .map(|(m, c)| (-(m as f64) / SCALE, c))
            .collect();
        v.extend(self.pos.recorded().map(|(m, c)| (m as f64 / SCALE, c)));
        v
    }
}

/// Count, mean, standard deviation, exact extremes, RMS and the distribution of one quantity.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    n: u64,
    /// The first sample: sums are of `x - shift`, so that a large mean does not cancel the
    /// variance away.
    shift: f64,
    s1: f64,
    s2: f64,
    min: f64,
    max: f64,
    /// The distribution of the values.
    pub dist: Dist,
}

impl Stats {
    /// No samples yet.
    pub fn new() -> Self {
        Stats {
            n: 0,
            shift: 0.0,
            s1: 0.0,
            s2: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            dist: Dist::new(),
        }
    }

    /// Adds a sample, ns (NaN is ignored).
    #[inline]
    pub fn add(&mut self, x: f64) {
        if x.is_nan() {
            return;
        }
        if self.n == 0 {
            self.shift = x;
        }
        self.n += 1;
        let d = x - self.shift;
        self.s1 += d;
        self.s2 += d * d;
        // Plain comparisons (NaN is excluded above).
        if x < self.min {
            self.min = x;
        }
        if x > self.max {
            self.max = x;
        }
        self.dist.add(x);
    }

    /// Adds another set of samples.
    pub fn merge(&mut self, o: &Stats) {
        if o.n == 0 {
            return;
        }
        if self.n == 0 {
            *self = o.clone();
            return;
        }
        // Re-centre o's sums on our shift: sum (x - a) = sum (x - b) + n (b - a).
        let k = o.shift - self.shift;
        let n = o.n as f64;
        self.s1 += o.s1 + n * k;
        self.s2 += o.s2 + 2.0 * k * o.s1 + n * k * k;
        self.n += o.n;
        self.min = self.min.min(o.min);
        self.max = self.max.max(o.max);
        self.dist.merge(&o.dist);
    }

    /// Samples so far.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// Quantile `q` of the values, clamped to the exact extremes, ns (NaN without samples).
    pub fn quantile(&self, q: f64) -> f64 {
        if self.n == 0 {
            return f64::NAN;
        }
        self.dist.quantile(q).clamp(self.min, self.max)
    }

    /// Quantile `q` of |x|, clamped to the largest |x|, ns (NaN without samples).
    pub fn abs_quantile(&self, q: f64) -> f64 {
        if self.n == 0 {
            return f64::NAN;
        }
        let max_abs = self.max.abs().max(self.min.abs());
        let lo = if self.min <= 0.0 && self.max >= 0.0 {
            0.0
        } else {
            self.min.abs().min(self.max.abs())
        };
        self.dist.abs_quantile(q).clamp(lo, max_abs)
    }

    /// The summary (all NaN but `n` when there are no samples).
    pub fn summary(&self) -> Summary {
        if self.n == 0 {
            return Summary::empty();
        }
        let n = self.n as f64;
        let m = self.s1 / n;
        let var = (self.s2 / n - m * m).max(0.0);
        let mean = self.shift + m;
        let max_abs = self.max.abs().max(self.min.abs());
        Summary {
            n: self.n,
            mean,
            std: var.sqrt(),
            rms: (var + mean * mean).sqrt(),
            min: self.min,
            max: self.max,
            max_abs,
            p001: self.quantile(0.001),
            p01: self.quantile(0.01),
            p50: self.quantile(0.5),
            p99: self.quantile(0.99),
            p999: self.quantile(0.999),
            p99_abs: self.abs_quantile(0.99),
            p999_abs: self.abs_quantile(0.999),
        }
    }
}

/// What is reported of one quantity, ns. Quantiles are of the signed values unless named
/// `_abs`; each lies within [`quantile_error_bound`] of the sample of its rank.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Summary {
    /// Samples.
    pub n: u64,
    /// Mean.
    pub mean: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// Root mean square: sqrt(mean of x^2) = sqrt(std^2 + mean^2).
    pub rms: f64,
    /// Smallest value (exact).
    pub min: f64,
    /// Largest value (exact).
    pub max: f64,
    /// Largest |x| (exact).
    pub max_abs: f64,
    /// 0.1th percentile.
    pub p001: f64,
    /// 1st percentile.
    pub p01: f64,
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// 99.9th percentile.
    pub p999: f64,
    /// 99th percentile of |x|.
    pub p99_abs: f64,
    /// 99.9th percentile of |x|.
    pub p999_abs: f64,
}

impl Default for Summary {
    fn default() -> Self {
        Summary::empty()
    }
}

impl Summary {
    /// No samples: every figure NaN (written as null in JSON).
    pub fn empty() -> Self {
        let x = f64::NAN;
        Summary {
            n: 0,
            mean: x,
            std: x,
            rms: x,
            min: x,
            max: x,
            max_abs: x,
            p001: x,
            p01: x,
            p50: x,
            p99: x,
            p999: x,
            p99_abs: x,
            p999_abs: x,
        }
    }
}

/// The mean of each statistic over runs (the letter's MMean, MStd, MMax, MMin); `n` is the sum
/// and `max_abs` the largest. Runs without samples are left out.
pub fn mean_of(summaries: &[Summary]) -> Summary {
    let some: Vec<&Summary> = summaries.iter().filter(|s| s.n > 0).collect();
    if some.is_empty() {
        return Summary::empty();
    }
    let k = some.len() as f64;
    let f = |g: fn(&Summary) -> f64| some.iter().map(|s| g(s)).sum::<f64>() / k;
    Summary {
        n: some.iter().map(|s| s.n).sum(),
        mean: f(|s| s.mean),
        std: f(|s| s.std),
        rms: f(|s| s.rms),
        min: f(|s| s.min),
        max: f(|s| s.max),
        max_abs: some.iter().map(|s| s.max_abs).fold(0.0, f64::max),
        p001: f(|s| s.p001),
        p01: f(|s| s.p01),
        p50: f(|s| s.p50),
        p99: f(|s| s.p99),
        p999: f(|s| s.p999),
        p99_abs: f(|s| s.p99_abs),
        p999_abs: f(|s| s.p999_abs),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The distribution as the `hdrhistogram` crate keeps it (3 significant digits): the
    /// reference the bucket layout is held to.
    struct Reference {
        pos: hdrhistogram::Histogram<u64>,
        neg: hdrhistogram::Histogram<u64>,
    }

    impl Reference {
        fn new() -> Self {
            Reference {
                pos: hdrhistogram::Histogram::new(3).unwrap(),
                neg: hdrhistogram::Histogram::new(3).unwrap(),
            }
        }
        fn add(&mut self, x: f64) {
            if x < 0.0 {
                self.neg.record(steps(-x)).unwrap();
            } else if x >= 0.0 {
                self.pos.record(steps(x)).unwrap();
            }
        }
        fn rank_of(h: &hdrhistogram::Histogram<u64>, r: u64) -> u64 {
            let mut acc = 0;
            for v in h.iter_recorded() {
                acc += v.count_at_value();
                if acc >= r {
                    return h.median_equivalent(v.value_iterated_to());
                }
            }
            h.max()
        }
        fn at_rank(&self, r: u64) -> f64 {
            let n_neg = self.neg.len();
            let r = r.clamp(1, n_neg + self.pos.len());
            if r <= n_neg {
                -(Self::rank_of(&self.neg, n_neg - r + 1) as f64) / SCALE
            } else {
                Self::rank_of(&self.pos, r - n_neg) as f64 / SCALE
            }
        }
        fn abs_at_rank(&self, r: u64) -> f64 {
            let mut m = self.pos.clone();
            m.add(&self.neg).unwrap();
            Self::rank_of(&m, r) as f64 / SCALE
        }
        fn bins(&self) -> Vec<(f64, u64)> {
            let mut v: Vec<(f64, u64)> = self
                .neg
                .iter_recorded()
                .map(|x| {
                    let m = self.neg.median_equivalent(x.value_iterated_to());
                    (-(m as f64) / SCALE, x.count_at_value())
                })
                .collect();
            v.reverse();
            v.extend(self.pos.iter_recorded().map(|x| {
                let m = self.pos.median_equivalent(x.value_iterated_to());
                (m as f64 / SCALE, x.count_at_value())
            }));
            v
        }
    }

    /// Every rank, |x| rank and bin reads as the crate's histograms read it, on values from
    /// zero to 10^15 ns of both signs, and after a merge.
    #[test]
    fn the_bucket_layout_is_the_hdr_crates() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for case in 0..40 {
            let n = [1usize, 2, 7, 100, 3000][case % 5];
            let (mut a, mut b, mut r) = (Dist::new(), Dist::new(), Reference::new());
            for i in 0..n {
                let mag = 10f64.powf(rng.random_range(-3.0..15.0));
                let x = match rng.random_range(0..10) {
                    0 => 0.0,
                    1 => (mag * 64.0).round() / 64.0,
                    2..=5 => -mag,
                    _ => mag,
                };
                if i % 2 == 0 {
                    a.add(x)
                } else {
                    b.add(x)
                }
                r.add(x);
            }
            a.merge(&b);
            assert_eq!(a.total(), n as u64);
            for k in 1..=n as u64 {
                assert_eq!(
                    a.at_rank(k).to_bits(),
                    r.at_rank(k).to_bits(),
                    "case {case} rank {k}"
                );
            }
            for k in [1, n as u64 / 2 + 1, n as u64] {
                let q = k as f64 / n as f64;
                assert_eq!(
                    a.abs_quantile(q).to_bits(),
                    r.abs_at_rank(k).to_bits(),
                    "case {case}"
                );
            }
            assert_eq!(a.bins(), r.bins(), "case {case}");
        }
    }

    /// The exact quantile by the module's definition.
    fn exact(sorted: &[f64], q: f64) -> f64 {
        let n = sorted.len();
        let r = ((q * n as f64).ceil() as usize).clamp(1, n);
        sorted[r - 1]
    }

    #[test]
    fn moments_and_quantiles_by_hand() {
        let mut s = Stats::new();
        for x in [1.0, 2.0, 3.0, 4.0, -10.0] {
            s.add(x);
        }
        let m = s.summary();
        assert_eq!(m.mean, 0.0);
        // Population variance: (1 + 4 + 9 + 16 + 100) / 5 = 26.
        assert!((m.std - 26f64.sqrt()).abs() < 1e-12);
        assert_eq!((m.min, m.max, m.max_abs), (-10.0, 4.0, 10.0));
        assert!((m.rms - 26f64.sqrt()).abs() < 1e-12);
        // Sorted: -10, 1, 2, 3, 4. p50: rank ceil(2.5) = 3 -> 2; p99: rank 5 -> 4; p001: -10.
        assert_eq!((m.p50, m.p99, m.p001), (2.0, 4.0, -10.0));
        // |x| sorted: 1, 2, 3, 4, 10: the 99th percentile of |x| is 10, the 50th 3.
        assert_eq!(m.p99_abs, 10.0);
        assert_eq!(s.abs_quantile(0.5), 3.0);
    }

    #[test]
    fn rms_is_not_the_standard_deviation() {
        // A constant offset: std 0, RMS the offset.
        let mut s = Stats::new();
        for _ in 0..1000 {
            s.add(27_000.0);
        }
        let m = s.summary();
        assert!(m.std.abs() < 1e-9, "{m:?}");
        assert!((m.rms - 27_000.0).abs() < 1e-9, "{m:?}");
    }

    #[test]
    fn no_ceiling() {
        // Values far beyond any fixed range are kept and read back within the bound.
        let mut s = Stats::new();
        for x in [807_000.0, 5.0e9, -3.0e12, 12.5] {
            s.add(x);
        }
        let m = s.summary();
        assert_eq!((m.min, m.max), (-3.0e12, 5.0e9));
        assert_eq!(m.p99, 5.0e9, "clamped to the exact maximum");
        let p50 = s.quantile(0.5);
        assert!((p50 - 12.5).abs() <= quantile_error_bound(12.5), "{p50}");
        let p75 = s.quantile(0.75);
        assert!(
            (p75 - 807_000.0).abs() <= quantile_error_bound(807_000.0),
            "{p75}"
        );
    }

    #[test]
    fn empty_is_nan() {
        let s = Stats::new();
        let m = s.summary();
        assert_eq!(m.n, 0);
        assert!(m.mean.is_nan() && m.p99.is_nan() && m.min.is_nan());
        assert!(s.quantile(0.5).is_nan() && s.abs_quantile(0.5).is_nan());
    }

    #[test]
    fn merging_equals_adding_all() {
        let mut a = Stats::new();
        let mut b = Stats::new();
        let mut all = Stats::new();
        for i in 0..5000 {
            let x = (i as f64 * 0.37).sin() * 1e5 + 3e6;
            if i % 3 == 0 {
                a.add(x);
            } else {
                b.add(x);
            }
            all.add(x);
        }
        a.merge(&b);
        let (m, n) = (a.summary(), all.summary());
        assert_eq!(m.n, n.n);
        assert!((m.mean - n.mean).abs() < 1e-6 && (m.std - n.std).abs() < 1e-6);
        assert_eq!((m.min, m.max, m.p99, m.p001), (n.min, n.max, n.p99, n.p001));
    }

    #[test]
    fn mean_over_runs() {
        let a = Summary {
            n: 1,
            mean: 1.0,
            std: 2.0,
            max: 3.0,
            min: -4.0,
            ..Summary::empty()
        };
        let b = Summary {
            n: 1,
            mean: 3.0,
            std: 4.0,
            max: 5.0,
            min: -6.0,
            ..Summary::empty()
        };
        let m = mean_of(&[a, b, Summary::empty()]);
        assert_eq!((m.mean, m.std, m.max, m.min, m.n), (2.0, 3.0, 4.0, -5.0, 2));
    }

    proptest! {
        /// Every quantile, signed and of |x|, within the stated bound of the exact one, over
        /// values spanning nine decades with both signs.
        #[test]
        fn quantiles_within_the_bound(
            xs in prop::collection::vec(
                (any::<bool>(), -3.0f64..9.0, 0.0f64..1.0).prop_map(|(neg, e, f)| {
                    let v = 10f64.powf(e) * (1.0 + f);
                    if neg { -v } else { v }
                }),
                1..400,
            ),
            q in 0.0f64..1.0,
        ) {
            let mut s = Stats::new();
            for &x in &xs {
                s.add(x);
            }
            let mut sorted = xs.clone();
            sorted.sort_by(f64::total_cmp);
            for q in [q, 0.001, 0.01, 0.5, 0.99, 0.999] {
                let e = exact(&sorted, q);
                let got = s.quantile(q);
                prop_assert!((got - e).abs() <= quantile_error_bound(e), "q {} exact {} got {}", q, e, got);
            }
            let mut mags: Vec<f64> = xs.iter().map(|x| x.abs()).collect();
            mags.sort_by(f64::total_cmp);
            let e = exact(&mags, q);
            let got = s.abs_quantile(q);
            prop_assert!((got - e).abs() <= quantile_error_bound(e), "|x| q {} exact {} got {}", q, e, got);
        }
    }
}
