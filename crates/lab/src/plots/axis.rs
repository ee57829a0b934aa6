//! What the plots' axes cover, what they count into which bin, the colours and the type sizes:
//! decisions a reader has to be able to trust, kept apart from the drawing so that they are
//! tested on their own.

use crate::stats::Dist;
use plotters::style::RGBColor;

/// The methods' colours, by their position in the report's order: no two alike, none red,
/// black or grey (those are the markers'). Matplotlib's tab10 without its red and grey, then
/// five more far from them; a comparison with more entries than colours (methods with several
/// send modes) draws the later ones dashed (see [`dashed_series`]).
pub(crate) const COLORS: [RGBColor; 13] = [
    RGBColor(0x1f, 0x77, 0xb4), // blue
    RGBColor(0x17, 0xbe, 0xcf), // cyan
    RGBColor(0x2c, 0xa0, 0x2c), // green
    RGBColor(0xff, 0x7f, 0x0e), // orange
    RGBColor(0x8c, 0x56, 0x4b), // brown
    RGBColor(0xe3, 0x77, 0xc2), // pink
    RGBColor(0xbc, 0xbd, 0x22), // olive
    RGBColor(0x94, 0x67, 0xbd), // purple
    RGBColor(0x00, 0x00, 0x80), // navy
    RGBColor(0x00, 0x8f, 0x6f), // teal
    RGBColor(0xff, 0xc8, 0x00), // amber
    RGBColor(0x7f, 0x9f, 0xff), // light blue
    RGBColor(0xa0, 0x00, 0xa0), // magenta
];

/// The colour of the method at `i` in the report's order.
pub(crate) fn series_color(i: usize) -> RGBColor {
    COLORS[i % COLORS.len()]
}

/// Whether the method at `i` is drawn dashed: past the palette, where its colour repeats one
/// drawn solid.
pub(crate) fn dashed_series(i: usize) -> bool {
    i >= COLORS.len()
}

/// The markers' colours (always drawn dashed): the target and SYNC0/the late line. No method
/// has either.
pub(crate) const TARGET_BLACK: RGBColor = RGBColor(0x00, 0x00, 0x00);
pub(crate) const LATE_RED: RGBColor = RGBColor(0xd0, 0x00, 0x00);
/// Every marker colour, for the test that no method shares one.
#[cfg(test)]
const MARKER_COLORS: [RGBColor; 2] = [TARGET_BLACK, LATE_RED];

/// Type sizes as plotters takes them: it draws a size `s` at an em of `s / 1.24` px (SVG and
/// bitmap alike), and the figures are shown at their own width in report.html, so a tick
/// label of 18 is 14.5 px on screen.
pub(crate) const TICK: u32 = 18;
pub(crate) const TITLE: u32 = 22;
pub(crate) const PANEL_TITLE: u32 = 19;
pub(crate) const LEGEND: u32 = 19;

/// A horizontal or vertical line of a plot: where (ns), its label, its colour.
pub(crate) struct Mark {
    pub at_ns: f64,
    pub label: String,
    pub color: RGBColor,
}

/// The axis over data from `min` to `max` (ns): all of it, with 5 % to spare on each side (at
/// least 1 ns) so that no value sits on the frame. A magnitude's axis starts at 0 (it cannot be
/// below, and 0 is its reference). No data: an empty axis around 0.
pub(crate) fn cover(min: f64, max: f64, magnitude: bool) -> (f64, f64) {
    if !(min.is_finite() && max.is_finite()) || min > max {
        return if magnitude { (0.0, 1.0) } else { (-1.0, 1.0) };
    }
    let pad = ((max - min) * 0.05).max(1.0);
    let lo = if magnitude && min >= 0.0 {
        0.0
    } else {
        min - pad
    };
    (lo, max + pad)
}

