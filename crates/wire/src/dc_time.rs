//! Wrap-safe Distributed Clocks time arithmetic.
//!
//! DC system time is a 64-bit nanosecond count since 2000-01-01 00:00 (ESC datasheet section I,
//! "Distributed Clocks"). Slaves with 32-bit DC units, the receive-time port registers and most
//! masters' cyclic reads use only the low 32 bits, which wrap every 4.295 s, so every difference
//! taken from them must be a wrapping difference interpreted as signed.

/// `a - b` for 32-bit DC times, correct across a wrap as long as the true difference lies within
/// ±2^31 ns (±2.147 s).
#[inline]
pub const fn diff_u32(a: u32, b: u32) -> i32 {
    a.wrapping_sub(b) as i32
}

/// `a - b` for 64-bit DC times as a signed value.
#[inline]
pub const fn diff_u64(a: u64, b: u64) -> i64 {
    a.wrapping_sub(b) as i64
}

/// Adds a signed nanosecond amount to a 64-bit DC time (wrapping, as the ESC's adder does).
#[inline]
pub const fn add_signed_u64(t: u64, delta: i64) -> u64 {
    t.wrapping_add(delta as u64)
}

/// Reconstructs a 64-bit time from its low 32 bits, picking the value nearest to `near`
/// (a 64-bit time known to be within ±2^31 ns of the true one).
#[inline]
pub const fn extend_u32(near: u64, low: u32) -> u64 {
    let delta = diff_u32(low, near as u32);
    add_signed_u64(near, delta as i64)
}

/// `t mod period` for a DC time, with `period > 0`.
#[inline]
pub const fn phase_in_period(t: u64, period_ns: u32) -> u32 {
    (t % period_ns as u64) as u32
}

/// Bit 31 of the System Time Difference register (0x092C): set when the local copy of the system
/// time is smaller than the received system time.
pub const TIME_DIFFERENCE_LOCAL_SMALLER: u32 = 0x8000_0000;

/// Decodes the System Time Difference register (0x092C) into `local copy - received` in ns.
///
/// The register is sign-magnitude (Beckhoff ESC register description, register 0x092C, as
/// Infineon's XMC4800 reference manual reproduces it): bits 30:0 hold the mean difference
/// between the local copy of the system time and the received system time values, |local -
/// received|; bit 31 is 0 when the local copy is greater than or equal to the received system
/// time and 1 when it is smaller. Decoding bit 31 as a minus sign therefore yields
/// `local - received`: a positive value means this clock is ahead of the time written to it (of
/// the reference, in a synchronised segment), a negative one that it is behind. The reset value
/// is 0x00000000, so a clock that was never compared (the reference) reads 0.
#[inline]
pub const fn decode_time_difference(raw: u32) -> i32 {
    let magnitude = (raw & 0x7fff_ffff) as i32;
    if raw & TIME_DIFFERENCE_LOCAL_SMALLER != 0 {
        -magnitude
    } else {
        magnitude
    }
}

/// Encodes `local copy - received` in ns as the 0x092C value (see [`decode_time_difference`]),
/// saturating the magnitude at 2^31 - 1. Bit 31 is set only when the local copy is smaller than
/// the received time; an exact zero difference encodes as 0x00000000, the reset value.
#[inline]
pub const fn encode_time_difference(local_minus_received_ns: i64) -> u32 {
    let magnitude = local_minus_received_ns.unsigned_abs();
    let magnitude = if magnitude > 0x7fff_ffff {
        0x7fff_ffff
    } else {
        magnitude as u32
    };
    if local_minus_received_ns < 0 {
        magnitude | TIME_DIFFERENCE_LOCAL_SMALLER
    } else {
        magnitude
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differences_survive_the_32_bit_wrap() {
        // 10 ns after the wrap minus 20 ns before it is 30 ns.
        assert_eq!(diff_u32(10, u32::MAX - 19), 30);
        assert_eq!(diff_u32(u32::MAX - 19, 10), -30);
        assert_eq!(diff_u32(1_000, 1_000), 0);
    }

    #[test]
    fn extends_low_bits_across_a_wrap() {
        let near = 0x1_ffff_fff0u64; // 16 ns before a 32-bit wrap
        assert_eq!(extend_u32(near, 0x0000_0005), 0x2_0000_0005);
        assert_eq!(extend_u32(near, 0xffff_ff00), 0x1_ffff_ff00);
        assert_eq!(extend_u32(0x2_0000_0010, 0xffff_fff0), 0x1_ffff_fff0);
    }

    #[test]
    fn time_difference_matches_the_register_description() {
        // Hand-worked from the register description of 0x092C: bits 30:0 = |local - received|,
        // bit 31 = 0 when local >= received, 1 when local < received.
        //
        // Local copy 0x1000_0064, received 0x1000_0000: local greater by 100 ns, bit 31 clear.
        let local_greater = diff_u32(0x1000_0064, 0x1000_0000) as i64;
        assert_eq!(encode_time_difference(local_greater), 0x0000_0064);
        assert_eq!(decode_time_difference(0x0000_0064), 100);
        // Local copy 0x1000_0000, received 0x1000_0064: local smaller by 100 ns, bit 31 set.
        let local_smaller = diff_u32(0x1000_0000, 0x1000_0064) as i64;
        assert_eq!(encode_time_difference(local_smaller), 0x8000_0064);
        assert_eq!(decode_time_difference(0x8000_0064), -100);
        // Equal: "greater than or equal" keeps bit 31 clear; the register reads 0x00000000.
        assert_eq!(encode_time_difference(0), 0x0000_0000);
        assert_eq!(decode_time_difference(0x0000_0000), 0);
        // The reset value decodes to no difference.
        assert_eq!(decode_time_difference(0), 0);
        // A 0x80000000 (bit 31 with magnitude 0) still decodes to 0, but is never produced.
        assert_eq!(decode_time_difference(0x8000_0000), 0);
        // Local smaller by 1 ns: sign-magnitude, not two's complement (0x80000001, not 0xffffffff).
        assert_eq!(encode_time_difference(-1), 0x8000_0001);
        assert_eq!(encode_time_difference(1), 0x0000_0001);
        // Saturation of the 31 magnitude bits, either sign.
        assert_eq!(encode_time_difference(i64::MIN), 0xffff_ffff);
        assert_eq!(encode_time_difference(-(1 << 40)), 0xffff_ffff);
        assert_eq!(encode_time_difference(1 << 40), 0x7fff_ffff);
        // Round trip within the magnitude range; the magnitude bits are always |difference|.
        for d in [-0x7fff_ffff_i64, -12_345, -1, 0, 1, 40, 0x7fff_ffff] {
            let raw = encode_time_difference(d);
            assert_eq!(i64::from(decode_time_difference(raw)), d);
            assert_eq!(u64::from(raw & 0x7fff_ffff), d.unsigned_abs());
        }
    }

    #[test]
    fn phase() {
        assert_eq!(phase_in_period(2_500_000, 1_000_000), 500_000);
    }
}
