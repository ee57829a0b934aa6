//! The Distributed Clocks unit of one ESC: local clock, system time offset and delay, the time
//! control loop, receive-time latches and the SYNC0/SYNC1 cyclic unit, behind the register block
//! 0x0900-0x09FF.
//!
//! # Time control loop model
//!
//! The ESC datasheet (Beckhoff, "EtherCAT Slave Controller", section I "Technology" 9.1.4-9.1.5,
//! section II "Registers" 0x092C-0x0935) describes the loop by its registers, not its circuit.
//! Each rule below says what the datasheet says and, where it is silent, what is assumed and
//! why. The code is in `dc_unit/control_loop.rs`; the numbers refer to its comments.
//!
//! 1. **Compare.** A write to System Time (0x0910, by ARMW or FRMW) compares bits 31:0 of the
//!    written value with the local copy of the system time: "Δt = (t_Local time + t_Offset −
//!    t_Propagation delay) − t_Received System Time"; "If Δt is positive, the local time is
//!    running faster than the System time, and has to be slowed down" (section I, 9.1.5). The
//!    local copy is the one latched at the frame's start on port 0's receive clock (as 0x0910
//!    reads). Assumed: differences of 2^30 ns or more (a master writing 0 while it resets) are
//!    shown but do not steer the clock, and the next write starts a new interval (the
//!    datasheet promises nothing for such differences).
//! 2. **0x092C, the mean difference.** "Mean difference between local copy of System Time and
//!    received System Time values", bits 30:0 the magnitude, bit 31 set when the local copy is
//!    smaller, reset value 0 (section II, 0x092C); 0x0934 sets the "filter depth for mean value
//!    calculation of the received System Times" (section I, 9.1.5), `2^depth` values (bits
//!    3:0; depth 0 shows every difference as it is; reset value 4 as the model had it, the
//!    register table was not at hand). The reference clock, never
//!    compared, reads 0 (as real ones do). Assumed: a reset mean holds no values and averages
//!    the ones it has until `2^depth` are in (weight `1/n` for the n-th), then weighs a new
//!    one `2^-depth` (an exponential mean of that depth). The datasheet says the filters must
//!    be reset before drift compensation because their state "can have negative impact on the
//!    settling time" (section I, 9.1.4); it does not say how a reset filter fills. A filter
//!    that restarted from zero with weight `2^-depth` would still be held near zero by its
//!    reset for thousands of values: ethercrab's 100 writes would teach it 2.4 % of a drift
//!    (`1 - (1 - 2^-12)^100`), where the real EL2889 in replay-dc.pcapng lost most of it
//!    (tests/drift_loop.rs).
//! 3. **The speed counter, phase.** 0x0930, Speed Counter Start, is the "bandwidth for
//!    adjustment of local copy of System Time (larger values → smaller bandwidth and smoother
//!    adjustment)" (section II: reset value 0x1000, "Minimum value: 0x0080 to 0x3FFF"); the
//!    note to 0x0932 counts a speed counter period as `start ± diff + 2` ticks. Assumed (the
//!    datasheet does not draw the circuit): the local time advances 10 ns per 100 MHz tick and
//!    the loop makes one tick per speed counter period advance 11 or 9 ns instead; after a
//!    write the mean difference is stepped away so, one nanosecond per `start + 2` ticks
//!    (`1 / (10 ns * 4098)` = 24.4 ppm at 0x1000), until it is gone or the next write
//!    replaces it.
//! 4. **0x0932, the speed counter diff.** "Representation of the deviation between local clock
//!    period and Reference Clock's clock period (representation: two's complement). Range:
//!    ±(Speed Counter Start − 0x7F)"; its note: "Calculate the clock deviation after System Time
//!    Difference has settled at a low value as follows: Deviation = Speed Counter Diff / (5
//!    (Speed Counter Start + Speed Counter Diff + 2) (Speed Counter Start − Speed Counter Diff +
//!    2))" (section II, 0x0932; the formula as typeset there, read back from its text); 0x0935
//!    sets the "filter depth for mean value calculation ... of the calculated clock period
//!    deviations" (section I, 9.1.5; bits 3:0, reset value 12 as the model had it).
//!    Modelled: at every write that follows another (since the last reset, at least 1 us
//!    earlier) the loop calculates the clock period deviation over the interval between them —
//!    the change of the difference that its own steps (phase and frequency) do not explain,
//!    per elapsed time — and takes the mean of these deviations over the time of their
//!    intervals, filled as 0x092C's mean is (rule 2, `2^depth` intervals at depth 0x0935). The
//!    mean, within the range the register can represent (763 ppm at 0x1000), is the frequency
//!    correction the speed counter applies; 0x0932 reads the integer whose deviation by the
//!    note's formula is nearest to it. Assumed: the sign (positive when the local clock period
//!    is the longer, i.e. the crystal slow and the loop speeding it up, as the register's name
//!    reads); the rate is applied unquantised (the integer steps of 0x0932 are 0.012 ppm at
//!    0x1000); the mean weighted by the intervals' lengths, and a single interval's deviation
//!    not limited, only the mean: so the deviation a write's arrival jitter or a stamp's 40 ns
//!    cell puts into one interval comes out of the next (a bus shift master on a
//!    general-purpose host writes with microseconds of jitter: 5 us in 1 ms is 5 000 ppm for
//!    one interval), and a short interval (a frame resent within microseconds) weighs by its
//!    shortness. (Limited per interval to the range, the 40 ns cells of two MII stamps, up to
//!    80 ns over the tens of microseconds between static drift compensation frames, are cut
//!    unevenly around the drift: paper-2024's slaves left the bring-up having learnt 10-12 %
//!    less than their drift, where static drift compensation is there to teach it whole.)
//! 5. **Resets.** Writing 0x0930 "resets System Time Difference (0x092C:0x092F) and Speed
//!    Counter Diff (0x0932:0x0933)" (section II) and the internal filters: "Writing the current
//!    value of the register again is sufficient to reset the filters" (section I, 9.1.4): both
//!    means empty, no previous write, no phase step pending. Nothing else resets the loop: the
//!    note to 0x0928 asks the master to "reset internal system time difference filter and speed
//!    counter filter by writing Speed Counter Start (0x0930:0x0931) after changing this value",
//!    so a new offset or delay without that reset reaches the means as a step, as on the real
//!    ESC; a new filter depth applies from the next value on (assumed).
//!
//! The clock between writes is [`LocalClock`]'s: crystal, frequency correction, pending phase
//! step, all evaluated analytically.

