//! A bounding-volume hierarchy over a scene's boxes, for fast ray casting.
//!
//! Contrast probes cast tens of thousands of rays per observation; testing every box of a
//! hundred-box room for each is most of the cost of [`observe`](super::observe). The
//! hierarchy (median split along the longest axis of box centres, up to [`LEAF_SIZE`] boxes
//! per leaf) visits a few nodes per ray instead. It borrows the scene and is built per call,
//! so it can never go stale, and it returns exactly the hits of [`Scene::cast`]: the same
//! per-box test, and the same lowest-index rule for ties.

use nalgebra::{Point3, Vector3};

use super::scene::{slab, Face, Hit, Ray, Scene, Tracer, HIT_EPS};

/// Boxes per leaf: below this, testing boxes is cheaper than descending.
pub const LEAF_SIZE: usize = 4;

#[derive(Debug, Clone)]
struct Node {
    lo: [f64; 3],
    hi: [f64; 3],
    /// Leaf: boxes `order[first..first + count]`. Inner (`count == 0`): children are the
    /// next node and node `right`.
    first: usize,
    count: usize,
    right: usize,
}

/// Boxes with more than this share of the scene bounds' surface area (floor, walls) stay
/// out of the tree: they would stretch every node around them to the size of the room.
pub const LARGE_BOX_AREA_SHARE: f64 = 1.0 / 16.0;

/// A scene with its hierarchy.
#[derive(Debug, Clone)]
pub struct SceneIndex<'a> {
    scene: &'a Scene,
    /// Box bounds as arrays, by box index.
    bounds: Vec<([f64; 3], [f64; 3])>,
    /// Tested for every ray, before the tree.
    large: Vec<usize>,
    nodes: Vec<Node>,
    order: Vec<usize>,
}

fn surface_area(lo: &[f64; 3], hi: &[f64; 3]) -> f64 {
    let d = [hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]];
    2.0 * (d[0] * d[1] + d[1] * d[2] + d[2] * d[0])
}

impl<'a> SceneIndex<'a> {
    pub fn new(scene: &'a Scene) -> SceneIndex<'a> {
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for b in &scene.boxes {
            for k in 0..3 {
                lo[k] = lo[k].min(b.min[k]);
                hi[k] = hi[k].max(b.max[k]);
            }
        }
        let limit = LARGE_BOX_AREA_SHARE * surface_area(&lo, &hi);
        let (large, order): (Vec<usize>, Vec<usize>) = (0..scene.boxes.len()).partition(|&i| {
            let b = &scene.boxes[i];
            surface_area(&b.min.coords.into(), &b.max.coords.into()) > limit
        });
        let mut index = SceneIndex {
            scene,
            bounds: scene
                .boxes
                .iter()
                .map(|b| (b.min.coords.into(), b.max.coords.into()))
                .collect(),
            large,
            nodes: Vec::new(),
            order,
        };
        if !index.order.is_empty() {
            index.build(0, index.order.len());
        }
        index
    }

    fn build(&mut self, first: usize, count: usize) -> usize {
        let boxes = &self.scene.boxes;
        let members = &mut self.order[first..first + count];
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let (mut clo, mut chi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &i in members.iter() {
            let b = &boxes[i];
            for k in 0..3 {
                lo[k] = lo[k].min(b.min[k]);
                hi[k] = hi[k].max(b.max[k]);
                let c = 0.5 * (b.min[k] + b.max[k]);
                clo[k] = clo[k].min(c);
                chi[k] = chi[k].max(c);
            }
        }
        let node = self.nodes.len();
        self.nodes.push(Node {
            lo,
            hi,
            first,
            count,
            right: 0,
        });
        if count <= LEAF_SIZE {
            return node;
        }
        let axis = (0..3)
            .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
            .unwrap_or(0);
        let centre = |i: usize| boxes[i].min[axis] + boxes[i].max[axis];
        members.sort_by(|&a, &b| centre(a).total_cmp(&centre(b)).then(a.cmp(&b)));
        let half = count / 2;
        self.nodes[node].count = 0;
        self.build(first, half);
        let right = self.build(first + half, count - half);
        self.nodes[node].right = right;
        node
    }
}

impl Tracer for SceneIndex<'_> {
    fn scene(&self) -> &Scene {
        self.scene
    }

    fn cast(&self, origin: &Point3<f64>, dir: &Vector3<f64>) -> Option<Hit> {
        let ray = Ray::new(origin, dir)?;
        let mut best: Option<(f64, usize, Face)> = None;
        for &i in &self.large {
            let (lo, hi) = &self.bounds[i];
            ray.offer(lo, hi, i, &mut best);
        }
        // Entry distance of a node's bounds, if the ray meets them ahead of its origin.
        let enter = |n: usize| {
            let node = &self.nodes[n];
            slab(&ray.origin, &ray.dir, &node.lo, &node.hi)
                .filter(|&(_, t_far, _, _)| t_far > HIT_EPS)
                .map(|(t_near, _, _, _)| t_near)
        };
        // Depth first, nearer child first, so the best hit is found early and prunes the
        // rest. Median splits keep the tree log2(n / LEAF_SIZE) deep, and the stack holds at
        // most one pending sibling per level: 64 slots is plenty.
        let mut stack = [(0usize, 0.0f64); 64];
        let mut top = 0;
        if let Some(t) = (!self.nodes.is_empty()).then(|| enter(0)).flatten() {
            stack[0] = (0, t);
            top = 1;
        }
        while top > 0 {
            top -= 1;
            let (n, t_enter) = stack[top];
            // Strictly farther than the best hit: nothing inside can win, not even a tie.
            if best.is_some_and(|(bt, _, _)| t_enter > bt) {
                continue;
            }
            let node = &self.nodes[n];
            if node.count > 0 {
                for &i in &self.order[node.first..node.first + node.count] {
                    let (lo, hi) = &self.bounds[i];
                    ray.offer(lo, hi, i, &mut best);
                }
                continue;
            }
            let mut children = [(n + 1, enter(n + 1)), (node.right, enter(node.right))];
            if let [(_, Some(a)), (_, Some(b))] = children {
                if b > a {
                    children.swap(0, 1);
                }
            }
            // Farther child pushed first, popped last.
            for (child, t) in children {
                if let Some(t) = t {
                    if top < stack.len() {
                        stack[top] = (child, t);
                        top += 1;
                    }
                }
            }
        }
        best.map(|(t, box_index, face)| ray.hit(t, box_index, face))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::Rng;

    #[test]
    fn same_hits_as_brute_force() {
        let scene = Scene::room(11);
        let index = SceneIndex::new(&scene);
        let mut rng = Rng::new(5);
        for _ in 0..2000 {
            let o = Point3::new(
                rng.range(0.2, 5.8),
                rng.range(0.2, 4.8),
                rng.range(0.1, 2.6),
            );
            let d = Vector3::new(rng.normal(), rng.normal(), rng.normal());
            assert_eq!(index.cast(&o, &d), scene.cast(&o, &d));
        }
        // Axis-parallel rays along shared faces, where ties happen.
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = 1.0;
            let o = Point3::new(3.0, 2.5, 0.08);
            assert_eq!(index.cast(&o, &d), scene.cast(&o, &d));
            assert_eq!(index.cast(&o, &-d), scene.cast(&o, &-d));
        }
        let empty = Scene {
            boxes: Vec::new(),
            light: Point3::origin(),
        };
        assert!(SceneIndex::new(&empty)
            .cast(&Point3::origin(), &Vector3::x())
            .is_none());
    }
}
