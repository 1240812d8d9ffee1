//! The pose graph's normal equations, solved without a dense matrix.
//!
//! A session's information matrix has one 6×6 block per capture and one off-diagonal block
//! per edge; each capture ties to a few others, so all but a few blocks are zero. Held dense,
//! a session of n captures costs 288·n² bytes and n³ work per Gauss–Newton step: 50 captures
//! are 2 ms, 1,000 are 288 MB and seconds, and the service accepts many more. Here the
//! matrix is held in *envelope* (profile) storage — each block row from its first non-zero
//! block to the diagonal — where a Cholesky factorisation creates no fill outside the
//! envelope, after the captures are ordered to keep the envelope narrow (reverse
//! Cuthill–McKee over the capture graph: a driving session's band is the few captures each
//! one sees again). The pose covariances the map needs are the inverse's diagonal blocks,
//! which the factor gives within the envelope, without the rest of the inverse (Takahashi's
//! recurrence).

use nalgebra::{Matrix6, Vector6};

#[cfg(test)]
use crate::checkpoint::never_stopped;
use crate::checkpoint::{Checkpoint, Stopped};

/// The stage a stopped factorisation or inversion names.
const STAGE: &str = "pose graph";

/// A symmetric matrix of `n`×`n` blocks of 6×6, its lower triangle held by block rows, each
/// from `first[i]` to the diagonal.
#[derive(Debug, Clone)]
pub struct Envelope {
    first: Vec<usize>,
    /// Where row i's blocks start in `blocks`.
    start: Vec<usize>,
    blocks: Vec<Matrix6<f64>>,
}

impl Envelope {
    /// The zero matrix of `n` block rows whose non-zero off-diagonal blocks are among
    /// `links` (pairs of block indices, either order).
    pub fn new(n: usize, links: impl IntoIterator<Item = (usize, usize)>) -> Envelope {
        let first = first_blocks(n, links);
        let mut start = Vec::with_capacity(n + 1);
        let mut total = 0;
        for (i, f) in first.iter().enumerate() {
            start.push(total);
            total += i - f + 1;
        }
        start.push(total);
        Envelope {
            first,
            start,
            blocks: vec![Matrix6::zeros(); total],
        }
    }

    fn index(&self, i: usize, j: usize) -> Option<usize> {
        (j <= i && j >= self.first[i]).then(|| self.start[i] + j - self.first[i])
    }

    /// Block (i, j), i ≥ j, within the envelope.
    fn at(&self, i: usize, j: usize) -> &Matrix6<f64> {
        &self.blocks[self.index(i, j).expect("within the envelope")]
    }

    /// Adds `m` to block (i, j) (and, the matrix being symmetric, its transpose to (j, i)).
    /// Panics outside the envelope given to [`Envelope::new`].
    pub fn add(&mut self, i: usize, j: usize, m: &Matrix6<f64>) {
        if i >= j {
            let k = self.index(i, j).expect("a link given to Envelope::new");
            self.blocks[k] += m;
        } else if let Some(k) = self.index(j, i) {
            self.blocks[k] += m.transpose();
        } else {
            panic!("block ({i}, {j}) outside the envelope");
        }
    }

    /// [`Envelope::cholesky_until`] without a checkpoint.
    #[cfg(test)]
    pub fn cholesky(self) -> Option<Factor> {
        never_stopped(self.cholesky_until(Checkpoint::NEVER))
    }