use crate::clock::{CrystalParams, LocalClock};
use control_loop::SPEED_COUNTER_START_RESET;
use ecsync_wire::dc_time;
use ecsync_wire::register as reg;

/// Offset of the DC block in register space.
pub const DC_BLOCK_START: u16 = 0x0900;
/// Size of the DC block.
pub const DC_BLOCK_LEN: usize = 0x100;

/// Static configuration of a DC unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DcParams {
    /// The crystal.
    pub crystal: CrystalParams,
    /// 64-bit system time (feature bit 3); 32-bit units ignore the upper half.
    pub is_64bit: bool,
    /// Resolution with which the frame's start is seen at port 0, ns (MII 40, EBUS 10): the
    /// local time latched at SOF for System Time reads and compares has this granularity.
    pub sof_resolution_ns: u64,
}

/// The phase of port `p`'s receive clock against the local counter: fixed per port, on the
/// counter's 10 ns tick grid (the stamp is the counter's value at that edge).
fn port_phase(clock: &LocalClock, p: usize, res: u64) -> u64 {
    clock.tick_residue() + 10 * ((clock.params().seed >> (8 * p)) % (res / 10).max(1))
}

/// `x / 5` by multiplication with the reciprocal (exact for every u64).
#[inline(always)]
fn div5(x: u64) -> u64 {
    ((u128::from(x) * 0xcccc_cccc_cccc_cccd) >> 66) as u64
}

/// `x % 40`, written out so that the optimiser cannot merge it with `x % 10` into a variable
/// 64-bit division (tens of cycles on the hot path).
#[inline(always)]
fn rem40(x: u64) -> u64 {
    x - div5(x >> 3) * 40
}

/// `x % 10`, see [`rem40`].
#[inline(always)]
fn rem10(x: u64) -> u64 {
    x - div5(x >> 1) * 10
}

/// [`dc_time::encode_time_difference`] with the sign bit moved into place rather than
/// branched on.
#[inline(always)]
fn encode_time_difference_branch_free(local_minus_received_ns: i64) -> u32 {
    const SMALLER: u32 = dc_time::TIME_DIFFERENCE_LOCAL_SMALLER;
    let magnitude = local_minus_received_ns
        .unsigned_abs()
        .min(u64::from(!SMALLER)) as u32;
    let smaller = ((local_minus_received_ns as u64) >> 63) as u32;
    magnitude | (smaller * SMALLER)
}

/// Rounds half away from zero without a libm call.
#[inline]
fn round_fast(x: f64) -> i64 {
    if x >= 0.0 {
        (x + 0.5) as i64
    } else {
        (x - 0.5) as i64
    }
}

