//! Issue 13, acceptance 5, over the veth pair: `ecsync serve` of two Ingenia EVS-NET-01
//! servo drives built from the vendor's ESI (../shared/esi/) and the project's own drive
//! from its shipped ESI; ethercrab on its raw socket and SOEM through pysoem scan them and
//! read their identity and PDO assignment over CoE. Independent truth: the ESI's values
//! (vendor 0x029C, product 61935618 for the Ingenia drive, RPDO 1 / TPDO 1 assigned by
//! default, its RPDO 1 entries: controlword, position and velocity set-points, mode).

use super::*;
use crate::common;
use crate::ethercrab_io::EthercrabIo;
use ethercrab::std::ethercat_now;
use ethercrab::{MainDevice, MainDeviceConfig, PduStorage, Timeouts, error::Error};

type Storage = PduStorage<16, { PduStorage::element_size(1100) }>;
static STORAGE: Storage = PduStorage::new();

/// The network file: two Ingenia drives, then the shipped virtual drive.
fn network(dir: &Path) -> (PathBuf, String) {
    let ingenia = dir.join("ingenia-evs-net-01.xml");
    let shipped = common::shipped_esi();
    let text = format!(
        "[segment]\n\
         [[segment.slave]]\nname = \"a\"\nupstream = \"master\"\nesi = \"{i}\"\nserial = 11\n\n\
         [[segment.slave]]\nname = \"b\"\nupstream = \"a\"\nesi = \"{i}\"\nserial = 12\n\n\
         [[segment.slave]]\nname = \"c\"\nupstream = \"b\"\nesi = \"{s}\"\n",
        i = ingenia.display(),
        s = shipped.display()
    );
    let d = tmp("esi-net");
    let path = d.join("esi.toml");
    std::fs::write(&path, &text).unwrap();
    (path, text)
}

// The ESI's `<Vendor><Id>#x0000029c` and `<Type ProductCode="61935618">`.
const INGENIA: (u32, u32) = (0x0000_029c, 61_935_618);

/// The ESI network served on the veth pair, with the devices its drives were built as.
fn serve_esi_drives(pair: &NetPair) -> (Served, Vec<ecsync_sim::model::DeviceInfo>) {
    let (path, text) = network(&common::esi_dir());
    let specs = ecsync_sim::config::parse_segment(path.to_str().unwrap(), &text).unwrap();
    let seg = Segment::new(&specs).unwrap();
    let devices: Vec<_> = (0..seg.len())
        .map(|i| seg.esc(i).device().clone())
        .collect();
    assert_eq!((devices[0].vendor_id, devices[0].product_code), INGENIA);
    (pair.serve(&["--config", path.to_str().unwrap()]), devices)
}

#[test]
#[ignore = "needs network namespaces (root), ../shared/esi"]
fn ethercrab_scans_drives_built_from_esi_files_over_the_veth_pair() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let pair = NetPair::new("i");
    let (_served, devices) = serve_esi_drives(&pair);

    // ethercrab on its raw socket: the scan, then CoE in PRE-OP.
    let (tx, rx, pdu_loop) = STORAGE.try_split().expect("split once");
    let io = EthercrabIo::start(&pair, tx, rx);
    let timeouts = Timeouts {
        pdu: Duration::from_millis(500),
        eeprom: Duration::from_millis(500),
        ..Timeouts::default()
    };
    let maindevice = MainDevice::new(pdu_loop, timeouts, MainDeviceConfig::default());
    let result: Result<(), Error> = futures_lite::future::block_on(async {
        let group = maindevice.init_single_group::<8, 256>(ethercat_now).await?;
        assert_eq!(group.len(), devices.len());
        for (i, sd) in group.iter(&maindevice).enumerate() {
            let d = &devices[i];
            let id = sd.identity();
            assert_eq!(
                (id.vendor_id, id.product_id, id.revision, id.serial),
                (d.vendor_id, d.product_code, d.revision, d.serial),
                "slave {i}: SII identity"
            );
            let vendor: u32 = sd.sdo_read(0x1018, 1).await?;
            let product: u32 = sd.sdo_read(0x1018, 2).await?;
            let rx: u16 = sd.sdo_read(0x1c12, 1).await?;
            let tx: u16 = sd.sdo_read(0x1c13, 1).await?;
            let first: u32 = sd.sdo_read(0x1600, 1).await?;
            assert_eq!(
                (vendor, product, rx, tx, first),
                (d.vendor_id, d.product_code, 0x1600, 0x1a00, 0x6040_0010),
                "slave {i} over CoE"
            );
        }
        Ok(())
    });
    drop(io);
    result.expect("ethercrab against the ESI drives");
}

#[test]
#[ignore = "needs network namespaces (root), ../shared/esi, pysoem"]
fn soem_scans_drives_built_from_esi_files_over_the_veth_pair() {
    // SOEM waits for its frames spinning on a core: not beside a timed run.
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let py = super::soem::python();
    let pair = NetPair::new("is");
    let (_served, devices) = serve_esi_drives(&pair);
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/pysoem/scan_esi.py");
    let o = Command::new("ip")
        .args(["netns", "exec", &pair.ns_b, &py])
        .arg(&script)
        .arg(&pair.if_b)
        .output()
        .expect("run pysoem");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    println!("{v}");
    assert_eq!(v["slaves"], 3);
    for (i, d) in v["drives"].as_array().unwrap().iter().enumerate() {
        let dev = &devices[i];
        assert_eq!(
            (d["man"].as_u64(), d["id"].as_u64(), d["rev"].as_u64()),
            (
                Some(u64::from(dev.vendor_id)),
                Some(u64::from(dev.product_code)),
                Some(u64::from(dev.revision))
            ),
            "slave {i}: SII identity"
        );
        assert_eq!(d["vendor_sdo"], dev.vendor_id, "slave {i}: 0x1018:01");
        assert_eq!(d["product_sdo"], dev.product_code, "slave {i}: 0x1018:02");
        assert_eq!(
            (d["rx_assign"].as_u64(), d["tx_assign"].as_u64()),
            (Some(0x1600), Some(0x1a00))
        );
    }
    // The Ingenia drive's RPDO 1 as its ESI writes it.
    assert_eq!(
        v["drives"][0]["rx_map"],
        serde_json::json!([
            0x6040_0010u32,
            0x607a_0020u32,
            0x60ff_0020u32,
            0x6060_0008u32
        ])
    );
    // Two Ingenia drives (11 + 11 bytes each) and the virtual drive (16 + 18).
    assert_eq!(v["io_map"], 2 * 22 + 34);
}