/// The values a distribution's histogram counts: its smallest and largest recorded value (the
/// middles of its HDR buckets, which is what [`rebin`] places). `None` when empty.
pub(crate) fn support(h: &Dist) -> Option<(f64, f64)> {
    let b = h.bins();
    Some((b.first()?.0, b.last()?.0))
}

/// The axis of several distributions' histograms: every one's full support.
pub(crate) fn cover_dists<'a>(
    dists: impl IntoIterator<Item = &'a Dist>,
    magnitude: bool,
) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for (a, b) in dists.into_iter().filter_map(support) {
        lo = lo.min(a);
        hi = hi.max(b);
    }
    cover(lo, hi, magnitude)
}

/// Widens `(lo, hi)` to a marker that is near the data (within twice the axis's width), so that
/// it is drawn where it is; one farther off stays outside and is named at the edge instead
/// (the data's own scale matters more than the distance to a far deadline).
pub(crate) fn with_marks(lo: f64, hi: f64, marks: &[Mark]) -> (f64, f64) {
    let width = hi - lo;
    let (mut lo, mut hi) = (lo, hi);
    for mk in marks {
        if mk.at_ns > hi && mk.at_ns - hi < 2.0 * width {
            hi = mk.at_ns + 0.05 * width;
        }
        if mk.at_ns < lo && lo - mk.at_ns < 2.0 * width {
            lo = mk.at_ns - 0.05 * width;
        }
    }
    (lo, hi)
}

/// `bins` counts of `h` over `[lo, hi)`. A value outside is left out, never added to an end
/// bin (that would draw a spike where there is no data); with an axis from [`cover`] of the
/// support there is none.
pub(crate) fn rebin(h: &Dist, lo: f64, hi: f64, bins: usize) -> Vec<u64> {
    let width = (hi - lo) / bins as f64;
    let mut out = vec![0u64; bins];
    for (x, c) in h.bins() {
        let k = ((x - lo) / width).floor();
        if k >= 0.0 && k < bins as f64 {
            out[k as usize] += c;
        }
    }
    out
}

/// Viridis at ten evenly spaced steps (matplotlib's `viridis(linspace(0, 1, 10))`): the heat
/// maps' colour scale. Perceptually uniform and readable in grey and by the colour-blind, and
/// none of its colours is the grey a heat map draws a point that is not good in.
const VIRIDIS: [RGBColor; 10] = [
    RGBColor(0x44, 0x01, 0x54),
    RGBColor(0x48, 0x28, 0x78),
    RGBColor(0x3e, 0x49, 0x89),
    RGBColor(0x31, 0x68, 0x8e),
    RGBColor(0x26, 0x82, 0x8e),
    RGBColor(0x1f, 0x9e, 0x89),
    RGBColor(0x35, 0xb7, 0x79),
    RGBColor(0x6e, 0xce, 0x58),
    RGBColor(0xb5, 0xde, 0x2b),
    RGBColor(0xfd, 0xe7, 0x25),
];