/// State of the DC unit.
///
/// `repr(C)` and laid out by cache line: line 0 holds what the cyclic frame's reads and the
/// SYNC0 deadline use, line 1 the time control loop's state, line 2 the clock's hot part;
/// the registers the cyclic frames never touch, and the clock's cold part, come after (see
/// [`crate::Esc`]'s layout: in a network of hundreds of drives, every line a cycle touches
/// per drive is missed in the cache).
#[derive(Debug, Clone)]
#[repr(C)]
pub struct DcUnit {
    // Line 0.
    sof_res: u64,
    sof_phase: u64,
    offset: u64,
    delay: u32,
    /// 0x092C as read: `dt_filtered` (local - received) rounded and sign-magnitude encoded, kept
    /// in step with it (the cyclic frame reads it from every slave).
    diff_register: u32,
    dt_filtered: f64,
    start_time: u64,
    /// Samples in the means of 0x092C and of the clock period deviation since the last reset
    /// (each counts up to its depth's `2^depth`).
    dt_count: u32,
    speed_count: u32,
    sync0_cycle: u32,
    is_64bit: bool,
    activation: u8,
    cyclic_control: u8,
    /// `last_sample_*` hold the previous write since the last reset.
    has_last_sample: bool,
    // Line 1: the time control loop, derived from the registers, kept so the hot path
    // divides nothing once the means are full.
    /// The weights of a full mean, `2^-depth` (0x0934, 0x0935).
    dt_weight: f64,
    speed_weight: f64,
    /// The phase step rate, `1 / (10 ns * (speed counter start + 2))`.
    slew_rate: f64,
    /// The largest frequency correction the speed counter diff's range allows (a fraction).
    deviation_max: f64,
    /// The previous write: when (ps), and the difference it aimed for.
    last_sample_ps: u64,
    last_sample_dt: f64,
    /// The clock period deviations' mean as its two sums: of each interval's deviation times
    /// its length (ns), and of the lengths (ns).
    deviation_sum_ns: f64,
    elapsed_sum_ns: f64,
    /// Line 2: its hot part first (one line), its crystal parameters and random generator
    /// after.
    clock: LocalClock,
    // Cold: the loop's registers (0x0930, 0x0934 and 0x0935 bits 3:0), the latches, the
    // cyclic unit's rest.
    speed_counter_start: u16,
    dt_filter_depth: u8,
    speed_filter_depth: u8,
    port_times: [u32; 4],
    pu_time: u64,
    pulse_length: u16,
    sync1_cycle: u32,
    sync0_status_cleared_at: Option<u64>,
    latch_mode: u8,
}

// The hot lines as laid out above.
const _: () = assert!(core::mem::offset_of!(DcUnit, dt_weight) == 64);
const _: () = assert!(core::mem::offset_of!(DcUnit, clock) == 128);

/// The low 32 bits of a little-endian value of up to 8 bytes (shorter values are zero-extended):
/// what the time control loop compares of a system time write.
#[inline]
fn low_u32(data: &[u8]) -> u32 {
    match data.get(..4) {
        Some(w) => u32::from_le_bytes([w[0], w[1], w[2], w[3]]),
        None => data
            .iter()
            .rev()
            .fold(0u32, |acc, &b| (acc << 8) | u32::from(b)),
    }
}

/// What a write to the DC block asks the segment to do beyond the unit itself.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DcWriteEffects {
    /// Receive Time Port 0 was written: latch this frame's receive times on all ports.
    pub latch_receive_times: bool,
}

impl DcUnit {
    /// A powered-up DC unit with datasheet defaults.
    pub fn new(params: DcParams) -> Self {
        Self::new_at(params, 0)
    }

    /// A DC unit switched on at real time `t_ps` (a power cycle): its local time starts from
    /// the crystal's `initial_local_ns` then.
    pub fn new_at(params: DcParams, t_ps: u64) -> Self {
        let clock = LocalClock::new_at(params.crystal, t_ps);
        let res = (params.sof_resolution_ns.max(10) / 10) * 10;
        let mut unit = DcUnit {
            sof_res: res,
            sof_phase: port_phase(&clock, 0, res),
            clock,
            is_64bit: params.is_64bit,
            offset: 0,
            delay: 0,
            speed_counter_start: SPEED_COUNTER_START_RESET,
            dt_filter_depth: 0,
            speed_filter_depth: 0,
            dt_filtered: 0.0,
            diff_register: 0,
            dt_weight: 1.0,
            speed_weight: 1.0,
            deviation_sum_ns: 0.0,
            elapsed_sum_ns: 0.0,
            slew_rate: 0.0,
            deviation_max: 0.0,
            has_last_sample: false,
            last_sample_ps: 0,
            last_sample_dt: 0.0,
            dt_count: 0,
            speed_count: 0,
            port_times: [0; 4],
            pu_time: 0,
            cyclic_control: 0,
            activation: 0,
            pulse_length: 0,
            start_time: 0,
            sync0_cycle: 0,
            sync1_cycle: 0,
            sync0_status_cleared_at: None,
            latch_mode: 0,
        };
        // Reset values (section II): 0x0930 = 0x1000, 0x0934 = 0x04, 0x0935 = 0x0C; the
        // loop's filters empty.
        unit.write_speed_counter_start(SPEED_COUNTER_START_RESET, t_ps);
        unit.set_dt_filter_depth(4);
        unit.set_speed_filter_depth(12);
        unit
    }

    /// The local clock.
    pub fn clock(&self) -> &LocalClock {
        &self.clock
    }

    /// Brings the clock's anchor to `t_ps` (wander steps, slews).
    pub fn advance_to(&mut self, t_ps: u64) {
        self.clock.advance_to(t_ps);
    }

    /// Local time (register view, quantised) at `t_ps`.
    pub fn local_ns(&self, t_ps: u64) -> u64 {
        let l = self.clock.local_ns(t_ps);
        if self.is_64bit { l } else { l & 0xffff_ffff }
    }

