//! The views' gradient gains, and the gradient test of the triplets whose depth one view
//! fixes.
//!
//! A triplet whose verifying view cannot check its depth (`Hypothesis::depth_blind`: its view-1
//! segment runs along that pair's epipolar lines) is confirmed in that view at any depth; a
//! ghost — two views on one edge, the searched view on another — has only photometry against
//! it, so its three gradients must agree within `MatchParams::depth_blind_gradient_ratio_max`
//! (docs/RIGS.md). Cameras with their own exposure see one edge at gradients in the ratio of
//! their gains, which would refuse every such triplet of a rig whose gains differ by that much
//! (the facing triangle with its third camera at 0.6 of the others' gain: 52.9% → 22.8%
//! complete, 3.7% → 14.5% wrong); so the test compares gradients divided by each view's gain,
//! the median ratio to view 1 over every hypothesis whose three gradients are known (the
//! wrong ones among them are a minority and agree about as well; the rendered rooms and the
//! real photographs we have: within 1% of 1). Measured on the depth-checked hypotheses alone,
//! an L-shaped rig — its lines nearly all along one baseline or the other — had too few.

use super::{gradients_compatible, Hypothesis, Views};

/// Fewest hypotheses of known gradients that measure the gains; with fewer, each view's
/// gain is taken as 1.
pub const MIN_GAIN_SAMPLES: usize = 32;

/// Each view's gradient gain relative to view 1 (`[1, g2, g3]`): the median ratio over the
/// hypotheses whose three gradients are known.
pub fn view_gains(views: &Views, hypotheses: &[Hypothesis]) -> [f64; 3] {
    let mut logs: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    for h in hypotheses {
        let g = gradients(views, h);
        if g.iter().all(|&x| x > 0.0 && x.is_finite()) {
            logs[0].push(log_ratio(g[1], g[0]));
            logs[1].push(log_ratio(g[2], g[0]));
        }
    }
    if logs[0].len() < MIN_GAIN_SAMPLES {
        return [1.0; 3];
    }
    let [l2, l3] = logs.map(|mut l| median(&mut l).exp());
    // A list may give gradients so far apart that their gain is past f64: no gain is known.
    if !(l2.is_normal() && l3.is_normal()) {
        return [1.0; 3];
    }
    [1.0, l2, l3]
}

/// Drops the depth-blind triplets whose three gradients, each divided by its view's gain,
/// are not within `ratio_max` of each other. Returns the gains and how many were dropped.
pub fn refuse_depth_blind(
    views: &Views,
    hypotheses: &mut Vec<Hypothesis>,
    ratio_max: f64,
) -> ([f64; 3], u32) {
    let gains = view_gains(views, hypotheses);
    let before = hypotheses.len();
    hypotheses.retain(|h| {
        if !h.depth_blind {
            return true;
        }
        let g = gradients(views, h);
        let [a, b, c] = [g[0] / gains[0], g[1] / gains[1], g[2] / gains[2]];
        gradients_compatible(a, b, ratio_max)
            && gradients_compatible(a, c, ratio_max)
            && gradients_compatible(b, c, ratio_max)
    });
    (gains, (before - hypotheses.len()) as u32)
}

/// ln(a / b) of two positive finite numbers, finite even where a / b is not.
fn log_ratio(a: f64, b: f64) -> f64 {
    let r = a / b;
    if r.is_normal() {
        r.ln()
    } else {
        a.ln() - b.ln()
    }
}

fn gradients(views: &Views, h: &Hypothesis) -> [f64; 3] {
    std::array::from_fn(|v| views.segments[v][h.segments[v] as usize].gradient)
}

fn median(values: &mut [f64]) -> f64 {
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::matching::RectSegment;
    use nalgebra::Point2;

    fn segment(gradient: f64, index: u32) -> RectSegment {
        let y = f64::from(index);
        RectSegment::new(Point2::new(0.0, y), Point2::new(10.0, y), gradient, index)
    }

    fn hypothesis(i: u32, depth_blind: bool) -> Hypothesis {
        Hypothesis {
            segments: [i, i, i],
            residual_px: 0.1,
            s1_span: (0.0, 10.0),
            disparity: (1.0, 1.0),
            frame: 0,
            depth_blind,
        }
    }

    #[test]
    fn gains_are_measured_on_checked_triplets_and_divide_out_of_the_blind_ones() {
        // View 2 at 1.8 times view 1's gain, view 3 at 0.7 times; every edge seen alike
        // otherwise, with a spread of ±10% per view.
        let n = 64u32;
        let spread = |i: u32, v: u32| 1.0 + 0.1 * (f64::from((i * 7 + v * 3) % 5) / 2.0 - 1.0);
        let lists: [Vec<RectSegment>; 3] = std::array::from_fn(|v| {
            let gain = [1.0, 1.8, 0.7][v];
            (0..n)
                .map(|i| segment(20.0 * gain * spread(i, v as u32), i))
                .collect()
        });
        let views = Views {
            segments: [&lists[0], &lists[1], &lists[2]],
            oriented: true,
        };
        let mut hypotheses: Vec<Hypothesis> = (0..n).map(|i| hypothesis(i, i % 4 == 0)).collect();
        let gains = view_gains(&views, &hypotheses);
        assert!((gains[1] / 1.8 - 1.0).abs() < 0.1, "{gains:?}");
        assert!((gains[2] / 0.7 - 1.0).abs() < 0.1, "{gains:?}");
        // 1.8 / 0.7 = 2.6 apart, beyond 1.6 as they come: divided by the gains, all kept.
        let (_, refused) = refuse_depth_blind(&views, &mut hypotheses, 1.6);
        assert_eq!(refused, 0);
        assert_eq!(hypotheses.len(), n as usize);
        // With too few hypotheses to measure them, the gains are 1 and the blind triplets of
        // such a rig are refused.
        let few_count = MIN_GAIN_SAMPLES as u32 - 1;
        let mut few: Vec<Hypothesis> = (0..few_count).map(|i| hypothesis(i, true)).collect();
        assert_eq!(view_gains(&views, &few), [1.0; 3]);
        let (_, refused) = refuse_depth_blind(&views, &mut few, 1.6);
        assert_eq!(refused, few_count);
        // A ghost: its searched view's gradient half of what the gains predict.
        let mut ghost_lists = lists.clone();
        ghost_lists[2][0] = segment(0.5 * 20.0 * 0.7, 0);
        let views = Views {
            segments: [&ghost_lists[0], &ghost_lists[1], &ghost_lists[2]],
            oriented: true,
        };
        let mut hypotheses: Vec<Hypothesis> = (0..n).map(|i| hypothesis(i, i % 4 == 0)).collect();
        let (_, refused) = refuse_depth_blind(&views, &mut hypotheses, 1.6);
        assert_eq!(refused, 1);
        assert!(hypotheses.iter().all(|h| h.segments[0] != 0));
        // Gradients a list may give, 1e-300 against 1e300: no gain past f64 is reported.
        let extreme: [Vec<RectSegment>; 3] = std::array::from_fn(|v| {
            let g = [1e-300, 1e300, 1.0][v];
            (0..n).map(|i| segment(g, i)).collect()
        });
        let views = Views {
            segments: [&extreme[0], &extreme[1], &extreme[2]],
            oriented: true,
        };
        assert_eq!(view_gains(&views, &hypotheses), [1.0; 3]);
    }
}
