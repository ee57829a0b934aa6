//! Built-in segment descriptions.

use crate::clock::CrystalParams;
use crate::model::{DeviceInfo, EscModel};
use crate::segment::{SlaveSpec, Upstream};

/// Crystal errors of the six drives of the `paper-2024` preset, ppm. Drawn once, uniformly within
/// the +-50 ppm the letter's drives are specified to (an ESC needs 25 ppm or better per the
/// datasheet, section I 17.1; cheap drives with a +-50 ppm crystal sit at the edge).
pub const PAPER_2024_PPM: [f64; 6] = [12.4, -31.7, 44.1, -8.6, 27.9, -46.2];

/// Power-up local times of the six drives, ns (they were switched on at different instants).
pub const PAPER_2024_POWER_UP_NS: [u64; 6] = [
    3_141_592_653,
    2_718_281_828,
    1_414_213_562,
    1_732_050_807,
    2_236_067_977,
    1_618_033_988,
];

/// Cable from the master to the first drive, m.
pub const PAPER_2024_MASTER_CABLE_M: f64 = 2.0;
/// Cable between neighbouring drives, m: 5 x 0.3 m = 1.5 m from the reference to the last slave,
/// as in the letter's testbed.
pub const PAPER_2024_DRIVE_CABLE_M: f64 = 0.3;

/// Random-walk wander of every crystal, ppm per sqrt(s): a few parts per billion over seconds,
/// typical of an uncompensated quartz at constant temperature.
pub const CRYSTAL_WANDER_PPM_PER_SQRT_S: f64 = 0.005;

/// The letter's testbed: six DC servo drives in a line, 100BASE-TX ports, about 1.5 m of cable
/// from the reference to the last slave, crystals within +-50 ppm.
pub fn paper_2024() -> Vec<SlaveSpec> {
    (0..6)
        .map(|i| SlaveSpec {
            model: EscModel::servo_mii(),
            device: DeviceInfo::servo_drive(0x2024_0001 + i as u32),
            crystal: CrystalParams {
                ppm: PAPER_2024_PPM[i],
                wander_ppm_per_sqrt_s: CRYSTAL_WANDER_PPM_PER_SQRT_S,
                wander_step_ps: 10_000_000_000,
                initial_local_ns: PAPER_2024_POWER_UP_NS[i],
                seed: 0x5eed_0000 + i as u64,
            },
            upstream: if i == 0 {
                Upstream::Master
            } else {
                Upstream::Slave {
                    index: i - 1,
                    port: 1,
                }
            },
            entry_port: 0,
            cable_m: if i == 0 {
                PAPER_2024_MASTER_CABLE_M
            } else {
                PAPER_2024_DRIVE_CABLE_M
            },
        })
        .collect()
}

/// A line of `n` servo drives with crystals from a seeded spread of +-50 ppm.
pub fn line(n: usize, seed: u64) -> Vec<SlaveSpec> {
    let mut x = seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1;
    let mut next = move || {
        // xorshift64*: a tiny deterministic spread, enough for a preset.
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    };
    (0..n)
        .map(|i| {
            let r = next();
            SlaveSpec {
                model: EscModel::servo_mii(),
                device: DeviceInfo::servo_drive(i as u32 + 1),
                crystal: CrystalParams {
                    ppm: ((r >> 11) as f64 / (1u64 << 53) as f64) * 100.0 - 50.0,
                    initial_local_ns: 1_000_000_000 + (r % 2_000_000_000),
                    seed: seed ^ (i as u64),
                    ..Default::default()
                },
                upstream: if i == 0 {
                    Upstream::Master
                } else {
                    Upstream::Slave {
                        index: i - 1,
                        port: 1,
                    }
                },
                entry_port: 0,
                cable_m: 1.0,
            }
        })
        .collect()
}