    /// Local copy of the system time (register view) at `t_ps`.
    pub fn system_time_ns(&self, t_ps: u64) -> u64 {
        let s = self.clock.local_ns(t_ps).wrapping_add(self.offset);
        if self.is_64bit { s } else { s & 0xffff_ffff }
    }

    /// The system time on the unit's 64-bit time line (register view, quantised): a 32-bit
    /// unit's register shows its lower half. SYNC0's pulses are on this line.
    fn system_time_full_ns(&self, t_ps: u64) -> u64 {
        self.clock.local_ns(t_ps).wrapping_add(self.offset)
    }

    /// System time at `t_ps` as (integer ns, fraction), unquantised (ground truth).
    pub fn system_time_split(&self, t_ps: u64) -> (u64, f64) {
        self.system_time_split_in::<false>(t_ps)
    }

    /// [`DcUnit::system_time_split`], branch-free if `BRANCH_FREE` (a large network's
    /// drives: [`LocalClock::advance_to_in`]); the same figures either way.
    #[inline]
    pub(crate) fn system_time_split_in<const BRANCH_FREE: bool>(&self, t_ps: u64) -> (u64, f64) {
        let (ns, frac) = self.clock.local_exact_ns_in::<BRANCH_FREE>(t_ps);
        (ns.wrapping_add(self.offset), frac)
    }

    /// Whether the system time is 64 bits wide (else 32).
    pub fn is_64bit(&self) -> bool {
        self.is_64bit
    }

    /// System time offset (0x0920).
    pub fn offset(&self) -> u64 {
        self.offset
    }

    /// System time delay (0x0928).
    pub fn delay(&self) -> u32 {
        self.delay
    }

    /// Filtered system time difference `local copy - received` in ns (what 0x092C shows,
    /// signed as [`dc_time::decode_time_difference`] decodes it).
    pub fn time_difference_ns(&self) -> f64 {
        self.dt_filtered
    }

    /// Latches receive times: `ports[p]` is the real time the frame's first bit reached port p,
    /// or `None` if it did not pass that port (the register keeps its old value); `pu_ps` the
    /// time it reached the processing unit. Each port stamps with its own resolution `res_ns`
    /// (40 ns on MII, whose 25 MHz receive clock samples the frame start; 10 ns on EBUS; datasheet
    /// section I, 18.14): the counter is sampled on that port's clock edges, so all its stamps
    /// share one residue. The processing unit's stamp is port 0's when `pu_is_port0`.
    pub fn latch(
        &mut self,
        ports: [Option<u64>; 4],
        pu_ps: u64,
        pu_is_port0: bool,
        res_ns: [u64; 4],
    ) {
        for (p, t) in ports.iter().enumerate() {
            if let Some(t) = t {
                let res = res_ns[p].max(10) / 10 * 10;
                let phase = port_phase(&self.clock, p, res);
                let q = if res == 40 {
                    self.on_crystal_grid(self.clock.local_exact_ns(*t).0, *t, phase)
                } else {
                    let v = self.clock.local_ns(*t);
                    v - (v.wrapping_sub(phase) % res)
                };
                self.port_times[p] = q as u32;
                if p == 0 && pu_is_port0 {
                    let mut pu = q;
                    if !self.is_64bit {
                        pu &= 0xffff_ffff;
                    }
                    self.pu_time = pu;
                }
            }
        }
        if !pu_is_port0 {
            self.pu_time = self.local_ns(pu_ps);
        }
    }

