//! Issue 30, edge 3: a junction declared without a device is a coupler (an ET1100 with four
//! ports branches the line, it drives no motor), a coupler has no SYNC0 deadline in the ground
//! truth, and the per-slave tables name the slaves as the file does.

use ecsync_lab::report::{csv, per_slave_text, summarize};
use std::sync::atomic::AtomicU64;

/// A tree: drive "left-1" on the master, junction "junction-a" after it (no device given), two
/// drives on the junction's ports 1 and 3.
const TREE: &str = r#"
[segment]
seed = 7

[[segment.slave]]
name = "left-1"
model = "servo-mii"
upstream = "master"
cable_m = 2.0
ppm = 10.0

[[segment.slave]]
name = "junction-a"
model = "junction-mii"
upstream = "left-1"
upstream_port = 1
cable_m = 1.0
ppm = -20.0

[[segment.slave]]
name = "branch-b"
model = "servo-mii"
upstream = "junction-a"
upstream_port = 1
cable_m = 3.0
ppm = 30.0

[[segment.slave]]
name = "branch-c"
model = "servo-mii"
upstream = "junction-a"
upstream_port = 3
cable_m = 0.5
ppm = -5.0

[run]
cycle_us = 1000
sync0_shift_pct = 30
runs = 1
cycles = 3000
warmup_s = 2
static_drift_frames = 2000
methods = ["median-fit"]

[methods.median-fit]
init_frames = 1000
"#;

#[test]
fn a_junction_without_device_is_a_coupler_with_no_process_data() {
    let s = ecsync_lab::parse("tree.toml", TREE).expect("the tree parses");
    let j = &s.slaves[1];
    // A coupler: no process data (a servo drive would have 16 + 18 bytes), the EK1100 identity.
    assert_eq!(j.device.output_bytes() + j.device.input_bytes(), 0);
    assert_eq!(j.device.product_code, 0x0000_1100);
    // The drives stay drives.
    assert_eq!(s.slaves[0].device.output_bytes(), 16);
    assert_eq!(
        s.slave_names,
        ["left-1", "junction-a", "branch-b", "branch-c"]
    );
    // Asked for explicitly, a junction can still be a drive.
    let as_drive = TREE.replacen(
        "model = \"junction-mii\"",
        "model = \"junction-mii\"\ndevice = \"servo-drive\"",
        1,
    );
    let s = ecsync_lab::parse("tree.toml", &as_drive).expect("parses");
    assert_eq!(s.slaves[1].device.output_bytes(), 16);
}

#[test]
fn couplers_get_no_sync0_rows_and_tables_name_the_slaves() {
    let s = ecsync_lab::parse("tree.toml", TREE).expect("the tree parses");
    let c = ecsync_lab::compare(&s, 1, &AtomicU64::new(0)).expect("the comparison runs");
    let out = summarize(&c);
    let g = &out.methods["median-fit"].ground_truth;
    // Positions follow the wire: left-1 (0), junction-a (1), then the junction's ports in the
    // order a frame passes them (0, 3, 1, 2: ESC datasheet, frame processing order), so the
    // port 3 branch before the port 1 one. Only the three drives have a SYNC0 deadline.
    let rows: Vec<(u16, &str)> = g
        .per_slave
        .iter()
        .map(|r| (r.position, r.name.as_str()))
        .collect();
    assert_eq!(rows, [(0, "left-1"), (2, "branch-c"), (3, "branch-b")]);
    let text = per_slave_text(&out);
    for name in ["left-1", "branch-b", "branch-c"] {
        assert!(text.contains(name), "{name} missing in\n{text}");
    }
    assert!(
        !text.contains("junction-a"),
        "the coupler has a row:\n{text}"
    );
    let table = csv(&out, &["median-fit".to_string()]);
    assert!(table.contains("\nmedian-fit,branch-b,3,"), "{table}");
}
