//! Random networks for the tests: lines and trees of servo drives with a coupler in some,
//! crystals within +-50 ppm, on the loaded PREEMPT_RT host (the file `random_networks.rs`
//! and `more_methods.rs` include).

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use std::fmt::Write as _;

/// A random network as a scenario file: `n` drives, a junction with up to three branches in
/// some of them, crystals and the master's within +-50 ppm.
pub fn network(rng: &mut ChaCha8Rng, n: usize) -> String {
    let mut t = String::from("[segment]\n");
    let _ = writeln!(t, "seed = {}", rng.random::<u32>());
    let mut names: Vec<String> = Vec::new();
    // Where the next drive of a branch attaches: (upstream name, port).
    let mut tails: Vec<(String, u8)> = vec![("master".into(), 0)];
    let junction_at = if n >= 4 && rng.random_bool(0.5) {
        Some(rng.random_range(1..n - 2))
    } else {
        None
    };
    for i in 0..n {
        let name = format!("s{i}");
        let k = rng.random_range(0..tails.len());
        let (up, port) = tails[k].clone();
        let is_junction = junction_at == Some(i);
        let model = if is_junction {
            "junction-mii"
        } else {
            "servo-mii"
        };
        let device = if is_junction {
            "coupler"
        } else {
            "servo-drive"
        };
        let _ = writeln!(
            t,
            "[[segment.slave]]\nname = \"{name}\"\nmodel = \"{model}\"\ndevice = \"{device}\"\nupstream = \"{up}\""
        );
        if up != "master" {
            let _ = writeln!(t, "upstream_port = {port}");
        }
        let _ = writeln!(
            t,
            "cable_m = {:.2}\nppm = {:.3}\npower_up_ns = {}",
            rng.random_range(0.2..20.0),
            rng.random_range(-50.0..50.0),
            rng.random_range(1_000_000_000u64..4_000_000_000)
        );
        // This drive's free ports continue its branch (a junction opens three).
        tails.remove(k);
        if is_junction {
            for p in 1..=3 {
                tails.push((name.clone(), p));
            }
        } else {
            tails.push((name.clone(), 1));
        }
        names.push(name);
    }
    let master = rng.random_range(-50.0..50.0);
    let _ = write!(
        t,
        "[host]\npreset = \"preempt-rt-stress\"\nmaster_ppm = {master:.3}\n\
[run]\ncycle_us = 1000\nsync0_shift_pct = 30\nruns = 1\ncycles = 12000\nwarmup_s = 10.5\n\
seed = {}\nmethods = [\"median\", \"median-fit\"]\nstatic_drift_frames = 15000\n",
        rng.random::<u32>()
    );
    t
}