    /// Fills the shadow of the DC block (`block[0]` is register 0x0900) with the values registers
    /// in `range` (absolute addresses, half-open) read at `t_ps`.
    pub fn refresh(&mut self, block: &mut [u8; DC_BLOCK_LEN], lo: u16, hi: u16, t_ps: u64) {
        let overlaps = |a: u16, len: u16| lo < a + len && a < hi;
        let mut put = |addr: u16, bytes: &[u8]| {
            let at = usize::from(addr - DC_BLOCK_START);
            block[at..at + bytes.len()].copy_from_slice(bytes);
        };
        if overlaps(reg::DC_RECEIVE_TIME_PORT0, 16) {
            for p in 0..4 {
                put(
                    reg::DC_RECEIVE_TIME_PORT0 + 4 * p as u16,
                    &self.port_times[p].to_le_bytes(),
                );
            }
        }
        if overlaps(reg::DC_SYSTEM_TIME, 8) {
            self.clock.advance_to(t_ps);
            put(
                reg::DC_SYSTEM_TIME,
                &self.system_time_read_ns(t_ps).to_le_bytes(),
            );
        }
        if overlaps(reg::DC_RECEIVE_TIME_PU, 8) {
            put(reg::DC_RECEIVE_TIME_PU, &self.pu_time.to_le_bytes());
        }
        if overlaps(reg::DC_SYSTEM_TIME_OFFSET, 16) {
            put(reg::DC_SYSTEM_TIME_OFFSET, &self.offset.to_le_bytes());
            put(reg::DC_SYSTEM_TIME_DELAY, &self.delay.to_le_bytes());
            put(reg::DC_SYSTEM_TIME_DIFF, &self.diff_register.to_le_bytes());
        }
        if overlaps(reg::DC_SPEED_COUNTER_START, 7) {
            put(
                reg::DC_SPEED_COUNTER_START,
                &self.speed_counter_start.to_le_bytes(),
            );
            put(
                reg::DC_SPEED_COUNTER_DIFF,
                &self.speed_counter_diff().to_le_bytes(),
            );
            put(reg::DC_TIME_DIFF_FILTER_DEPTH, &[self.dt_filter_depth]);
            put(
                reg::DC_SPEED_COUNTER_FILTER_DEPTH,
                &[self.speed_filter_depth],
            );
            put(0x0936, &[self.latch_mode]);
        }
        if overlaps(reg::DC_CYCLIC_UNIT_CONTROL, 0x28) {
            self.clock.advance_to(t_ps);
            // SYNC0 on the unit's 64-bit time line; the registers show what the unit has.
            let now = self.system_time_full_ns(t_ps);
            let shown = if self.is_64bit { u64::MAX } else { 0xffff_ffff };
            put(reg::DC_CYCLIC_UNIT_CONTROL, &[self.cyclic_control]);
            put(reg::DC_ACTIVATION, &[self.activation]);
            put(reg::DC_PULSE_LENGTH, &self.pulse_length.to_le_bytes());
            let next0 = self.next_sync0_after(now);
            let status = if self.sync0_active() {
                let pending = next0.map(|n| n == self.first_sync0()).unwrap_or(true);
                u8::from(!pending) // bit 0: SYNC0 pulse has been generated
            } else {
                0
            };
            // 0x098E: bit 0 SYNC0 activated, bit 1 SYNC1 activated.
            let act = u8::from(self.sync0_active()) | u8::from(self.sync1_active()) << 1;
            put(reg::DC_ACTIVATION_STATUS, &[act]);
            put(reg::DC_SYNC0_STATUS, &[status]);
            let status1 = self
                .sync1()
                .is_some_and(|(first, _)| dc_time::diff_u64(now, first) >= 0);
            put(reg::DC_SYNC1_STATUS, &[u8::from(status1)]);
            let next0_v = if self.sync0_active() {
                next0.unwrap_or(0)
            } else {
                self.start_time
            };
            put(reg::DC_START_TIME, &(next0_v & shown).to_le_bytes());
            let next1 = if self.sync1_active() {
                self.next_sync1_after(now)
            } else {
                next0.map(|n| n.wrapping_add(u64::from(self.sync1_cycle)))
            };
            put(
                reg::DC_NEXT_SYNC1,
                &(next1.unwrap_or(0) & shown).to_le_bytes(),
            );
            put(reg::DC_SYNC0_CYCLE, &self.sync0_cycle.to_le_bytes());
            put(reg::DC_SYNC1_CYCLE, &self.sync1_cycle.to_le_bytes());
        }
    }

    /// A write of the System Time register (0x0910, `data` from its first byte): the time
    /// control loop compares bits 31:0.
    #[inline]
    pub fn write_system_time(&mut self, data: &[u8], t_ps: u64) {
        self.write_system_time_in::<false>(data, t_ps);
    }

    /// [`DcUnit::write_system_time`], the clock branch-free if `BRANCH_FREE` (a large
    /// network's drives: [`LocalClock::advance_to_in`]); the same figures either way.
    #[inline(always)]
    pub(crate) fn write_system_time_in<const BRANCH_FREE: bool>(&mut self, data: &[u8], t_ps: u64) {
        self.compare_system_time::<BRANCH_FREE>(low_u32(data), t_ps);
    }

