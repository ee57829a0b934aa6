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

/// Decodes the System Time Difference register (0x092C) into `received - local copy` in ns.
///
/// The register is sign-magnitude: bits 30:0 hold |received system time - local copy of system
/// time| and bit 31 is set when the local copy is greater than or equal to the received time
/// (ESC datasheet section II v3.3, register 0x092C; the v2.x text had the polarity reversed and was
/// corrected in v2.8). Decoding bit 31 as a minus sign therefore yields `received - local`: a
/// negative value means this clock is ahead of the reference.
#[inline]
pub const fn decode_time_difference(raw: u32) -> i32 {
    let magnitude = (raw & 0x7fff_ffff) as i32;
    if raw & 0x8000_0000 != 0 {
        -magnitude
    } else {
        magnitude
    }
}

/// Encodes `received - local` in ns as the 0x092C value, saturating the magnitude at 2^31 - 1.
/// Equality sets bit 31 ("local copy greater than or equal").
#[inline]
pub const fn encode_time_difference(received_minus_local_ns: i64) -> u32 {
    let magnitude = received_minus_local_ns.unsigned_abs();
    let magnitude = if magnitude > 0x7fff_ffff {
        0x7fff_ffff
    } else {
        magnitude as u32
    };
    if received_minus_local_ns <= 0 {
        magnitude | 0x8000_0000
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
        // Local copy 100 ns behind the received time: bit 31 clear, magnitude 100.
        assert_eq!(encode_time_difference(100), 0x64);
        assert_eq!(decode_time_difference(0x0000_0064), 100);
        // Local copy 100 ns ahead: bit 31 set.
        assert_eq!(encode_time_difference(-100), 0x8000_0064);
        assert_eq!(decode_time_difference(0x8000_0064), -100);
        // Equal: "greater than or equal" sets bit 31; decodes to 0.
        assert_eq!(encode_time_difference(0), 0x8000_0000);
        assert_eq!(decode_time_difference(0x8000_0000), 0);
        assert_eq!(encode_time_difference(i64::MIN), 0xffff_ffff);
        assert_eq!(encode_time_difference(1 << 40), 0x7fff_ffff);
        // Not two's complement: -1 is 0x80000001, not 0xffffffff.
        assert_eq!(encode_time_difference(-1), 0x8000_0001);
    }

    #[test]
    fn phase() {
        assert_eq!(phase_in_period(2_500_000, 1_000_000), 500_000);
    }
}
