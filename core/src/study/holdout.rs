//! Measuring a response surface where it was not fitted: held-out points, random in a study's
//! box and never its design's, whose solved values are compared with what the surface predicted
//! there before they were solved (docs/surrogate.md, "Surface audit").
//!
//! One measure for the coordinator's audit and the benchmarks: per QoI, the largest and mean
//! |predicted - solved| relative to the QoI's spread, and the share of points within 2 standard
//! deviations (the error bars' calibration).

use super::surrogate::Prediction;

/// Closest a held-out point may be to a design point, in units of the box's sides (largest
/// coordinate difference): at a design point the surface interpolates and the error measures
/// nothing.
pub const MIN_DISTANCE: f64 = 1e-3;
/// Draws per held-out point before one is accepted whatever its distance (a box the design fills).
const TRIES: usize = 64;

/// At most `n` points drawn uniformly in the box `ranges` ((low, high) per coordinate; a
/// zero-width range gives its value), each farther than [`MIN_DISTANCE`] from every point of
/// `design` (same coordinates; fewer points where the design fills the box), from a generator
/// seeded by `seed`: the same arguments give the same points.
pub fn held_out_points(ranges: &[(f64, f64)], design: &[Vec<f64>], n: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut state = seed ^ 0x6a09_e667_f3bc_c909;
    let mut uniform = || {
        // splitmix64, its top 53 bits as a number in [0, 1)
        state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = state;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        (z ^ (z >> 31)) as f64 / 2f64.powi(64)
    };
    let near = |x: &[f64]| {
        design.iter().any(|d| {
            d.iter().zip(x).zip(ranges).all(|((a, b), (lo, hi))| {
                let side = hi - lo;
                side <= 0.0 || (a - b).abs() <= MIN_DISTANCE * side
            })
        })
    };
    (0..n)
        .filter_map(|_| {
            (0..TRIES).find_map(|_| {
                let x: Vec<f64> = ranges.iter().map(|(lo, hi)| lo + uniform() * (hi - lo)).collect();
                (!near(&x)).then_some(x)
            })
        })
        .collect()
}

/// A QoI's spread over the values known of it (largest - smallest): the scale of a surface's
/// errors. A QoI without spread falls back to its largest |value|, then to 1.
pub fn spread(values: impl IntoIterator<Item = f64>) -> f64 {
    let (lo, hi) = values.into_iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(v), h.max(v)));
    let largest = lo.abs().max(hi.abs());
    if hi > lo {
        hi - lo
    } else if largest > 0.0 && largest.is_finite() {
        largest
    } else {
        1.0
    }
}

/// What the held-out points measured of one QoI's surface.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SurfaceErrors {
    /// largest |predicted mean - solved value| / spread
    pub largest: f64,
    /// mean of the same
    pub mean: f64,
    /// share of the points whose error is within 2 predicted standard deviations
    pub within_2sd: f64,
    /// points compared
    pub count: usize,
    /// the largest error anywhere in the box as the surface estimates it (an adaptive study's
    /// cross-validation: core::study::adaptive::Surfaces::cross_validate), what its target is
    /// judged on; None where only points are compared
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub box_largest: Option<f64>,
}

/// The errors of `pairs` (the surface's prediction, the solved value) relative to `spread`.
pub fn surface_errors(pairs: &[(Prediction, f64)], spread: f64) -> SurfaceErrors {
    let count = pairs.len();
    let errors: Vec<f64> = pairs.iter().map(|(p, v)| (p.mean - v).abs()).collect();
    let within = pairs.iter().zip(&errors).filter(|((p, _), e)| **e <= 2.0 * p.std).count();
    let n = count.max(1) as f64;
    SurfaceErrors {
        largest: errors.iter().fold(0.0f64, |m, e| m.max(*e)) / spread,
        mean: errors.iter().sum::<f64>() / n / spread,
        within_2sd: within as f64 / n,
        count,
        box_largest: None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn held_out_points_are_in_the_box_away_from_the_design_and_repeatable() {
        let ranges = [(0.1, 0.2), (2e7, 1e8), (0.3, 0.3)];
        let design: Vec<Vec<f64>> = (0..11)
            .flat_map(|i| (0..11).map(move |j| vec![0.1 + 0.01 * i as f64, 2e7 + 8e6 * j as f64, 0.3]))
            .collect();
        let points = held_out_points(&ranges, &design, 50, 7);
        assert_eq!(points.len(), 50);
        for p in &points {
            assert!((0.1..=0.2).contains(&p[0]) && (2e7..=1e8).contains(&p[1]) && p[2] == 0.3, "{p:?}");
            let nearest = design
                .iter()
                .map(|d| ((d[0] - p[0]).abs() / 0.1).max((d[1] - p[1]).abs() / 8e7))
                .fold(f64::INFINITY, f64::min);
            assert!(nearest > MIN_DISTANCE, "{p:?} at {nearest} of a design point");
        }
        assert_eq!(points, held_out_points(&ranges, &design, 50, 7), "a seed gives its points");
        assert_ne!(points, held_out_points(&ranges, &design, 50, 8));
        // a design that fills its box (one point, no width) leaves no point to hold out
        assert!(held_out_points(&[(0.1, 0.1)], &[vec![0.1]], 3, 7).is_empty());
        // uniform: each half of each side holds about half of them
        let low = points.iter().filter(|p| p[0] < 0.15).count();
        assert!((15..=35).contains(&low), "{low} of 50 below the middle");
    }

    #[test]
    fn errors_are_relative_to_the_spread_and_count_the_calibrated_points() {
        assert_eq!(spread([1.0, 3.0, 2.0]), 2.0);
        assert_eq!(spread([0.0, 0.0]), 1.0);
        assert_eq!(spread([-4.0, -4.0]), 4.0);
        let at = |mean: f64, std: f64| Prediction { mean, std };
        let e = surface_errors(&[(at(1.0, 0.1), 1.1), (at(2.0, 0.1), 2.5), (at(0.0, 0.0), 0.0)], 2.0);
        assert!((e.largest - 0.25).abs() < 1e-12 && (e.mean - 0.6 / 3.0 / 2.0).abs() < 1e-12, "{e:?}");
        // within 2 sd: the first (0.1 <= 0.2) and the exact third, not the second (0.5 > 0.2)
        assert!((e.within_2sd - 2.0 / 3.0).abs() < 1e-12 && e.count == 3, "{e:?}");
    }
}