    /// Applies a write of `data` to the registers at `addr..addr + data.len()` (absolute
    /// addresses within the DC block) at real time `t_ps`.
    pub fn write(&mut self, addr: u16, data: &[u8], t_ps: u64) -> DcWriteEffects {
        // The cyclic hot path: a system time write (FRMW/ARMW of 0x0910) touches nothing else.
        if addr == reg::DC_SYSTEM_TIME && data.len() <= 8 {
            self.compare_system_time::<false>(low_u32(data), t_ps);
            return DcWriteEffects::default();
        }
        let mut fx = DcWriteEffects::default();
        let lo = addr;
        let hi = addr + data.len() as u16;
        let byte = |a: u16| -> Option<u8> {
            if a >= lo && a < hi {
                Some(data[usize::from(a - lo)])
            } else {
                None
            }
        };
        // Merge written bytes over the current value of a register of `N` bytes.
        fn merge<const N: usize>(
            cur: [u8; N],
            at: u16,
            byte: &dyn Fn(u16) -> Option<u8>,
        ) -> [u8; N] {
            let mut v = cur;
            for (i, b) in v.iter_mut().enumerate() {
                if let Some(nb) = byte(at + i as u16) {
                    *b = nb;
                }
            }
            v
        }
        let touches = |a: u16, len: u16| lo < a + len && a < hi;

        if touches(reg::DC_RECEIVE_TIME_PORT0, 4) {
            fx.latch_receive_times = true;
        }
        if touches(reg::DC_SYSTEM_TIME_OFFSET, 8) {
            self.clock.advance_to(t_ps);
            self.offset = u64::from_le_bytes(merge(
                self.offset.to_le_bytes(),
                reg::DC_SYSTEM_TIME_OFFSET,
                &byte,
            ));
        }
        if touches(reg::DC_SYSTEM_TIME_DELAY, 4) {
            self.delay = u32::from_le_bytes(merge(
                self.delay.to_le_bytes(),
                reg::DC_SYSTEM_TIME_DELAY,
                &byte,
            ));
        }
        if touches(reg::DC_SPEED_COUNTER_START, 2) {
            let v = u16::from_le_bytes(merge(
                self.speed_counter_start.to_le_bytes(),
                reg::DC_SPEED_COUNTER_START,
                &byte,
            ));
            self.write_speed_counter_start(v, t_ps);
        }
        if let Some(b) = byte(reg::DC_TIME_DIFF_FILTER_DEPTH) {
            self.set_dt_filter_depth(b);
        }
        if let Some(b) = byte(reg::DC_SPEED_COUNTER_FILTER_DEPTH) {
            self.set_speed_filter_depth(b);
        }
        if let Some(b) = byte(0x0936) {
            self.latch_mode = b;
        }
        if let Some(b) = byte(reg::DC_CYCLIC_UNIT_CONTROL) {
            self.cyclic_control = b;
        }
        if touches(reg::DC_PULSE_LENGTH, 2) {
            self.pulse_length = u16::from_le_bytes(merge(
                self.pulse_length.to_le_bytes(),
                reg::DC_PULSE_LENGTH,
                &byte,
            ));
        }
        if touches(reg::DC_START_TIME, 8) {
            self.start_time = u64::from_le_bytes(merge(
                self.start_time.to_le_bytes(),
                reg::DC_START_TIME,
                &byte,
            ));
            if !self.is_64bit {
                self.start_time &= 0xffff_ffff;
            }
        }
        if touches(reg::DC_SYNC0_CYCLE, 4) {
            self.sync0_cycle = u32::from_le_bytes(merge(
                self.sync0_cycle.to_le_bytes(),
                reg::DC_SYNC0_CYCLE,
                &byte,
            ));
        }
        if touches(reg::DC_SYNC1_CYCLE, 4) {
            self.sync1_cycle = u32::from_le_bytes(merge(
                self.sync1_cycle.to_le_bytes(),
                reg::DC_SYNC1_CYCLE,
                &byte,
            ));
        }
        if let Some(b) = byte(reg::DC_ACTIVATION) {
            self.activate(b, t_ps);
        }
        if byte(reg::DC_SYSTEM_TIME).is_some() {
            // The comparison uses bits 31:0 of the written value (datasheet section I, 9.1.3.3);
            // it needs at least the first byte, unwritten low bytes count as zero.
            let mut v = [0u8; 4];
            for (i, b) in v.iter_mut().enumerate() {
                *b = byte(reg::DC_SYSTEM_TIME + i as u16).unwrap_or(0);
            }
            self.compare_system_time::<false>(u32::from_le_bytes(v), t_ps);
        }
        fx
    }

    fn sync0_active(&self) -> bool {
        self.activation & 0b11 == 0b11
    }

    fn activate(&mut self, b: u8, t_ps: u64) {
        let was = self.sync0_active();
        self.activation = b;
        if self.sync0_active() && !was {
            // Cyclic operation starts: if the start time already lies in the past, the ESC
            // waits until its 32-bit comparison matches again, i.e. one 2^32 ns wrap later
            // (datasheet: a start time in the past starts SYNC only after ~4.3 s).
            self.clock.advance_to(t_ps);
            let now = self.system_time_ns(t_ps);
            if !self.is_64bit {
                // A 32-bit unit starts where its 32-bit time next equals the start time. On
                // the unit's own time line, which the simulation keeps in 64 bits (the upper
                // half what the offset and the wraps so far put there): the pulses then go on
                // a cycle apart across the register's wraps, as the real counter's do, and
                // the first lies where the 32-bit comparison matches (a start taken as the
                // register's 32-bit value on the 64-bit line put every pulse 2^32 mod cycle
                // times the wraps off the grid the master computed).
                let full = self.system_time_full_ns(t_ps);
                let mut start = (full & !0xffff_ffff) | (self.start_time & 0xffff_ffff);
                if dc_time::diff_u64(start, full) <= 0 {
                    start = start.wrapping_add(1 << 32);
                }
                self.start_time = start;
            } else if dc_time::diff_u64(self.start_time, now) <= 0 {
                let behind = now.wrapping_sub(self.start_time);
                let wraps = behind / (1 << 32) + 1;
                self.start_time = self.start_time.wrapping_add(wraps << 32);
            }
            self.sync0_status_cleared_at = None;
        }
    }

