//! SplitMix64 (Steele, Lea and Flood, "Fast splittable pseudorandom number generators", 2014):
//! the simulator's one small generator for noise streams and seeds, shared by the lab's host
//! noise, its runs' seeds and the TSN network's launch jitter and cross traffic.
//!
//! It is counter-based: the stream's state moves by a constant, the golden gamma, and each
//! output is a hash of the state. So [`splitmix64`] of a seed is a seed of its own, independent
//! of its neighbours, and a stream can be cut anywhere and resumed from its state. (The
//! crystals' wander uses ChaCha8 instead, [`crate::clock`].)
//!
//! ```
//! use ecsync_sim::rng::{SplitMix64, splitmix64};
//!
//! let mut r = SplitMix64(7);
//! let first = r.next();
//! assert_eq!(first, splitmix64(7), "the first output is the hash of the seed");
//! assert_eq!(r.0, 7u64.wrapping_add(SplitMix64::GAMMA));
//! let u = r.next_unit();
//! assert!(u > 0.0 && u <= 1.0);
//! ```

/// The golden gamma, `2^64 / phi` rounded to odd: the state's step.
const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

/// The output of a SplitMix64 stream whose state is `z`: a hash of `z` (the state plus the
/// gamma, through the MurmurHash3 finaliser variant of the paper). Seeds derived by it from a
/// seed and an index are independent streams.
pub const fn splitmix64(z: u64) -> u64 {
    let mut z = z.wrapping_add(GAMMA);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Uniform in (0, 1] from 64 random bits: the top 53 bits, plus one, over 2^53. Never 0, so
/// its logarithm is finite (exponential gaps, Box-Muller).
pub fn unit_from_bits(bits: u64) -> f64 {
    ((bits >> 11) + 1) as f64 / (1u64 << 53) as f64
}

/// A SplitMix64 stream. The field is the state: the stream is a function of it alone, so it
/// can be stored and resumed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// The state's step per output.
    pub const GAMMA: u64 = GAMMA;

    /// The next output: [`splitmix64`] of the state, which then moves on by the gamma.
    // An inherent `next` (not `Iterator`): the stream never ends, and an `Option` on the
    // noise's hot path would only be unwrapped.
    #[allow(clippy::should_implement_trait)]
    #[inline]
    pub fn next(&mut self) -> u64 {
        let v = splitmix64(self.0);
        self.0 = self.0.wrapping_add(GAMMA);
        v
    }

    /// The next output as a uniform number in (0, 1] ([`unit_from_bits`]).
    #[inline]
    pub fn next_unit(&mut self) -> f64 {
        unit_from_bits(self.next())
    }
}

/// The stream as a `rand` generator, for `rand_distr`'s distributions (the host's Gaussian
/// jitter): 32-bit draws take the output's high half.
impl rand::TryRng for SplitMix64 {
    type Error = core::convert::Infallible;

    fn try_next_u32(&mut self) -> Result<u32, Self::Error> {
        Ok((self.next() >> 32) as u32)
    }

    fn try_next_u64(&mut self) -> Result<u64, Self::Error> {
        Ok(self.next())
    }

    fn try_fill_bytes(&mut self, dst: &mut [u8]) -> Result<(), Self::Error> {
        for c in dst.chunks_mut(8) {
            let v = self.next().to_le_bytes();
            c.copy_from_slice(&v[..c.len()]);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The first outputs of Vigna's reference `splitmix64.c` with its state set to 1234567
    /// (compiled and run to get them).
    #[test]
    fn matches_the_reference_stream() {
        let mut r = SplitMix64(1_234_567);
        for want in [
            6_457_827_717_110_365_317,
            3_203_168_211_198_807_973,
            9_817_491_932_198_370_423,
            4_593_380_528_125_082_431,
            16_408_922_859_458_223_821,
        ] {
            assert_eq!(r.next(), want);
        }
    }

    #[test]
    fn unit_is_in_the_half_open_interval() {
        assert_eq!(unit_from_bits(0), 1.0 / (1u64 << 53) as f64);
        assert_eq!(unit_from_bits(u64::MAX), 1.0);
    }
}
