//! Angles of 2D directions as keys for sorted searches: exact (the library's `atan2`), and a
//! polynomial approximation a few times cheaper, with a stated error bound, for searches whose
//! candidates then face an exact test. Shared by the matcher's windows and the crowding index.

use nalgebra::Vector2;

/// The angle key of a direction: `[0, 2π)` for oriented segments, `[0, π)` otherwise.
pub fn angle_key(dir: Vector2<f64>, period: f64) -> f64 {
    let a = dir.y.atan2(dir.x).rem_euclid(period);
    if a >= period {
        0.0
    } else {
        a
    }
}

/// Largest difference between [`approx_angle_key`] and [`angle_key`], radians: the
/// polynomial's own 2.5e-7 with room for rounding (checked by a test over a million
/// directions).
pub const APPROX_ANGLE_KEY_ERROR: f64 = 1e-6;

/// An odd polynomial for atan on [0, 1] (least squares on Chebyshev nodes, reweighted towards
/// equal ripple): x·(c0 + c1·x² + … + c6·x¹²).
const ATAN_COEFFICIENTS: [f64; 7] = [
    0.999_996_111_678_082_6,
    -0.333_173_681_833_257_9,
    0.198_078_156_710_546_93,
    -0.132_333_404_957_817_3,
    0.079_623_623_024_114_38,
    -0.033_604_167_651_806_61,
    0.006_811_773_805_806_595,
];

/// `atan x` within [`APPROX_ANGLE_KEY_ERROR`] for x ≥ 0 (odd for x < 0): the polynomial on
/// [0, 1], and π/2 − atan(1/x) beyond. NaN stays NaN.
#[inline]
pub fn approx_atan(x: f64) -> f64 {
    let t = x.abs();
    let a = if t <= 1.0 {
        atan_on_unit(t)
    } else {
        std::f64::consts::FRAC_PI_2 - atan_on_unit(1.0 / t)
    };
    a.copysign(x)
}

/// The polynomial for atan on [0, 1].
#[inline]
fn atan_on_unit(t: f64) -> f64 {
    let t2 = t * t;
    t * ATAN_COEFFICIENTS
        .iter()
        .rev()
        .fold(0.0, |acc, &c| acc * t2 + c)
}

/// [`angle_key`] within [`APPROX_ANGLE_KEY_ERROR`], at a fraction of the library `atan2`'s
/// cost: the direction is folded into the first octant and its atan taken by a polynomial.
/// For a window search whose candidates then face an exact test: widen its tolerance by the
/// error bound and nothing it would have found is missed.
#[inline]
pub fn approx_angle_key(dir: Vector2<f64>, period: f64) -> f64 {
    let (ax, ay) = (dir.x.abs(), dir.y.abs());
    let steep = ay > ax;
    let (num, den) = if steep { (ax, ay) } else { (ay, ax) };
    if den.is_nan() || den <= 0.0 {
        return 0.0;
    }
    let mut a = atan_on_unit(num / den);
    if steep {
        a = std::f64::consts::FRAC_PI_2 - a;
    }
    if dir.x < 0.0 {
        a = std::f64::consts::PI - a;
    }
    if dir.y < 0.0 {
        a = -a;
    }
    let a = a.rem_euclid(period);
    if a >= period {
        0.0
    } else {
        a
    }
}

/// Signed difference of two angle keys, folded into `(-period/2, period/2]`.
pub fn angle_diff(a: f64, b: f64, period: f64) -> f64 {
    let d = (a - b).rem_euclid(period);
    if d > period / 2.0 {
        d - period
    } else {
        d
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::f64::consts::PI;

    #[test]
    fn the_approximate_angle_key_stays_within_its_bound() {
        // Every direction of a fine fan, both periods, the axes and the octant borders
        // exactly, and lengths far from one.
        let mut worst: f64 = 0.0;
        for period in [PI, 2.0 * PI] {
            let n = 1_000_000;
            let special = [
                0.0,
                PI / 4.0,
                PI / 2.0,
                3.0 * PI / 4.0,
                PI,
                -PI / 2.0,
                -PI / 4.0,
            ];
            let angles = (0..n)
                .map(|k| -PI + 2.0 * PI * k as f64 / n as f64)
                .chain(special);
            for theta in angles {
                for scale in [1e-6, 1.0, 3e4] {
                    let dir = Vector2::new(theta.cos(), theta.sin()) * scale;
                    let d = angle_diff(
                        approx_angle_key(dir, period),
                        angle_key(dir, period),
                        period,
                    );
                    worst = worst.max(d.abs());
                    let key = approx_angle_key(dir, period);
                    assert!((0.0..period).contains(&key), "{theta} {key}");
                }
            }
        }
        assert!(worst <= APPROX_ANGLE_KEY_ERROR, "{worst}");
        // The atan alone, over the widths a prediction's slack can give it.
        let atan_worst = (0..200_000)
            .map(|k| 10f64.powf(-6.0 + 12.0 * k as f64 / 200_000.0))
            .flat_map(|x| [x, -x])
            .map(|x| (approx_atan(x) - x.atan()).abs())
            .fold(0.0, f64::max);
        assert!(atan_worst <= APPROX_ANGLE_KEY_ERROR, "{atan_worst}");
        assert!(worst > 0.0, "the polynomial cannot be exact");
        assert_eq!(approx_angle_key(Vector2::zeros(), 2.0 * PI), 0.0);
    }
}