    fn first_sync0(&self) -> u64 {
        self.start_time
    }

    /// The system time of the first SYNC0 pulse strictly after system time `s`, if SYNC0 runs.
    pub fn next_sync0_after(&self, s: u64) -> Option<u64> {
        if !self.sync0_active() {
            return None;
        }
        let since = dc_time::diff_u64(s, self.start_time);
        if since < 0 {
            return Some(self.start_time);
        }
        if self.sync0_cycle == 0 {
            return None; // single shot, already fired
        }
        let cyc = u64::from(self.sync0_cycle);
        let k = since as u64 / cyc + 1;
        Some(self.start_time.wrapping_add(k * cyc))
    }

    fn sync1_active(&self) -> bool {
        self.activation & 0b101 == 0b101
    }

    /// SYNC1 as the ESC generates it, if active (0x0981 bits 0 and 2): (first pulse, period),
    /// system time ns. The datasheet's rule (ESC datasheet section I, "SYNC1 signal"; TI's
    /// SPRUII0 words it the same): SYNC1 comes the SYNC1 cycle time `d` (0x09A4) after a SYNC0
    /// pulse, and the delay is measured anew only from the first SYNC0 pulse after that SYNC1
    /// pulse (the start's excepted). So with SYNC0 every `c`, SYNC1 comes every
    /// `(d / c + 1) c` at `start + d`: `d` under `c` delays each SYNC0 by `d`, `d = c (n - 1)`
    /// makes one SYNC1 per `n` SYNC0 (oversampling by `n`, the EL4732 set-up of ethercrab
    /// #368), and `d = 0` puts SYNC1 on every SYNC0. A single-shot SYNC0 (`c = 0`) has one.
    pub fn sync1(&self) -> Option<(u64, u64)> {
        if !self.sync1_active() {
            return None;
        }
        let (c, d) = (u64::from(self.sync0_cycle), u64::from(self.sync1_cycle));
        let period = d.checked_div(c).map_or(0, |n| (n + 1) * c);
        Some((self.start_time.wrapping_add(d), period))
    }

    /// [`DcUnit::sync1`] as a grid of pulses, (first, period ns), when it is one: a period
    /// of 0 (single shot) or past 32 bits is not.
    pub fn sync1_grid(&self) -> Option<(u64, u32)> {
        let (first, period) = self.sync1()?;
        let period = u32::try_from(period).ok().filter(|&p| p > 0)?;
        Some((first, period))
    }

    /// The system time of the first SYNC1 pulse strictly after system time `s`, if SYNC1 runs.
    pub fn next_sync1_after(&self, s: u64) -> Option<u64> {
        let (first, period) = self.sync1()?;
        let since = dc_time::diff_u64(s, first);
        if since < 0 {
            return Some(first);
        }
        if period == 0 {
            return None;
        }
        Some(first.wrapping_add((since as u64 / period + 1) * period))
    }

    /// SYNC0 configuration: (start time, cycle ns), if SYNC0 is active.
    pub fn sync0(&self) -> Option<(u64, u32)> {
        self.sync0_active()
            .then_some((self.start_time, self.sync0_cycle))
    }

    /// The system time as an ECAT read of 0x0910 returns it: the local copy at the frame's SOF
    /// minus the system time delay, i.e. the system time at which the frame passed the reference
    /// clock (datasheet section II, 0x0910 "including system time delay").
    pub fn system_time_read_ns(&self, t_ps: u64) -> u64 {
        let v = if self.sof_res == 40 {
            self.on_crystal_grid(self.clock.local_exact_ns(t_ps).0, t_ps, self.sof_phase)
        } else {
            self.sof(self.clock.local_ns(t_ps))
        };
        let v = v
            .wrapping_add(self.offset)
            .wrapping_sub(u64::from(self.delay));
        if self.is_64bit { v } else { v & 0xffff_ffff }
    }

    /// The local time as latched at a frame's start: the counter at the last edge of port 0's
    /// receive clock.
    #[inline]
    fn sof(&self, local: u64) -> u64 {
        let x = local.wrapping_sub(self.sof_phase);
        // Constant divisors for the two physical layers (a variable 64-bit division costs tens
        // of cycles on the hot path). Separate functions keep the optimiser from folding the
        // constant arms back into one variable division.
        let r = match self.sof_res {
            40 => rem40(x),
            10 => rem10(x),
            res => x % res,
        };
        local - r
    }

    /// What [`DcUnit::read_fast`] does for 0x092C: the time difference register into `out` (at
    /// most 4 bytes; longer reads are left alone), ORed for broadcast reads. The 4-byte BRD of
    /// the cyclic frame takes one word operation.
    #[inline]
    pub fn read_time_difference(&self, out: &mut [u8], or: bool) {
        if let Ok(word) = <&mut [u8; 4]>::try_from(&mut *out) {
            let cur = if or { u32::from_le_bytes(*word) } else { 0 };
            *word = (cur | self.diff_register).to_le_bytes();
        } else if out.len() < 4 {
            let v = self.diff_register.to_le_bytes();
            for (o, b) in out.iter_mut().zip(v) {
                *o = if or { *o | b } else { b };
            }
        }
    }

