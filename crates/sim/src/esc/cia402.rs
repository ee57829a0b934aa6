//! The servo drive's application: the CiA 402 device profile (IEC 61800-7-201, ETG.6010) on the
//! process data as the master mapped it (0x1C12/0x1C13 and the mappings they name).
//!
//! What it does, each time the outputs pass it (once a cycle):
//! - the state machine of the controlword 0x6040 (ETG.6010 section 4, "Device control"):
//!   Shutdown (xxxx xxxx 0xxx x110) to Ready to switch on, Switch on (0xxx 0111) to Switched
//!   on, Enable operation (0xxx 1111) to Operation enabled (from Ready to switch on as well,
//!   through Switched on: transitions 3 and 4 in two cycles, as drives accept them), Disable
//!   voltage (0xxx xx0x) and Quick stop (0xxx x01x) to Switch on disabled, Fault reset (bit
//!   7's rising edge) out of Fault; below OP the drive has no valid outputs and is in Switch on
//!   disabled;
//! - the statusword 0x6041 of the state (bits 0-6 as the profile's table, bit 9 remote, bit 12
//!   "drive follows the command value" in cyclic synchronous modes while operation is enabled);
//! - the modes of operation display 0x6061 = the modes of operation 0x6060 (cyclic synchronous
//!   position 8 if not mapped);
//! - cyclic synchronous position: the drive takes the target position 0x607A at its SYNC0 and
//!   reaches it by the next cycle, so the position actual value 0x6064 is the target of the
//!   cycle before; the following error 0x60F4 is the target now minus the position actual;
//!   the velocity actual value 0x606C is the position's change per cycle scaled to counts per
//!   second (the cycle time of 0x1C32:02). Without operation enabled the position holds.
//!
//! When it runs: the application steps as the frame's inputs pass the drive, once a cycle, not
//! at the SYNC0 pulse itself. For frames before their SYNC0 (every frame the comparison calls
//! on time) this is the same thing: the target taken is the one the pulse would take and the
//! inputs read are those copied for the next frame. A late frame's target takes effect with
//! that frame instead of at the next pulse (a real drive would run one cycle on the old
//! target); the SYNC0 deadline itself, what 0x1C32:0B counts, is kept by the pulse (sync.rs).
//!
//! Assumptions, written down: an ideal axis (no dynamics beyond the one cycle of latency, no
//! limits, no torque: 0x6077 stays 0); entries not named here (vendor objects, padding) keep
//! zeros; entries must be whole bytes. A device without 0x6040 and 0x6041 mapped is not a
//! drive: the ESC's loopback application runs instead.

use ecsync_wire::AlState;

/// No such entry mapped.
const NONE: u32 = u32::MAX;

/// Where the drive's objects are in the process RAM (byte offsets), as the mapping lays them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct DrivePlan {
    controlword: u32,
    modes: u32,
    target_position: u32,
    statusword: u32,
    modes_display: u32,
    position_actual: u32,
    velocity_actual: u32,
    following_error: u32,
    /// The cycle time, ns (0x1C32:02), for the velocity's scale.
    cycle_ns: u32,
}

/// The drive's state (CiA 402 "power drive system" states).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) enum DriveState {
    #[default]
    SwitchOnDisabled,
    ReadyToSwitchOn,
    SwitchedOn,
    OperationEnabled,
    Fault,
}

/// What the drive keeps from one cycle to the next.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct DriveMemory {
    state: DriveState,
    last_controlword: u16,
    /// The target position taken at the last cycle, counts.
    demand: i32,
    /// The position actual value, counts.
    position: i32,
    /// The inputs as last written (statusword, mode, position, velocity, following error):
    /// the same again is not written again (the input buffer is the application's alone).
    written: Option<(u16, i8, i32, i32, i32)>,
}

impl DriveMemory {
    /// The input buffer moved or was cleared: the next cycle writes every input.
    pub(super) fn inputs_lost(&mut self) {
        self.written = None;
    }
}