    /// The Cholesky factor L (H = L Lᵀ, each diagonal block lower triangular), or `None`
    /// when the matrix is not positive definite; asking `checkpoint` before each block row:
    /// a session's graph may take a second or two, and a request past its deadline should
    /// not.
    pub fn cholesky_until(mut self, checkpoint: Checkpoint) -> Result<Option<Factor>, Stopped> {
        let n = self.first.len();
        for i in 0..n {
            checkpoint.before(STAGE)?;
            let fi = self.first[i];
            for j in fi..=i {
                let fj = self.first[j];
                let mut s = *self.at(i, j);
                for k in fi.max(fj)..j {
                    s -= self.at(i, k) * self.at(j, k).transpose();
                }
                let k = self.index(i, j).expect("within the envelope");
                if j < i {
                    // L_ij = S L_jj⁻ᵀ: solve L_jj X = Sᵀ for X = L_ijᵀ.
                    let ljj = self.at(j, j);
                    let Some(x) = ljj.solve_lower_triangular(&s.transpose()) else {
                        return Ok(None);
                    };
                    self.blocks[k] = x.transpose();
                } else {
                    let sym = (s + s.transpose()) * 0.5;
                    let Some(c) = sym.cholesky() else {
                        return Ok(None);
                    };
                    self.blocks[k] = c.l();
                }
            }
        }
        // Column i's rows below the diagonal: the rows k > i whose envelope reaches i.
        let mut below: Vec<Vec<usize>> = vec![Vec::new(); n];
        for k in 0..n {
            for column in below.iter_mut().take(k).skip(self.first[k]) {
                column.push(k);
            }
        }
        Ok(Some(Factor { l: self, below }))
    }
}

/// The Cholesky factor of an [`Envelope`].
#[derive(Debug, Clone)]
pub struct Factor {
    l: Envelope,
    below: Vec<Vec<usize>>,
}

impl Factor {
    /// Solves H x = b; `None` when `b` has not one block per block row.
    pub fn solve(&self, b: &[Vector6<f64>]) -> Option<Vec<Vector6<f64>>> {
        let l = &self.l;
        let n = l.first.len();
        if b.len() != n {
            return None;
        }
        let mut y: Vec<Vector6<f64>> = Vec::with_capacity(n);
        for (i, bi) in b.iter().enumerate() {
            let mut s = *bi;
            for (k, yk) in y.iter().enumerate().skip(l.first[i]) {
                s -= l.at(i, k) * yk;
            }
            y.push(l.at(i, i).solve_lower_triangular(&s)?);
        }
        // Backward, Lᵀ x = y: row i of Lᵀ is column i of L.
        let mut x = y;
        for i in (0..n).rev() {
            let mut s = x[i];
            for &k in &self.below[i] {
                s -= l.at(k, i).transpose() * x[k];
            }
            x[i] = l.at(i, i).tr_solve_lower_triangular(&s)?;
        }
        Some(x)
    }

    /// [`Factor::inverse_diagonal_until`] without a checkpoint.
    #[cfg(test)]
    pub fn inverse_diagonal(&self) -> Option<Vec<Matrix6<f64>>> {
        never_stopped(self.inverse_diagonal_until(Checkpoint::NEVER))
    }

    /// The diagonal blocks of H⁻¹, asking `checkpoint` before each block row. Σ = L⁻ᵀL⁻¹
    /// gives LᵀΣ = L⁻¹, lower triangular, so for j ≥ i, Σ_ij = L_ii⁻ᵀ(δ_ij L_ii⁻¹ −
    /// Σ_k L_kiᵀ Σ_kj) over the rows k > i of column i; from the last row up, every Σ_kj it
    /// needs lies within the envelope.
    pub fn inverse_diagonal_until(
        &self,
        checkpoint: Checkpoint,
    ) -> Result<Option<Vec<Matrix6<f64>>>, Stopped> {
        let l = &self.l;
        let n = l.first.len();
        let mut sigma = Envelope {
            first: l.first.clone(),
            start: l.start.clone(),
            blocks: vec![Matrix6::zeros(); l.blocks.len()],
        };
        let below = &self.below;
        // Σ_kj for k, j ≥ i, either order.
        let get = |s: &Envelope, k: usize, j: usize| -> Matrix6<f64> {
            if k >= j {
                *s.at(k, j)
            } else {
                s.at(j, k).transpose()
            }
        };
        for i in (0..n).rev() {
            checkpoint.before(STAGE)?;
            let Some(lii_inv) = l.at(i, i).solve_lower_triangular(&Matrix6::identity()) else {
                return Ok(None);
            };
            for &j in below[i].iter().rev() {
                let mut s = Matrix6::zeros();
                for &k in &below[i] {
                    s += l.at(k, i).transpose() * get(&sigma, k, j);
                }
                let Some(solved) = l.at(i, i).tr_solve_lower_triangular(&s) else {
                    return Ok(None);
                };
                let sij = -solved;
                // Stored as Σ_ji = Σ_ijᵀ, in row j.
                let idx = sigma.index(j, i).expect("within the envelope");
                sigma.blocks[idx] = sij.transpose();
            }
            let mut s = lii_inv;
            for &k in &below[i] {
                s -= l.at(k, i).transpose() * get(&sigma, k, i);
            }
            let Some(sii) = l.at(i, i).tr_solve_lower_triangular(&s) else {
                return Ok(None);
            };
            let idx = sigma.index(i, i).expect("diagonal");
            sigma.blocks[idx] = (sii + sii.transpose()) * 0.5;
        }
        Ok(Some((0..n).map(|i| *sigma.at(i, i)).collect()))
    }
}

