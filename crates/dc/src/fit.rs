//! The one least-squares line of the project: `y = a + b x` fitted online, point by point, with
//! Welford's updates (running means and co-moments), so that no large sums of squares of
//! nanosecond timestamps cancel. Used by the `median-fit` method's initialisation, the bring-up's
//! crystal rates, the lab's drift of the init frames and `ecsync run`'s reference crystal.
//!
//! ```
//! use ecsync_dc::fit::LineFit;
//!
//! // y = 3 + 0.5 x, exactly.
//! let fit = LineFit::of((0..10).map(|x| (f64::from(x), 3.0 + 0.5 * f64::from(x))));
//! assert_eq!(fit.line(), (3.0, 0.5));
//! assert_eq!(fit.slope(), Some(0.5));
//! // One point has no slope.
//! assert_eq!(LineFit::of([(1.0, 2.0)]).slope(), None);
//! ```

/// An online least-squares line `y = a + b x` (Welford's updates: no large sums cancel).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LineFit {
    n: f64,
    mean_x: f64,
    mean_y: f64,
    /// Sum of squared deviations of x from its running mean.
    cxx: f64,
    /// Sum of co-deviations of x and y.
    cxy: f64,
}

impl LineFit {
    /// No points yet.
    pub const fn new() -> Self {
        LineFit {
            n: 0.0,
            mean_x: 0.0,
            mean_y: 0.0,
            cxx: 0.0,
            cxy: 0.0,
        }
    }

    /// The fit of `points`, `(x, y)` each.
    pub fn of(points: impl IntoIterator<Item = (f64, f64)>) -> Self {
        let mut fit = LineFit::new();
        for (x, y) in points {
            fit.add(x, y);
        }
        fit
    }

    /// Adds the point `(x, y)`.
    #[inline]
    pub fn add(&mut self, x: f64, y: f64) {
        self.n += 1.0;
        let dx = x - self.mean_x;
        self.mean_x += dx / self.n;
        self.mean_y += (y - self.mean_y) / self.n;
        self.cxx += dx * (x - self.mean_x);
        self.cxy += dx * (y - self.mean_y);
    }

    /// Points added.
    pub fn len(&self) -> u64 {
        self.n as u64
    }

    /// Whether no point was added.
    pub fn is_empty(&self) -> bool {
        self.n == 0.0
    }

    /// The mean of the points' x.
    pub fn mean_x(&self) -> f64 {
        self.mean_x
    }

    /// The mean of the points' y.
    pub fn mean_y(&self) -> f64 {
        self.mean_y
    }

    /// The slope `b`; `None` with fewer than two distinct x.
    pub fn slope(&self) -> Option<f64> {
        (self.cxx > 0.0).then(|| self.cxy / self.cxx)
    }

    /// `(a, b)`; with fewer than two distinct x the slope is 0 (the line through the mean).
    pub fn line(&self) -> (f64, f64) {
        let b = self.slope().unwrap_or(0.0);
        (self.mean_y - b * self.mean_x, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against the textbook two-pass formula on points a crystal and jitter would give: large
    /// x and y (nanosecond timestamps), a slope 1 + 37 ppm. (The exact slope of these points
    /// is the two-pass figure to the last bit; the running means round at every step, within
    /// 1e-4 ppm of it.)
    #[test]
    fn agrees_with_the_two_pass_formula() {
        let pts: [(f64, f64); 7] = core::array::from_fn(|k| {
            let x = 1.7e12 + k as f64 * 1e6;
            let jitter = [3.0, -1.0, 4.0, -1.0, 5.0, -9.0, 2.0][k];
            (x, 5e11 + (x - 1.7e12) * (1.0 + 37e-6) + jitter)
        });
        let n = pts.len() as f64;
        let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
        let sxx: f64 = pts.iter().map(|p| (p.0 - mx) * (p.0 - mx)).sum();
        let fit = LineFit::of(pts);
        let b = fit.slope().unwrap();
        assert!((b - sxy / sxx).abs() < 1e-10, "{b} vs {}", sxy / sxx);
        assert!((fit.mean_y() - my).abs() < 1e-3);
        assert_eq!(fit.len(), 7);
    }

    #[test]
    fn no_slope_without_two_distinct_x() {
        assert_eq!(LineFit::new().slope(), None);
        assert!(LineFit::new().is_empty());
        assert_eq!(LineFit::of([(2.0, 1.0), (2.0, 5.0)]).slope(), None);
        assert_eq!(LineFit::of([(2.0, 1.0), (2.0, 5.0)]).line(), (3.0, 0.0));
    }
}