impl DrivePlan {
    /// The plan for outputs `rx` and inputs `tx` ((index, subindex, bits) in mapping order)
    /// whose buffers start at RAM offsets `out_at` and `in_at`; `None` if the mapping is not a
    /// drive's or not in whole bytes.
    pub(super) fn new(
        rx: &[(u16, u8, u8)],
        tx: &[(u16, u8, u8)],
        out_at: usize,
        in_at: usize,
        cycle_ns: u32,
    ) -> Option<DrivePlan> {
        let find = |list: &[(u16, u8, u8)], base: usize, index: u16, bits: u8| -> Option<u32> {
            let mut at = 0usize;
            for &(i, _, b) in list {
                if b % 8 != 0 {
                    return None;
                }
                if i == index && b == bits {
                    return Some((base + at / 8) as u32);
                }
                at += usize::from(b);
            }
            Some(NONE)
        };
        let whole = |list: &[(u16, u8, u8)]| list.iter().all(|e| e.2 % 8 == 0);
        if !whole(rx) || !whole(tx) {
            return None;
        }
        let plan = DrivePlan {
            controlword: find(rx, out_at, 0x6040, 16)?,
            modes: find(rx, out_at, 0x6060, 8)?,
            target_position: find(rx, out_at, 0x607a, 32)?,
            statusword: find(tx, in_at, 0x6041, 16)?,
            modes_display: find(tx, in_at, 0x6061, 8)?,
            position_actual: find(tx, in_at, 0x6064, 32)?,
            velocity_actual: find(tx, in_at, 0x606c, 32)?,
            following_error: find(tx, in_at, 0x60f4, 32)?,
            cycle_ns,
        };
        (plan.controlword != NONE && plan.statusword != NONE).then_some(plan)
    }
}

fn get_u16(ram: &[u8], at: u32) -> Option<u16> {
    let at = at as usize;
    Some(u16::from_le_bytes(ram.get(at..at + 2)?.try_into().ok()?))
}

fn get_i32(ram: &[u8], at: u32) -> Option<i32> {
    let at = at as usize;
    Some(i32::from_le_bytes(ram.get(at..at + 4)?.try_into().ok()?))
}

fn put(ram: &mut [u8], at: u32, bytes: &[u8]) {
    let at = at as usize;
    if let Some(d) = ram.get_mut(at..at + bytes.len()) {
        d.copy_from_slice(bytes);
    }
}

/// The state after controlword `cw` (the last cycle's was `last`) in state `s`.
fn next_state(s: DriveState, cw: u16, last: u16) -> DriveState {
    use DriveState::*;
    if s == Fault {
        // Fault reset: bit 7's rising edge.
        return if cw & 0x80 != 0 && last & 0x80 == 0 {
            SwitchOnDisabled
        } else {
            Fault
        };
    }
    if cw & 0x0082 == 0x0000 || cw & 0x0086 == 0x0002 {
        // Disable voltage; quick stop (taken at once by an ideal axis).
        return SwitchOnDisabled;
    }
    match (s, cw & 0x008f) {
        (SwitchOnDisabled | SwitchedOn | OperationEnabled, c) if c & 0x87 == 0x06 => {
            ReadyToSwitchOn
        }
        (ReadyToSwitchOn, 0x07 | 0x0f) => SwitchedOn,
        (SwitchedOn, 0x0f) => OperationEnabled,
        (OperationEnabled, 0x07) => SwitchedOn,
        (s, _) => s,
    }
}

fn statusword(s: DriveState, csp: bool) -> u16 {
    // Bit 4 voltage enabled, bit 5 quick stop (1: not active), bit 9 remote.
    match s {
        DriveState::SwitchOnDisabled => 0x0250,
        DriveState::ReadyToSwitchOn => 0x0231,
        DriveState::SwitchedOn => 0x0233,
        DriveState::OperationEnabled if csp => 0x1237,
        DriveState::OperationEnabled => 0x0237,
        DriveState::Fault => 0x0218,
    }
}

