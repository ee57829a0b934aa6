//! Built-in segment descriptions.
//!
//! The built-in scenario files are embedded from the repository's top-level `presets/` folder,
//! the one place they are kept: the files users read, copy and edit are the ones the binary runs.

pub use crate::clock::CRYSTAL_WANDER_PPM_PER_SQRT_S;
use crate::clock::CrystalParams;
use crate::model::{DeviceInfo, EscModel};
use crate::segment::{SlaveSpec, Upstream};

/// The `paper-2024` preset file (the repository's `presets/paper-2024.toml`, for users to copy).
pub const PAPER_2024_TOML: &str = include_str!("../../../presets/paper-2024.toml");

/// The letter's testbed: six DC servo drives in a line, 100BASE-TX ports, about 1.5 m of cable
/// from the reference to the last slave, crystals within +-50 ppm. Read from
/// [`PAPER_2024_TOML`], which documents every number.
pub fn paper_2024() -> Vec<SlaveSpec> {
    crate::config::parse_segment("presets/paper-2024.toml", PAPER_2024_TOML)
        .expect("the built-in preset is valid")
}

/// The `twelve-drives` preset file (the repository's `presets/twelve-drives.toml`).
pub const TWELVE_DRIVES_TOML: &str = include_str!("../../../presets/twelve-drives.toml");

/// The `akd` preset file (the repository's `presets/akd.toml`): two drives like the
/// Kollmorgen AKD (the `akd` device family).
pub const AKD_TOML: &str = include_str!("../../../presets/akd.toml");

/// The `lan9252-pair` preset file (the repository's `presets/lan9252-pair.toml`): two
/// Microchip LAN9252 boards over 100BASE-TX (the `lan9252` device family).
pub const LAN9252_PAIR_TOML: &str = include_str!("../../../presets/lan9252-pair.toml");

/// The `ek1100-el2828-el2889` preset file (the repository's `presets/ek1100-el2828-el2889.toml`):
/// the network of the captures of real hardware in `../shared/captures/`.
pub const EK1100_EL2828_EL2889_TOML: &str =
    include_str!("../../../presets/ek1100-el2828-el2889.toml");

/// The `oversampling` preset file (the repository's `presets/oversampling.toml`): a coupler,
/// an oversampling analog output terminal on SYNC1 and a servo drive on SYNC0.
pub const OVERSAMPLING_TOML: &str = include_str!("../../../presets/oversampling.toml");

/// Every built-in network (a scenario with a `[segment]`), by the name of its file in
/// `presets/`.
pub const NETWORKS: [(&str, &str); 6] = [
    ("paper-2024", PAPER_2024_TOML),
    ("twelve-drives", TWELVE_DRIVES_TOML),
    ("akd", AKD_TOML),
    ("lan9252-pair", LAN9252_PAIR_TOML),
    ("ek1100-el2828-el2889", EK1100_EL2828_EL2889_TOML),
    ("oversampling", OVERSAMPLING_TOML),
];

/// Looks up a built-in network by name: its TOML text.
pub fn named(name: &str) -> Option<&'static str> {
    NETWORKS.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}

/// The built-in networks' names, for messages.
pub fn names() -> String {
    NETWORKS.map(|(n, _)| n).join(", ")
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
                upstream: Upstream::in_line(i),
                entry_port: 0,
                cable_m: 1.0,
                ring: None,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_2024_is_the_letters_testbed() {
        let s = paper_2024();
        assert_eq!(s.len(), 6);
        let ref_to_last: f64 = s[1..].iter().map(|x| x.cable_m).sum();
        assert!(
            (ref_to_last - 1.5).abs() < 1e-9,
            "1.5 m from the reference to the last slave"
        );
        assert!(s.iter().all(|x| x.crystal.ppm.abs() <= 50.0));
        let pd: usize = s
            .iter()
            .map(|x| x.device.output_bytes() + x.device.input_bytes())
            .sum();
        assert_eq!(pd, 204, "the letter's 204 bytes of process data");
    }
}
