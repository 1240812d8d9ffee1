//! A box room's edges for the map's unit tests (registration, sessions): floor and ceiling
//! rectangles, the four vertical corners and shelves, each edge exact with an isotropic
//! covariance.

use nalgebra::{Matrix6, Point3};

use super::Measured;

/// The room about the origin, 5 x 6 x 2.4 m, with shelves on the north and east walls (and
/// the west one too when `west_shelves`), each edge with covariance `sigma_m`² I.
pub(crate) fn box_room(sigma_m: f64, west_shelves: bool) -> Vec<Measured> {
    let (x, y, z) = (2.5, 3.0, 2.4);
    let corners = [(-x, -y), (x, -y), (x, y), (-x, y)];
    let mut edges = Vec::new();
    for i in 0..4 {
        let (a, b) = (corners[i], corners[(i + 1) % 4]);
        for h in [0.0, z] {
            edges.push((Point3::new(a.0, a.1, h), Point3::new(b.0, b.1, h)));
        }
        edges.push((Point3::new(a.0, a.1, 0.0), Point3::new(a.0, a.1, z)));
    }
    for (k, h) in [0.6, 1.1, 1.7].into_iter().enumerate() {
        let x0 = -1.5 + 0.7 * k as f64;
        edges.push((Point3::new(x0, y, h), Point3::new(x0 + 1.2, y, h)));
        edges.push((
            Point3::new(x, -1.0 + k as f64, h),
            Point3::new(x, k as f64, h),
        ));
        if west_shelves {
            edges.push((
                Point3::new(-x, 0.5 * k as f64, h),
                Point3::new(-x, 1.0 + 0.5 * k as f64, h),
            ));
        }
    }
    edges
        .into_iter()
        .map(|(start, end)| edge(start, end, sigma_m))
        .collect()
}

/// A certain edge from `start` to `end` with `sigma_m` of isotropic noise at each end.
pub(crate) fn edge(start: Point3<f64>, end: Point3<f64>, sigma_m: f64) -> Measured {
    Measured {
        start,
        end,
        covariance: Matrix6::identity() * sigma_m.powi(2),
        uncertain: false,
    }
}