    /// The local time latched at the frame's start, at the clock's anchor: `sof` of the counter
    /// value. The SOF grid (`sof_phase` modulo `sof_res`) lies on the counter's 10 ns tick grid
    /// (see `port_phase`), so the latest SOF edge at or before the counter value is the latest
    /// at or before the unquantised time: the tick quantisation can be skipped whenever no
    /// subtraction wraps (local time from `sof_phase + 10` on, i.e. always but in the first
    /// instant after power-up).
    #[inline(always)]
    fn sof_at_anchor(&self) -> u64 {
        if self.sof_res == 40 {
            return self.on_crystal_grid(
                self.clock.anchor_ns(),
                self.clock.anchor_ps(),
                self.sof_phase,
            );
        }
        let raw = self.clock.anchor_ns();
        if raw >= self.sof_phase + 10 {
            self.sof(raw)
        } else {
            self.sof(self.clock.local_ns_at_anchor())
        }
    }

    /// The counter at the last edge of an MII port's 25 MHz receive clock at or before local
    /// time `local_ns` (whole nanoseconds) at real time `t_ps`: the edges are the ESC's crystal's, every fourth
    /// tick from `phase`, while the counter is the crystal's count plus the time control
    /// loop's corrections (the 9 and 11 ns steps). So a reference clock, never corrected,
    /// stamps on one residue modulo 40 ns for good (replay-dc: every FRMW the EK1100 answered
    /// reads 0 modulo 40), and a corrected clock's stamps move over the 40 ns as its
    /// corrections add up: a slave cannot steer its stamps' cells onto the reference's, and
    /// its 0x092C keeps the quantisation's ±40 ns (as the letter's rS-IS of 61-132 ns reads)
    /// where stamps on the corrected time let the loop hide it (0 or 40 ns).
    #[inline(always)]
    fn on_crystal_grid(&self, local_ns: u64, t_ps: u64, phase: u64) -> u64 {
        let back = rem40(self.clock.crystal_ns(t_ps).wrapping_sub(phase));
        self.clock.quantise(local_ns - back)
    }

    /// Reads the registers the cyclic frame reads (0x0910 by ARMW/FRMW/FPRD, 0x092C by BRD or
    /// FPRD) without going through the register shadow. Returns `false` for anything else.
    #[inline]
    pub fn read_fast(&mut self, addr: u16, out: &mut [u8], or: bool, t_ps: u64) -> bool {
        let v: [u8; 8] = if addr == reg::DC_SYSTEM_TIME && out.len() <= 8 {
            self.clock.advance_to(t_ps);
            let mut s = self.sof_at_anchor().wrapping_add(self.offset);
            s = s.wrapping_sub(u64::from(self.delay));
            if !self.is_64bit {
                s &= 0xffff_ffff;
            }
            s.to_le_bytes()
        } else if addr == reg::DC_SYSTEM_TIME_DIFF && out.len() <= 4 {
            let mut v = [0u8; 8];
            v[..4].copy_from_slice(&self.diff_register.to_le_bytes());
            v
        } else {
            return false;
        };
        match (out.len(), or) {
            (8, false) => out.copy_from_slice(&v),
            (4, false) => out.copy_from_slice(&v[..4]),
            (_, false) => {
                let n = out.len();
                out.copy_from_slice(&v[..n]);
            }
            (_, true) => out.iter_mut().zip(v).for_each(|(o, b)| *o |= b),
        }
        true
    }

    #[inline]
    fn set_dt_filtered(&mut self, v: f64) {
        self.set_dt_filtered_in::<false>(v);
    }

    /// `BRANCH_FREE`: the register's sign bit set without a branch (a large network's
    /// drives, whose differences change sign from cycle to cycle: see
    /// `LocalClock::advance_to_in`).
    #[inline(always)]
    fn set_dt_filtered_in<const BRANCH_FREE: bool>(&mut self, v: f64) {
        self.dt_filtered = v;
        let ns = round_fast(v);
        self.diff_register = if BRANCH_FREE {
            encode_time_difference_branch_free(ns)
        } else {
            dc_time::encode_time_difference(ns)
        };
    }
}

mod control_loop;

pub use control_loop::{speed_counter_deviation, speed_counter_diff_for};

/// The largest crystal difference to the reference the time control loop follows at the
/// Speed Counter Start a master writes (the reset value 0x1000), ppm: the deviation of the
/// largest Speed Counter Diff, `±(start − 0x7F)` (datasheet section II, 0x0932).
pub fn max_following_ppm() -> f64 {
    let start = control_loop::SPEED_COUNTER_START_RESET;
    let diff = f64::from(control_loop::speed_counter_diff_max(start));
    speed_counter_deviation(start, diff) * 1e6
}

#[cfg(test)]
mod tests;