/// The colour of `t` on the heat maps' scale (0: dark purple, 1: yellow), interpolated
/// between [`VIRIDIS`]'s steps; `t` outside 0..1 takes the end's colour, so a colour always
/// matches the colour bar.
pub(crate) fn viridis(t: f64) -> RGBColor {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let x = t * (VIRIDIS.len() - 1) as f64;
    let k = (x.floor() as usize).min(VIRIDIS.len() - 2);
    let f = x - k as f64;
    let (a, b) = (VIRIDIS[k], VIRIDIS[k + 1]);
    let mix = |p: u8, q: u8| (f64::from(p) + (f64::from(q) - f64::from(p)) * f).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// Whether text on `bg` is drawn white (on a dark colour) rather than black: by the colour's
/// relative luminance (Rec. 709 weights), so a cell's value stays readable on any colour.
pub(crate) fn white_text_on(bg: RGBColor) -> bool {
    let y = 0.2126 * f64::from(bg.0) + 0.7152 * f64::from(bg.1) + 0.0722 * f64::from(bg.2);
    y < 128.0
}

/// Hatching of the box from `a` to `b` (px, y down): lines `step` px apart rising to the
/// right, each from edge to edge, none outside the box (a hatch that spilled would paint the
/// next cell).
pub(crate) fn hatch(a: (i32, i32), b: (i32, i32), step: i32) -> Vec<((i32, i32), (i32, i32))> {
    let (x0, x1) = (a.0.min(b.0), a.0.max(b.0));
    let (y0, y1) = (a.1.min(b.1), a.1.max(b.1));
    let mut out = Vec::new();
    let mut c = x0 + y0 + step.max(1);
    while c < x1 + y1 {
        // The line x + y = c within the box: y from the larger of y0 and c - x1 to the
        // smaller of y1 and c - x0.
        let (lo, hi) = ((c - x1).max(y0), (c - x0).min(y1));
        if lo < hi {
            out.push(((c - lo, lo), (c - hi, hi)));
        }
        c += step.max(1);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A body of 10 000 values in 0..100 ns and three far outliers at 12 000 ns: the shape
    /// that clipped before (the axis held all but 0.05 % of each tail and piled the rest on
    /// the last bin).
    fn body_and_outliers() -> Dist {
        let mut d = Dist::new();
        for k in 0..10_000 {
            d.add(f64::from(k % 100));
        }
        for _ in 0..3 {
            d.add(12_000.0);
        }
        d
    }

    #[test]
    fn the_axis_holds_every_value_and_the_edge_bins_are_empty() {
        let d = body_and_outliers();
        let (lo, hi) = cover_dists([&d], false);
        assert!(lo < 0.0 && hi > 12_000.0, "axis {lo}..{hi}");
        let bins = rebin(&d, lo, hi, 160);
        assert_eq!(
            bins.iter().sum::<u64>(),
            d.total(),
            "every value counted once"
        );
        assert_eq!(bins[0], 0, "nothing piled on the first bin");
        assert_eq!(bins[159], 0, "nothing piled on the last bin");
        // The outliers are in the bin of 12 000 ns, not at an edge.
        let width = (hi - lo) / 160.0;
        let k = ((12_000.0 - lo) / width).floor() as usize;
        assert!(k < 159);
        assert_eq!(bins[k], 3);
    }

    #[test]
    fn out_of_range_values_are_left_out_not_piled_on_the_edges() {
        let d = body_and_outliers();
        // The old clip's range: the outliers are beyond it.
        let bins = rebin(&d, 0.0, 110.0, 110);
        assert_eq!(bins.iter().sum::<u64>(), 10_000);
        assert_eq!(bins[109], 0, "the 12 us outliers are not in the last bin");
    }

    #[test]
    fn a_magnitude_axis_starts_at_zero() {
        let mut d = Dist::new();
        for v in [500.0, 800.0, 12_000.0] {
            d.add(v);
        }
        let (lo, hi) = cover_dists([&d], true);
        assert_eq!(lo, 0.0);
        assert!(hi > 12_000.0);
        assert_eq!(cover(0.0, 0.0, true), (0.0, 1.0));
        // A signed quantity keeps its margin below.
        assert_eq!(cover(5_000.0, 6_000.0, false), (4_950.0, 6_050.0));
        // No data: an empty axis.
        assert_eq!(cover_dists([&Dist::new()], true), (0.0, 1.0));
    }

    #[test]
    fn several_distributions_share_one_axis_over_all_of_them() {
        let mut a = Dist::new();
        let mut b = Dist::new();
        a.add(-3_000.0);
        a.add(10.0);
        b.add(122_000.0);
        let (lo, hi) = cover_dists([&a, &b], false);
        assert!(lo < -3_000.0 && hi > 122_000.0, "{lo}..{hi}");
    }

    #[test]
    fn a_near_marker_widens_the_axis_a_far_one_does_not() {
        let near = Mark {
            at_ns: 150.0,
            label: "late".into(),
            color: LATE_RED,
        };
        assert_eq!(with_marks(0.0, 100.0, &[near]), (0.0, 155.0));
        let far = Mark {
            at_ns: 1_000.0,
            label: "late".into(),
            color: LATE_RED,
        };
        assert_eq!(with_marks(0.0, 100.0, &[far]), (0.0, 100.0));
    }

    /// Euclidean distance in RGB: a crude but sufficient test of "looks different" (tab10's
    /// closest pair, blue and cyan, are 76 apart).
    fn distance(a: RGBColor, b: RGBColor) -> f64 {
        let d = |x: u8, y: u8| f64::from(x) - f64::from(y);
        (d(a.0, b.0).powi(2) + d(a.1, b.1).powi(2) + d(a.2, b.2).powi(2)).sqrt()
    }

    #[test]
    fn method_colours_are_pairwise_distinct_and_none_is_a_marker_colour() {
        assert!(COLORS.len() >= ecsync_dc::registry::METHOD_COUNT);
        for (i, &a) in COLORS.iter().enumerate() {
            for &b in &COLORS[i + 1..] {
                assert!(distance(a, b) >= 60.0, "{a:?} and {b:?} look alike");
            }
            for &m in &MARKER_COLORS {
                assert!(
                    distance(a, m) >= 100.0,
                    "{a:?} is too close to marker {m:?}"
                );
            }
            // No grey: a method never looks like a neutral line.
            let (r, g, b) = (i32::from(a.0), i32::from(a.1), i32::from(a.2));
            assert!(
                (r - g).abs().max((g - b).abs()).max((r - b).abs()) >= 60,
                "{a:?} is grey"
            );
        }
        // Every method of a plain comparison is solid and has its own colour.
        for i in 0..ecsync_dc::registry::METHOD_COUNT {
            assert!(!dashed_series(i));
            for j in 0..i {
                assert_ne!(series_color(i), series_color(j));
            }
        }
    }

    #[test]
    fn panels_get_their_own_axis_when_ranges_differ_tenfold() {
        use crate::plots::draw::ranges_differ_tenfold;
        // rS-IS on the letter's testbed: 0..40 ns (MII stamps) beside bus shift's 0..12 000.
        assert!(ranges_differ_tenfold(&[
            (0.0, 40.0),
            (0.0, 12_000.0),
            (0.0, 90.0)
        ]));
        // M-rS: spreads within a factor of four share one axis.
        assert!(!ranges_differ_tenfold(&[
            (-20.0, 10.0),
            (-30.0, 40.0),
            (-12.0, 3.0)
        ]));
        // A flat series (no span) is no reason to split.
        assert!(!ranges_differ_tenfold(&[(5.0, 5.0), (0.0, 1000.0)]));
    }

    #[test]
    fn the_heat_scale_runs_from_viridis_start_to_end_and_clamps() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(1.0), VIRIDIS[9]);
        assert_eq!(viridis(-3.0), VIRIDIS[0]);
        assert_eq!(viridis(7.0), VIRIDIS[9]);
        assert_eq!(viridis(f64::NAN), VIRIDIS[0]);
        // Half way between two steps: the mean of the two.
        let m = viridis(0.5 / 9.0);
        assert_eq!(m, RGBColor(0x46, 0x15, 0x66));
        assert!(white_text_on(viridis(0.0)) && !white_text_on(viridis(1.0)));
    }

    #[test]
    fn hatching_stays_inside_its_box() {
        let lines = hatch((10, 20), (40, 38), 6);
        assert!(lines.len() >= 7, "{lines:?}");
        for (p, q) in &lines {
            for (x, y) in [p, q] {
                assert!((10..=40).contains(x) && (20..=38).contains(y), "{lines:?}");
            }
            // Each rises to the right at 45 degrees.
            assert_eq!(q.0 - p.0, p.1 - q.1);
        }
        assert!(hatch((0, 0), (0, 0), 6).is_empty());
    }
}