/// One cycle of the drive: the outputs in `ram` read, its inputs written.
#[inline]
pub(super) fn step(ram: &mut [u8], p: &DrivePlan, al_state: AlState, m: &mut DriveMemory) {
    let cw = get_u16(ram, p.controlword).unwrap_or(0);
    if al_state != AlState::Op {
        m.state = DriveState::SwitchOnDisabled;
        m.last_controlword = 0;
    } else if cw != m.last_controlword || m.state != DriveState::OperationEnabled {
        // (Operation enabled under the same controlword stays so: the common cycle skips
        // the table.)
        m.state = next_state(m.state, cw, m.last_controlword);
        m.last_controlword = cw;
    }
    let mode = if p.modes == NONE {
        8
    } else {
        ram.get(p.modes as usize).map_or(0, |&b| b as i8)
    };
    // Cyclic synchronous position (8); the other cyclic modes (9 velocity, 10 torque) hold the
    // position here.
    let before = m.position;
    let mut following = 0i32;
    if m.state == DriveState::OperationEnabled && mode == 8 {
        let target = get_i32(ram, p.target_position).unwrap_or(m.demand);
        m.position = m.demand;
        m.demand = target;
        following = target.wrapping_sub(m.position);
    } else {
        // Not following: the demand is where the axis stands (no jump when enabled again).
        m.demand = m.position;
    }
    let per_cycle = i64::from(m.position.wrapping_sub(before));
    let velocity = match p.cycle_ns {
        0 => 0,
        1_000_000 => per_cycle * 1_000,
        c => per_cycle * 1_000_000_000 / i64::from(c),
    } as i32;
    let sw = statusword(m.state, (8..=10).contains(&mode));
    let now = (sw, mode, m.position, velocity, following);
    if m.written == Some(now) {
        return;
    }
    m.written = Some(now);
    put(ram, p.statusword, &sw.to_le_bytes());
    if p.modes_display != NONE {
        put(ram, p.modes_display, &[mode as u8]);
    }
    if p.position_actual != NONE {
        put(ram, p.position_actual, &m.position.to_le_bytes());
    }
    if p.velocity_actual != NONE {
        put(ram, p.velocity_actual, &velocity.to_le_bytes());
    }
    if p.following_error != NONE {
        put(ram, p.following_error, &following.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The servo drive's default mapping (model.rs): outputs controlword, modes, padding,
    /// target position, target velocity, torque, touch probe; inputs statusword, modes
    /// display, padding, position, velocity, torque, following error.
    fn default_plan() -> DrivePlan {
        let rx = [
            (0x6040, 0, 16),
            (0x6060, 0, 8),
            (0, 0, 8),
            (0x607a, 0, 32),
            (0x60ff, 0, 32),
            (0x6071, 0, 16),
            (0x60b8, 0, 16),
        ];
        let tx = [
            (0x6041, 0, 16),
            (0x6061, 0, 8),
            (0, 0, 8),
            (0x6064, 0, 32),
            (0x606c, 0, 32),
            (0x6077, 0, 16),
            (0x60f4, 0, 32),
        ];
        DrivePlan::new(&rx, &tx, 0, 64, 1_000_000).unwrap()
    }

    fn cycle(ram: &mut [u8], p: &DrivePlan, m: &mut DriveMemory, cw: u16, target: i32) -> u16 {
        ram[0..2].copy_from_slice(&cw.to_le_bytes());
        ram[2] = 8;
        ram[4..8].copy_from_slice(&target.to_le_bytes());
        step(ram, p, AlState::Op, m);
        u16::from_le_bytes([ram[64], ram[65]])
    }

    #[test]
    fn the_state_machine_and_csp_worked_out_by_hand() {
        let p = default_plan();
        let mut ram = vec![0u8; 128];
        let mut m = DriveMemory::default();
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x0000, 0), 0x0250);
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x0006, 0), 0x0231);
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x0007, 0), 0x0233);
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x000f, 0), 0x1237);
        // Position actual: the target one cycle before; following error: target - actual;
        // velocity: 100 counts per 1 ms cycle = 100 000 counts/s.
        for k in 1..=5 {
            cycle(&mut ram, &p, &mut m, 0x000f, 100 * k);
        }
        let i32_at = |r: &[u8], a: usize| i32::from_le_bytes(r[a..a + 4].try_into().unwrap());
        assert_eq!(i32_at(&ram, 68), 400, "position actual");
        assert_eq!(i32_at(&ram, 72), 100_000, "velocity actual");
        assert_eq!(i32_at(&ram, 78), 100, "following error");
        assert_eq!(ram[66], 8, "modes display");
        // Disable operation holds the position; quick stop to switch on disabled.
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x0007, 900), 0x0233);
        assert_eq!(i32_at(&ram, 68), 400);
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x000b, 900), 0x0250);
        // Enabled again: no jump to the old demand.
        cycle(&mut ram, &p, &mut m, 0x0006, 900);
        cycle(&mut ram, &p, &mut m, 0x000f, 900);
        assert_eq!(cycle(&mut ram, &p, &mut m, 0x000f, 900), 0x1237);
        assert_eq!(i32_at(&ram, 68), 400);
        cycle(&mut ram, &p, &mut m, 0x000f, 950);
        assert_eq!(i32_at(&ram, 68), 900);
        // Below OP: switch on disabled.
        step(&mut ram, &p, AlState::SafeOp, &mut m);
        assert_eq!(u16::from_le_bytes([ram[64], ram[65]]), 0x0250);
    }

    #[test]
    fn a_mapping_without_the_drive_words_is_no_drive() {
        assert!(DrivePlan::new(&[(0x7000, 1, 8)], &[(0x6000, 1, 8)], 0, 8, 1).is_none());
        // Bits that are not whole bytes: not planned.
        assert!(
            DrivePlan::new(
                &[(0x6040, 0, 16), (0x7000, 1, 1)],
                &[(0x6041, 0, 16)],
                0,
                8,
                1
            )
            .is_none()
        );
        // Another order: the offsets follow the mapping.
        let p = DrivePlan::new(
            &[(0x607a, 0, 32), (0x6040, 0, 16)],
            &[(0x6064, 0, 32), (0x6041, 0, 16)],
            0x100,
            0x200,
            1_000_000,
        )
        .unwrap();
        assert_eq!((p.target_position, p.controlword), (0x100, 0x104));
        assert_eq!((p.position_actual, p.statusword), (0x200, 0x204));
        assert_eq!(p.modes, NONE);
    }
}