/// The work of factorising the matrix of `n` blocks linked by `links` once ordered by
/// [`narrow_order`]: the sum over block rows of the row's width squared, the 6×6 block products
/// one Cholesky takes (and as many the marginal covariances take). Computed from the links
/// alone, before anything is allocated.
pub fn ordered_work(n: usize, links: &[(usize, usize)]) -> u64 {
    let position = narrow_positions(n, links);
    let placed = links
        .iter()
        .filter(|&&(a, b)| a < n && b < n)
        .map(|&(a, b)| (position[a], position[b]));
    first_blocks(n, placed)
        .iter()
        .enumerate()
        .map(|(i, f)| ((i - f + 1) as u64).pow(2))
        .sum()
}

/// Each block row's first non-zero block of `n` rows linked by `links` (either order; links
/// past `n` ignored).
fn first_blocks(n: usize, links: impl IntoIterator<Item = (usize, usize)>) -> Vec<usize> {
    let mut first: Vec<usize> = (0..n).collect();
    for (a, b) in links {
        let (hi, lo) = (a.max(b), a.min(b));
        if hi < n {
            first[hi] = first[hi].min(lo);
        }
    }
    first
}

/// Where [`narrow_order`] puts each node: `position[node]`.
pub fn narrow_positions(n: usize, links: &[(usize, usize)]) -> Vec<usize> {
    let mut position = vec![0; n];
    for (p, &node) in narrow_order(n, links).iter().enumerate() {
        position[node] = p;
    }
    position
}

