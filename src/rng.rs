//! A tiny seeded generator (SplitMix64, Steele et al. 2014) for the data generator, point
//! sampling and tests. Written here rather than taken from `rand` because fixtures and test
//! expectations must stay bit-identical across crate releases, which `rand` does not promise
//! for its generators or distributions.

/// SplitMix64: 64-bit state, passes BigCrush, trivially reproducible.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// A generator from a seed.
    pub fn new(seed: u64) -> SplitMix64 {
        SplitMix64(seed)
    }

    /// The next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Uniform in [lo, hi).
    #[inline]
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    /// Uniform integer in [0, n) (n > 0), by Lemire's multiply-shift.
    #[inline]
    pub fn below(&mut self, n: u64) -> u64 {
        ((self.next_u64() as u128 * n as u128) >> 64) as u64
    }

    /// Standard normal deviate (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.unit().max(f64::MIN_POSITIVE);
        let u2 = self.unit();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// `k` distinct indices out of `0..n`, sorted (Floyd's algorithm for small k, a partial
    /// Fisher–Yates otherwise).
    pub fn sample_indices(&mut self, n: usize, k: usize) -> Vec<u32> {
        let k = k.min(n);
        let mut out: Vec<u32> = if k * 4 < n {
            let mut set = std::collections::HashSet::with_capacity(k);
            for j in (n - k)..n {
                let t = self.below(j as u64 + 1) as u32;
                if !set.insert(t) {
                    set.insert(j as u32);
                }
            }
            set.into_iter().collect()
        } else {
            let mut all: Vec<u32> = (0..n as u32).collect();
            for i in 0..k {
                let j = i + self.below((n - i) as u64) as usize;
                all.swap(i, j);
            }
            all.truncate(k);
            all
        };
        out.sort_unstable();
        out
    }
}
