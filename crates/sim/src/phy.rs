//! The physical layer's figures: 100BASE-TX byte time, preamble and FCS, cable propagation, and
//! a frame's time on the wire from them.

use ecsync_wire::MIN_FRAME_LEN;

/// Wire time of one byte at 100 Mbit/s, ps.
pub const BYTE_TIME_PS: u64 = 80_000;
/// Preamble and start-of-frame delimiter, bytes.
pub const PREAMBLE_BYTES: u64 = 8;
/// Frame check sequence, bytes.
pub const FCS_BYTES: u64 = 4;
/// Signal propagation in a cable, ps per metre (5 ns/m, datasheet section I, 9.3).
pub const CABLE_PS_PER_M: f64 = 5_000.0;

/// Wire time of a frame of `len` bytes (without FCS, before padding): preamble, padded frame,
/// FCS.
pub fn frame_wire_time_ps(len: usize) -> u64 {
    (PREAMBLE_BYTES + len.max(MIN_FRAME_LEN) as u64 + FCS_BYTES) * BYTE_TIME_PS
}
