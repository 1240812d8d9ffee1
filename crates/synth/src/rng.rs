//! A small deterministic random number generator for synthetic data.
//!
//! Synthetic scenes, rigs and defects must be reproducible forever from a `u64` seed, on every
//! platform and with every version of every dependency, so golden numbers in tests and benches
//! never drift. We therefore carry our own generator instead of depending on `rand`:
//! SplitMix64 (Steele, Lea & Flood 2014), which passes BigCrush, has a 2⁶⁴ period, and whose
//! whole state is one `u64`. Normals come from the Box–Muller transform.
//!
//! Independent streams for independent parts of a data set (the scene, each camera, each
//! image's defects) are derived with [`Rng::fork`], so that adding a draw in one part does not
//! shift the numbers of every other part.

/// SplitMix64. The state is plain data: cloning a generator replays its future.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rng {
    state: u64,
}

const GOLDEN_GAMMA: u64 = 0x9E37_79B9_7F4A_7C15;

/// The SplitMix64 output function: a strong 64-bit mixer (also used to derive stream seeds).
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng { state: seed }
    }

    /// A generator for sub-stream `stream` of this seed, independent of the parent's draws.
    pub fn fork(&self, stream: u64) -> Rng {
        Rng::new(mix64(self.state ^ mix64(stream.wrapping_add(GOLDEN_GAMMA))))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.state = self.state.wrapping_add(GOLDEN_GAMMA);
        mix64(self.state)
    }

    /// Uniform in `[0, 1)`, with the 53 bits an `f64` mantissa holds.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Uniform in `[-half_width, half_width)`.
    pub fn symmetric(&mut self, half_width: f64) -> f64 {
        self.range(-half_width, half_width)
    }

    /// Uniform integer in `0..n` (0 when `n == 0`), unbiased by rejection.
    pub fn below(&mut self, n: u64) -> u64 {
        if n == 0 {
            return 0;
        }
        // Reject the top partial copy of 0..n so every residue is equally likely.
        let zone = u64::MAX - (u64::MAX % n);
        loop {
            let x = self.next_u64();
            if x < zone {
                return x % n;
            }
        }
    }

    /// Uniform index in `0..n` (0 when `n == 0`).
    pub fn index(&mut self, n: usize) -> usize {
        self.below(n as u64) as usize
    }

    /// True with probability `p` (clamped to `[0, 1]`).
    pub fn chance(&mut self, p: f64) -> bool {
        self.uniform() < p
    }

    /// Standard normal deviate (Box–Muller; the second deviate is discarded so the state
    /// stays one `u64`).
    pub fn normal(&mut self) -> f64 {
        // 1 - u is in (0, 1], so the logarithm is finite.
        let u1 = 1.0 - self.uniform();
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Fisher–Yates shuffle.
    pub fn shuffle<T>(&mut self, items: &mut [T]) {
        for i in (1..items.len()).rev() {
            let j = self.index(i + 1);
            items.swap(i, j);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_stream() {
        let (mut a, mut b) = (Rng::new(42), Rng::new(42));
        for _ in 0..1000 {
            assert_eq!(a.next_u64(), b.next_u64());
        }
        assert_ne!(Rng::new(1).next_u64(), Rng::new(2).next_u64());
    }

    #[test]
    fn splitmix64_reference_values() {
        // Reference outputs of SplitMix64 seeded with 1234567 (Vigna's splitmix64.c), which
        // pin the generator so synthetic data sets stay identical across versions.
        let mut r = Rng::new(1234567);
        assert_eq!(r.next_u64(), 6457827717110365317);
        assert_eq!(r.next_u64(), 3203168211198807973);
        assert_eq!(r.next_u64(), 9817491932198370423);
    }

    #[test]
    fn forks_are_independent_and_reproducible() {
        let root = Rng::new(7);
        let mut a = root.fork(1);
        let mut b = root.fork(2);
        assert_ne!(a.next_u64(), b.next_u64());
        assert_eq!(root.fork(1).next_u64(), Rng::new(7).fork(1).next_u64());
    }

    #[test]
    fn distributions_have_the_right_moments() {
        let mut r = Rng::new(99);
        let n = 20_000;
        let (mut s, mut s2, mut u_min, mut u_max) = (0.0, 0.0, 1.0f64, 0.0f64);
        for _ in 0..n {
            let x = r.normal();
            s += x;
            s2 += x * x;
            let u = r.uniform();
            u_min = u_min.min(u);
            u_max = u_max.max(u);
        }
        let mean = s / n as f64;
        let var = s2 / n as f64 - mean * mean;
        assert!(mean.abs() < 0.03, "mean {mean}");
        assert!((var - 1.0).abs() < 0.05, "variance {var}");
        assert!((0.0..0.001).contains(&u_min) && u_max < 1.0 && u_max > 0.999);
        let mut counts = [0usize; 3];
        for _ in 0..3000 {
            counts[r.index(3)] += 1;
        }
        assert!(
            counts.iter().all(|&c| (850..1150).contains(&c)),
            "{counts:?}"
        );
    }

    #[test]
    fn shuffle_is_a_permutation() {
        let mut v: Vec<usize> = (0..50).collect();
        Rng::new(3).shuffle(&mut v);
        let mut sorted = v.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..50).collect::<Vec<_>>());
        assert_ne!(v, sorted);
    }
}
