//! A line of servo drives as a scenario file: a network whose cycle takes several frames.

use std::fmt::Write as _;

/// A line of `n` servo drives with a `cycle_us` cycle, SYNC0 at 90 %.
pub fn line(n: usize, cycle_us: u32) -> String {
    let mut t = String::from("[segment]\nseed = 7\n");
    let mut up = "master".to_string();
    for i in 0..n {
        let name = format!("d{i}");
        let _ = writeln!(
            t,
            "[[segment.slave]]\nname = \"{name}\"\nmodel = \"servo-mii\"\ndevice = \"servo-drive\"\nupstream = \"{up}\"\ncable_m = 1.0\nppm = {:.1}",
            (i as f64 * 7.3) % 80.0 - 40.0
        );
        if up != "master" {
            let _ = writeln!(t, "upstream_port = 1");
        }
        up = name;
    }
    let _ = write!(
        t,
        "[host]\npreset = \"preempt-rt-idle\"\n\
[run]\ncycle_us = {cycle_us}\nsync0_shift_pct = 90\nruns = 1\ncycles = 1500\nwarmup_s = 1\n\
seed = 3\nmethods = [\"soem-pi\", \"dcm-master-shift\"]\nstatic_drift_frames = 2000\n"
    );
    t
}
