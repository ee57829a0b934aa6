//! ESI files (ETG.2000 XML): any bytes, and the project's own ESI edited by the input (bytes
//! replaced, the file cut), are parsed without a panic; what parses builds a device, its SDO
//! server and its SII image without a panic, the SII's checksum valid; an error names a line
//! of the input.
#![no_main]

use ecsync_sim::coe::SdoServer;
use ecsync_sim::esi;
use ecsync_sim::model::EscModel;
use libfuzzer_sys::fuzz_target;

/// The ESI of ecsync's virtual drive: a whole, valid file to start edits from.
const SHIPPED: &[u8] = include_bytes!("../../esi/ecsync-virtual-drive.xml");

fn exercise(bytes: &[u8]) {
    match esi::parse_bytes("fuzz.xml", bytes) {
        Ok(f) => {
            for d in &f.devices {
                let dev = d.device_info(1);
                let s = SdoServer::new(&dev);
                for o in s.od.objects() {
                    let _ = s.od.read_complete(o.index, 0);
                }
                let img = ecsync_sim::sii_image::build(&EscModel::servo_mii(), &dev);
                assert!(ecsync_wire::sii::checksum_ok(&img));
            }
        }
        Err(e) => {
            let lines = bytes.iter().filter(|&&b| b == b'\n').count() + 1;
            assert!(e.line.is_none_or(|l| (1..=lines).contains(&l)), "{e}");
        }
    }
}

fuzz_target!(|data: &[u8]| {
    exercise(data);
    // The input as edits of the shipped file: (position, byte) pairs of 3 bytes, then a cut
    // when the input's length is odd.
    let mut b = SHIPPED.to_vec();
    for e in data.chunks_exact(3) {
        let at = usize::from(u16::from_le_bytes([e[0], e[1]])) * 7 % b.len();
        b[at] = e[2];
    }
    if data.len() % 2 == 1 {
        let cut = data.iter().map(|&x| usize::from(x)).sum::<usize>() * 13 % b.len();
        b.truncate(cut);
    }
    exercise(&b);
});