/// An order of `n` nodes linked by `links` that keeps every node near those it links to:
/// reverse Cuthill–McKee (breadth first from a least-linked node, neighbours by how few
/// links they have, the whole reversed), each connected part in turn. `order[p]` is the node
/// at position p.
pub fn narrow_order(n: usize, links: &[(usize, usize)]) -> Vec<usize> {
    let mut neighbours: Vec<Vec<usize>> = vec![Vec::new(); n];
    for &(a, b) in links {
        if a < n && b < n && a != b {
            neighbours[a].push(b);
            neighbours[b].push(a);
        }
    }
    for list in &mut neighbours {
        list.sort_unstable();
        list.dedup();
    }
    let degree: Vec<usize> = neighbours.iter().map(Vec::len).collect();
    let mut placed = vec![false; n];
    let mut order = Vec::with_capacity(n);
    let mut by_degree: Vec<usize> = (0..n).collect();
    by_degree.sort_by_key(|&v| (degree[v], v));
    for &root in &by_degree {
        if placed[root] {
            continue;
        }
        placed[root] = true;
        let mut head = order.len();
        order.push(root);
        while head < order.len() {
            let v = order[head];
            head += 1;
            let mut next: Vec<usize> = neighbours[v]
                .iter()
                .copied()
                .filter(|&w| !placed[w])
                .collect();
            next.sort_by_key(|&w| (degree[w], w));
            for w in next {
                placed[w] = true;
                order.push(w);
            }
        }
    }
    order.reverse();
    order
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;
    use proptest::prelude::*;

    /// A random symmetric positive-definite system on `n` blocks with `links`: each link an
    /// arbitrary block, the diagonal dominant.
    fn system(n: usize, links: &[(usize, usize)], seed: u64) -> (Envelope, DMatrix<f64>) {
        let mut state = seed | 1;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        let mut envelope = Envelope::new(n, links.iter().copied());
        let mut dense = DMatrix::zeros(6 * n, 6 * n);
        let mut put = |e: &mut Envelope, i: usize, j: usize, m: &Matrix6<f64>| {
            e.add(i, j, m);
            let mut v = dense.view_mut((6 * i, 6 * j), (6, 6));
            v += m;
            if i != j {
                let mut t = dense.view_mut((6 * j, 6 * i), (6, 6));
                t += m.transpose();
            }
        };
        for &(a, b) in links {
            if a == b {
                continue;
            }
            let m = Matrix6::from_fn(|_, _| next());
            put(&mut envelope, a, b, &m);
        }
        for i in 0..n {
            let r = Matrix6::from_fn(|_, _| next());
            let m = r * r.transpose() + Matrix6::identity() * (6.0 + 4.0 * n as f64);
            put(&mut envelope, i, i, &m);
        }
        (envelope, dense)
    }

    proptest! {
        #[test]
        fn solves_and_inverts_as_the_dense_matrix_does(
            n in 1usize..12,
            raw in proptest::collection::vec((0usize..12, 0usize..12), 0..30),
            seed in 1u64..u64::MAX,
        ) {
            let links: Vec<(usize, usize)> =
                raw.into_iter().filter(|&(a, b)| a < n && b < n).collect();
            let (envelope, dense) = system(n, &links, seed);
            let b: Vec<Vector6<f64>> = (0..n)
                .map(|i| Vector6::from_fn(|r, _| (i * 6 + r) as f64 - 3.0))
                .collect();
            let factor = envelope.cholesky().expect("positive definite");
            let x = factor.solve(&b).expect("solvable");
            let inverse = dense.clone().cholesky().expect("positive definite").inverse();
            let flat = DMatrix::from_fn(6 * n, 1, |r, _| b[r / 6][r % 6]);
            let want = &inverse * flat;
            for i in 0..n {
                for r in 0..6 {
                    prop_assert!((x[i][r] - want[(6 * i + r, 0)]).abs() < 1e-9);
                }
            }
            let diagonal = factor.inverse_diagonal().expect("invertible");
            for (i, block) in diagonal.iter().enumerate() {
                let want = inverse.view((6 * i, 6 * i), (6, 6));
                prop_assert!((block - want).abs().max() < 1e-12);
            }
        }
    }

    #[test]
    fn a_chain_in_any_numbering_is_ordered_into_a_band() {
        // A chain of 40 nodes numbered in a scrambled order: ordered, each link spans one
        // position, so each row holds two blocks.
        let scramble = |k: usize| (k * 17) % 40;
        let links: Vec<(usize, usize)> = (1..40).map(|k| (scramble(k - 1), scramble(k))).collect();
        let position = narrow_positions(40, &links);
        let placed: Vec<(usize, usize)> = links
            .iter()
            .map(|&(a, b)| (position[a], position[b]))
            .collect();
        assert_eq!(Envelope::new(40, placed).blocks.len(), 40 + 39);
        assert!(Envelope::new(40, links).blocks.len() > 300);
    }

    #[test]
    fn a_matrix_that_is_not_positive_definite_has_no_factor() {
        let mut e = Envelope::new(2, [(0, 1)]);
        e.add(0, 0, &Matrix6::identity());
        e.add(1, 1, &Matrix6::identity());
        e.add(1, 0, &(Matrix6::identity() * 2.0));
        assert!(e.cholesky().is_none());
    }
}
