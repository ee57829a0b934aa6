//! SOEM (pysoem from PyPI) against `ecsync serve` over the veth pair.

use super::*;

/// A Python that has pysoem: `ECSYNC_PYSOEM_PYTHON`, else the `python3` on the path; a panic
/// saying how to get one where there is none (the tests that need it are ignored unless asked
/// for, and asked for they must not pass without it).
pub(super) fn python() -> String {
    let py = std::env::var("ECSYNC_PYSOEM_PYTHON").unwrap_or_else(|_| "python3".into());
    let ok = Command::new(&py)
        .args(["-c", "import pysoem"])
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        ok,
        "this test needs pysoem, and {py} has none: pip install pysoem, or set ECSYNC_PYSOEM_PYTHON to a Python that has it (.ci/run makes a venv)"
    );
    py
}

#[test]
#[ignore = "needs network namespaces (root), pysoem"]
fn soem_scans_the_drives_over_coe_lists_their_dictionary_and_runs_them_in_op() {
    // SOEM waits for its frames spinning on a core: not beside a timed run on this
    // two-core machine.
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let py = python();
    let pair = NetPair::new("so");
    let _serve = pair.serve(&[]);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/scan.py");
    let o = Command::new("ip")
        .args(["netns", "exec", &pair.ns_b, &py])
        .arg(&script)
        .arg(&pair.if_b)
        .output()
        .expect("run pysoem");
    assert!(
        o.status.success(),
        "pysoem: {}",
        String::from_utf8_lossy(&o.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("JSON");
    println!("{v}");
    assert_eq!(v["slaves"], 6, "SOEM found the six drives");
    let dev = ecsync_sim::model::DeviceInfo::servo_drive(0);
    for (i, d) in v["drives"].as_array().unwrap().iter().enumerate() {
        assert_eq!(d["name"], dev.name.as_str(), "drive {i}: SII name");
        assert_eq!(d["man"], dev.vendor_id, "drive {i}: vendor from the SII");
        assert_eq!(
            d["vendor_sdo"], dev.vendor_id,
            "drive {i}: 0x1018:01 over CoE"
        );
        assert_eq!(d["product_sdo"], dev.product_code, "drive {i}: 0x1018:02");
        assert_eq!(
            (d["rx_assign"].as_u64(), d["tx_assign"].as_u64()),
            (Some(0x1600), Some(0x1a00)),
            "drive {i}: PDO assignment"
        );
        assert_eq!(d["rx_map_count"], dev.outputs.len(), "drive {i}: 0x1600:00");
        // SDO Information: the dictionary, an object's name and its entries' names.
        let od: Vec<u64> = d["od"]
            .as_array()
            .unwrap()
            .iter()
            .filter_map(|x| x.as_u64())
            .collect();
        for want in [
            0x1000, 0x1018, 0x1c12, 0x1c13, 0x1c32, 0x1c33, 0x6040, 0x6064,
        ] {
            assert!(od.contains(&want), "drive {i}: {want:#06x} listed: {od:x?}");
        }
        assert_eq!(d["identity_name"], "Identity");
        assert_eq!(
            d["identity_entries"],
            serde_json::json!([
                "Subindex 000",
                "Vendor ID",
                "Product code",
                "Revision",
                "Serial number"
            ])
        );
    }
    // The mapping SOEM built from the CoE PDO assignment and mapping: 16 + 18 bytes for
    // the drives left as they are, 8 + 8 for every other one, which the script's config
    // function mapped anew in PRE-OP (from the SII SOEM would have 34 for every drive).
    let short: Vec<bool> = v["short"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| b.as_bool().unwrap())
        .collect();
    assert_eq!(short, [false, true, false, true, false, true]);
    for (k, m) in v["mapped"].as_array().unwrap().iter().enumerate() {
        let want = if short[k] { [8, 8] } else { [16, 18] };
        assert_eq!(m, &serde_json::json!(want), "drive {k}: outputs, inputs");
    }
    assert_eq!(v["io_map"], 3 * 34 + 3 * 16);
    assert_eq!(v["op"], true, "every drive in OP");
    assert_eq!(v["wkc"], v["expected_wkc"]);
    // Enabled through the CiA 402 state machine: operation enabled, following the
    // target (statusword 0x1237), in cyclic synchronous position (8), at the target.
    for (k, e) in v["drive_inputs"].as_array().unwrap().iter().enumerate() {
        assert_eq!(
            e,
            &serde_json::json!([0x1237, 8, 1000 * (k + 1)]),
            "drive {k}: statusword, mode, position actual"
        );
    }
    assert_eq!(v["sm_event_missed"], serde_json::json!([0, 0, 0, 0, 0, 0]));
}
