//! Devices built from ESI files (ETG.2000): the project's own virtual drive
//! (`esi/ecsync-virtual-drive.xml`) against the built-in servo drive, and the vendors' files in
//! `../shared/esi/` (see its README.md) against values read from the XML independently: by the
//! tiny string search below ([`Xml`]), or written out by hand from the file with its line.

mod common;

use common::{Bus, esi_dir, shipped_esi};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::coe::{ObjectDictionary, SdoServer};
use ecsync_sim::esi::{self, EsiErrorKind};
use ecsync_sim::model::{DeviceInfo, EscModel};
use ecsync_sim::{Esc, Segment, SlaveSpec, Upstream};
use ecsync_wire::register::{self as reg, sii_control};
use ecsync_wire::sii::{self, category};
use ecsync_wire::{AlState, Command, DatagramAddress};

/// A first-occurrence string search over the XML text, independent of the parser under test.
struct Xml(String);

impl Xml {
    fn read(path: &std::path::Path) -> Self {
        Xml(std::fs::read_to_string(path).unwrap())
    }

    /// The text between the first `open` after `after` and the next `close`.
    fn between(&self, after: &str, open: &str, close: &str) -> &str {
        let from = self.0.find(after).expect(after);
        let rest = &self.0[from..];
        let a = rest.find(open).expect(open) + open.len();
        let b = a + rest[a..].find(close).expect(close);
        rest[a..b].trim()
    }

    /// The value of attribute `attr` in the first element starting with `tag`.
    fn attr(&self, tag: &str, attr: &str) -> &str {
        let from = self.0.find(tag).expect(tag);
        let end = from + self.0[from..].find('>').unwrap();
        let el = &self.0[from..end];
        let key = format!("{attr}=\"");
        let a = el.find(&key).expect(attr) + key.len();
        let b = a + el[a..].find('"').unwrap();
        &el[a..b]
    }
}

/// ETG.2000's HexDecValue: `#x...` or decimal.
fn number(s: &str) -> u32 {
    match s.strip_prefix("#x") {
        Some(h) => u32::from_str_radix(h, 16).unwrap(),
        None => s.parse().unwrap(),
    }
}

fn hex_bytes(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

/// The SII checksum as the ESC datasheet (section II, "SII EEPROM", word 7) defines it: CRC-8
/// with polynomial x^8 + x^2 + x + 1 (0x07), initial value 0xFF, over bytes 0-13; written here
/// bit by bit rather than taken from ecsync-wire.
fn crc8(bytes: &[u8]) -> u8 {
    let mut crc = 0xffu8;
    for &b in bytes {
        crc ^= b;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 {
                (crc << 1) ^ 0x07
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Eight bytes of slave `pos`'s SII EEPROM from word `word`, read the way a master does it
/// (ESC datasheet section II, "SII EEPROM interface"): the read command and the address
/// written to 0x0502-0x0507, 0x0502 polled until not busy, the data read from 0x0508.
fn sii_read(bus: &mut Bus, pos: u16, word: u32) -> [u8; 8] {
    let at = |ado: u16| DatagramAddress::Position {
        adp: 0u16.wrapping_sub(pos),
        ado,
    };
    let mut cmd = sii_control::CMD_READ.to_le_bytes().to_vec();
    cmd.extend_from_slice(&word.to_le_bytes());
    assert_eq!(bus.one(Command::Apwr, at(reg::SII_CONTROL), &cmd).wkc, 1);
    for _ in 0..10 {
        let c = bus.one(Command::Aprd, at(reg::SII_CONTROL), &[0, 0]);
        if u16::from_le_bytes([c.data[0], c.data[1]]) & sii_control::BUSY == 0 {
            let d = bus.one(Command::Aprd, at(reg::SII_DATA), &[0; 8]);
            return d.data.try_into().unwrap();
        }
    }
    panic!("slave {pos}: the SII read stays busy");
}

/// The ESC of `dev` on a servo-mii model, as the segment powers it up.
fn esc_of(dev: &DeviceInfo) -> Esc {
    Esc::new(EscModel::servo_mii(), dev.clone(), CrystalParams::default())
}

fn u32_at(od: &ObjectDictionary, index: u16, sub: u8) -> u32 {
    let v = od
        .read(index, sub)
        .unwrap_or_else(|e| panic!("{index:#06x}:{sub}: {e:?}"));
    assert!(v.len() <= 4, "{index:#06x}:{sub} is {} bytes", v.len());
    od.read_u32(index, sub)
}

/// The SII read back from the ESC: a valid checksum over words 0-6, which are `config`.
fn check_sii_head(esc: &Esc, config: &[u8]) {
    let img = esc.sii_image();
    assert_eq!(&img[..14], &config[..14], "SII words 0-6 from ConfigData");
    assert_eq!(img[14], crc8(&img[..14]), "SII word 7: the checksum");
    assert_eq!(img[15], 0, "the checksum's high byte");
}

#[test]
fn the_shipped_esi_builds_the_built_in_servo_drive() {
    let file = esi::load(&shipped_esi()).unwrap();
    assert_eq!(file.devices.len(), 1);
    let serial = 0x1234_5678;
    let dev = file.devices[0].device_info(serial);
    let builtin = DeviceInfo::servo_drive(serial);
    assert_eq!(
        (dev.vendor_id, dev.product_code, dev.revision, dev.serial),
        (0x0e5c, 0x4024, 0x0001_0000, serial)
    );
    assert_eq!(
        (
            dev.vendor_id,
            dev.product_code,
            dev.revision,
            dev.serial,
            &dev.name,
            dev.alias
        ),
        (
            builtin.vendor_id,
            builtin.product_code,
            builtin.revision,
            builtin.serial,
            &builtin.name,
            builtin.alias
        )
    );
    assert_eq!(dev.outputs, builtin.outputs, "RxPDO 0x1600");
    assert_eq!(dev.inputs, builtin.inputs, "TxPDO 0x1A00");
    assert_eq!(dev.mailbox, builtin.mailbox);
    assert_eq!(dev.process_data_starts(), builtin.process_data_starts());
    assert_eq!(dev.process_data_starts(), (0x1100, 0x1180));
    let modes: Vec<(&str, u16)> = dev
        .dc_opmodes
        .iter()
        .map(|m| (m.name.as_str(), m.assign_activate))
        .collect();
    assert_eq!(modes, [("DC", 0x0300), ("FreeRun", 0x0000)]);

    // The SII's fixed area (words 0-0x3F: configuration, checksum, identity, mailbox, size)
    // byte for byte; the SyncManagers and the CoE details as the built-in drive's.
    let (a, b) = (esc_of(&dev), esc_of(&builtin));
    let (ia, ib) = (a.sii_image(), b.sii_image());
    assert_eq!(&ia[..0x80], &ib[..0x80], "SII words 0-0x3F");
    assert!(sii::checksum_ok(ia));
    for cat in [category::SYNC_MANAGER, category::FMMU] {
        assert_eq!(
            sii::find_category(ia, cat).unwrap().data,
            sii::find_category(ib, cat).unwrap().data,
            "category {cat}"
        );
    }
    let coe = |img: &[u8]| sii::find_category(img, category::GENERAL).unwrap().data[5];
    assert_eq!(coe(ia), coe(ib), "CoE details");

    // The dictionary: the same objects with the same values, types, access and PDO mapping.
    let (sa, sb) = (SdoServer::new(&dev), SdoServer::new(&builtin));
    let indices = |s: &SdoServer| s.od.objects().iter().map(|o| o.index).collect::<Vec<_>>();
    assert_eq!(indices(&sa), indices(&sb));
    for (oa, ob) in sa.od.objects().iter().zip(sb.od.objects()) {
        assert_eq!(oa.code, ob.code, "{:#06x}", oa.index);
        let subs = |o: &ecsync_sim::coe::Object| {
            o.entries
                .iter()
                .map(|e| {
                    (
                        e.subindex,
                        e.value.clone(),
                        e.data_type,
                        e.access,
                        e.pdo_mapping,
                    )
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(subs(oa), subs(ob), "{:#06x} {}", oa.index, oa.name);
    }
    assert_eq!(u32_at(&sa.od, 0x1018, 4), serial, "the slave's own serial");
}

#[test]
#[ignore = "needs ../shared/esi"]
fn an_ingenia_drive_from_its_esi() {
    let dir = esi_dir();
    let path = dir.join("ingenia-evs-net-01.xml");
    let xml = Xml::read(&path);
    let file = esi::load(&path).unwrap();
    assert_eq!(file.devices.len(), 1);
    let d = &file.devices[0];
    // 583 objects in the dictionary (`grep -c "<Object>"`).
    assert_eq!(d.objects.len(), xml.0.matches("<Object>").count());
    assert_eq!(d.objects.len(), 583);

    let dev = d.device_info(77);
    // Identity: <Vendor><Id>#x0000029c (line 4), <Type ProductCode="61935618"
    // RevisionNo="327685">EVS-NET-01 (line 18).
    assert_eq!(
        dev.vendor_id,
        number(xml.between("<Vendor>", "<Id>", "</Id>"))
    );
    assert_eq!(
        dev.product_code,
        number(xml.attr("<Type ProductCode", "ProductCode"))
    );
    assert_eq!(
        dev.revision,
        number(xml.attr("<Type ProductCode", "RevisionNo"))
    );
    assert_eq!(
        (dev.vendor_id, dev.product_code, dev.revision),
        (0x29c, 61_935_618, 327_685)
    );
    assert_eq!(d.type_name, "EVS-NET-01");
    assert_eq!(dev.name, "EVS-NET-01");

    // The ESC's SII: ConfigData 080E02EE409C0000000000000000 (line 12405) as words 0-6, the
    // checksum over them, the identity, the mailbox at 0x1000/0x1400 of 128 bytes with CoE,
    // 16384 bytes of EEPROM (word 0x3E: 128 Kbit - 1).
    let esc = esc_of(&dev);
    let config = hex_bytes(xml.between("<Eeprom>", "<ConfigData>", "</ConfigData>"));
    check_sii_head(&esc, &config);
    let img = esc.sii_image();
    let id = sii::identity(img).unwrap();
    assert_eq!(
        (id.vendor_id, id.product_code, id.revision, id.serial),
        (0x29c, 61_935_618, 327_685, 77)
    );
    let word = |w: u16| sii::word(img, w).unwrap();
    assert_eq!(
        [word(0x18), word(0x19), word(0x1a), word(0x1b)],
        [0x1000, 128, 0x1400, 128]
    );
    assert_eq!(
        word(sii::WORD_MAILBOX_PROTOCOL),
        0x0004,
        "CoE (EoE, FoE not served)"
    );
    assert_eq!(img.len(), 16_384);
    assert_eq!(word(sii::WORD_SIZE), 127);
    // CoE SdoInfo, CompleteAccess, PdoAssign, PdoConfig (line 12382): 0x2F.
    let general = sii::find_category(img, category::GENERAL).unwrap();
    assert_eq!(general.data[sii::general::COE_DETAILS], 0x2f);
    // The SyncManagers of lines 12212-12215: process data at 0x1800 and 0x1C00, 11 bytes each
    // (the default PDOs' 16 + 32 + 32 + 8 bits).
    let sm = sii::find_category(img, category::SYNC_MANAGER).unwrap();
    let sms: Vec<(u16, u16, u8, u8)> = sm
        .data
        .chunks(8)
        .map(|e| {
            (
                u16::from_le_bytes([e[0], e[1]]),
                u16::from_le_bytes([e[2], e[3]]),
                e[4],
                e[7],
            )
        })
        .collect();
    assert_eq!(
        sms,
        [
            (0x1000, 128, 0x26, 1),
            (0x1400, 128, 0x22, 2),
            (0x1800, 11, 0x64, 3),
            (0x1c00, 11, 0x20, 4)
        ]
    );
    assert_eq!(dev.process_data_starts(), (0x1800, 0x1c00));
    assert_eq!((dev.output_bytes(), dev.input_bytes()), (11, 11));
    // Three RxPDOs and three TxPDOs in the SII's categories (one per direction, as real SIIs
    // and the masters that read the first have them), the first of each on SM2/SM3, the
    // others not assigned (0xFF).
    let pdo_sms = |kind: u16| {
        let cats: Vec<_> = sii::categories(img)
            .filter_map(Result::ok)
            .filter(|c| c.kind == kind)
            .collect();
        assert_eq!(cats.len(), 1, "one category of kind {kind:#x}");
        let (mut c, mut out) = (cats[0].data, Vec::new());
        while c.len() >= 8 {
            out.push((u16::from_le_bytes([c[0], c[1]]), c[3]));
            c = &c[8 + 8 * usize::from(c[2])..];
        }
        out
    };
    assert_eq!(
        pdo_sms(category::RXPDO),
        [(0x1600, 2), (0x1601, 0xff), (0x1602, 0xff)]
    );
    assert_eq!(
        pdo_sms(category::TXPDO),
        [(0x1a00, 3), (0x1a01, 0xff), (0x1a02, 0xff)]
    );

    // PDO mapping through the SDO server: 0x1600 the entries of <RxPdo Sm="2"> (line 12216:
    // 0x6040:00 16 bits, 0x607A:00 32, 0x60FF:00 32, 0x6060:00 8), 0x1A00 those of <TxPdo
    // Sm="3"> (line 12298: 0x6041 16, 0x6064 32, 0x606C 32, 0x6061 8); the assignment
    // 0x1C12/0x1C13 the PDOs with an Sm attribute.
    let s = SdoServer::new(&dev);
    let od = &s.od;
    let rx: Vec<u32> = (1..=u32_at(od, 0x1600, 0) as u8)
        .map(|k| u32_at(od, 0x1600, k))
        .collect();
    assert_eq!(rx, [0x6040_0010, 0x607a_0020, 0x60ff_0020, 0x6060_0008]);
    let tx: Vec<u32> = (1..=u32_at(od, 0x1a00, 0) as u8)
        .map(|k| u32_at(od, 0x1a00, k))
        .collect();
    assert_eq!(tx, [0x6041_0010, 0x6064_0020, 0x606c_0020, 0x6061_0008]);
    assert_eq!(
        [
            u32_at(od, 0x1c12, 0),
            u32_at(od, 0x1c12, 1),
            u32_at(od, 0x1c12, 2)
        ],
        [1, 0x1600, 0]
    );
    assert_eq!([u32_at(od, 0x1c13, 0), u32_at(od, 0x1c13, 1)], [1, 0x1a00]);
    // The ESI's own DefaultData for 0x1C12 (line 3145: 00, no PDO) as parsed.
    let raw_1c12 = d.objects.iter().find(|o| o.index == 0x1c12).unwrap();
    assert_eq!(raw_1c12.entries[0].value, [0]);
    assert_eq!(
        od.assigned_entries(0x1c12),
        dev.outputs
            .iter()
            .map(|e| (e.index, e.subindex, e.bits))
            .collect::<Vec<_>>()
    );
    // 0x1601 (line 2547), not assigned: 0x6040 and 0x607A.
    assert_eq!(
        [
            u32_at(od, 0x1601, 0),
            u32_at(od, 0x1601, 1),
            u32_at(od, 0x1601, 2)
        ],
        [2, 0x6040_0010, 0x607a_0020]
    );

    // Defaults: 0x1000 DefaultData 92010200 (line 2380, CiA 402 servo); 0x1018:01 the vendor;
    // 0x1018:02 the Type's product code, where the ESI's DefaultData (32000000, line 2409) is
    // kept in the parsed object; 0x1C32:04 1f40 (line 3246); 0x6065 64000000 (line 3743);
    // 0x6075 10270000 (line 3807); vendor objects 0x2100 REAL 0a000000 (line 6753) and 0x58AA
    // STRING(6) 302e302e31 "0.0.1" (line 4407).
    assert_eq!(u32_at(od, 0x1000, 0), 0x0002_0192);
    assert_eq!(u32_at(od, 0x1018, 1), 0x29c);
    assert_eq!(u32_at(od, 0x1018, 2), 61_935_618);
    let raw_1018 = d.objects.iter().find(|o| o.index == 0x1018).unwrap();
    assert_eq!(raw_1018.entries[2].value, [0x32, 0, 0, 0]);
    assert_eq!(u32_at(od, 0x1c32, 4), 0x401f);
    assert_eq!(u32_at(od, 0x1c32, 0), 32);
    assert_eq!(u32_at(od, 0x6065, 0), 100);
    assert_eq!(u32_at(od, 0x6075, 0), 10_000);
    assert_eq!(od.read(0x2100, 0).unwrap(), [0x0a, 0, 0, 0]);
    assert_eq!(od.read(0x58aa, 0).unwrap(), b"0.0.1");
    // 0x6040: rw, mappable into an RxPDO (PdoMapping r, line 3642).
    let cw = &od.object(0x6040).unwrap().entries[0];
    assert_eq!(
        (cw.access, cw.pdo_mapping, cw.bits),
        (ecsync_sim::coe::Access::ReadWrite, 0x0040, 16)
    );
    // The mappings are written in PRE-OP only (WriteRestrictions="PreOP").
    let mut s = s;
    assert!(s.od.write(0x1600, 0, &[0], AlState::SafeOp).is_err());
    assert!(s.od.write(0x1600, 0, &[0], AlState::PreOp).is_ok());

    // DC: "DCSync" with AssignActivate #x300 and a SYNC0 shift of -3 ns (line 12394).
    let dc: Vec<(&str, u16, i32)> = dev
        .dc_opmodes
        .iter()
        .map(|m| (m.name.as_str(), m.assign_activate, m.shift_time_sync0_ns))
        .collect();
    assert_eq!(dc, [("Synchron", 0, 0), ("DCSync", 0x0300, -3)]);
}

#[test]
#[ignore = "needs ../shared/esi"]
fn the_kickcat_test_devices_from_their_esis() {
    let dir = esi_dir();

    // test-complex.xml: vendor #x0CAFE (line 4), product #x00005678 revision #x2 (line 16), no
    // PDOs, ConfigData 820E04CC8813FF00000040C00000 (line 278).
    let path = dir.join("test-complex.xml");
    let xml = Xml::read(&path);
    let d = esi::load(&path).unwrap().devices.remove(0);
    let dev = d.device_info(1);
    assert_eq!(
        (dev.vendor_id, dev.product_code, dev.revision),
        (
            number(xml.between("<Vendor>", "<Id>", "</Id>")),
            number(xml.attr("<Type ProductCode", "ProductCode")),
            number(xml.attr("<Type ProductCode", "RevisionNo")),
        )
    );
    assert_eq!(
        (dev.vendor_id, dev.product_code, dev.revision),
        (0xcafe, 0x5678, 2)
    );
    assert_eq!(dev.name, "KickCAT ESI Test Complex");
    assert!(dev.outputs.is_empty() && dev.inputs.is_empty());
    let esc = esc_of(&dev);
    check_sii_head(
        &esc,
        &hex_bytes(xml.between("<Eeprom>", "<ConfigData>", "</ConfigData>")),
    );
    let s = SdoServer::new(&dev);
    let od = &s.od;
    // 0x1000 DefaultData 89130000; 0x6010 an enum with DefaultValue 2; 0x6020 an alias of INT
    // with DefaultValue #x00E1; 0x2000 a record of the enum (DefaultValue 1) and the alias
    // (#x0019); 0x1018:01 the vendor of <Vendor>, while the ESI's DefaultData say FE0A0000.
    assert_eq!(u32_at(od, 0x1000, 0), 0x1389);
    assert_eq!(od.read(0x6010, 0).unwrap(), [2]);
    assert_eq!(od.read(0x6020, 0).unwrap(), [0xe1, 0]);
    assert_eq!(od.read(0x2000, 0).unwrap(), [2]);
    assert_eq!(od.read(0x2000, 1).unwrap(), [1]);
    assert_eq!(od.read(0x2000, 2).unwrap(), [0x19, 0]);
    assert_eq!(u32_at(od, 0x1018, 1), 0xcafe);
    let raw = d.objects.iter().find(|o| o.index == 0x1018).unwrap();
    assert_eq!(raw.entries[1].value, [0xfe, 0x0a, 0, 0]);
    // The enum's and the alias's base types: UNSIGNED8 and INTEGER16.
    assert_eq!(od.object(0x6010).unwrap().entries[0].data_type, 0x0005);
    assert_eq!(od.object(0x6020).unwrap().entries[0].data_type, 0x0003);
    // Without PDOs nothing is assigned; the ESC's communication objects are added.
    assert_eq!(u32_at(od, 0x1c12, 0), 0);
    assert_eq!(u32_at(od, 0x1c32, 1), 0, "free run");

    // test-sm-fmmu.xml: product #x00005555 revision #x1; RxPdo 0x1600 on SM2, fixed and
    // mandatory, 0x7000:01 16 bits (line 49); TxPdo 0x1A00 on SM3: 0x6000:01 16 bits,
    // 0x6000:02 8 bits (line 61); every mailbox protocol; DC "Synchron" #x300, SYNC0 every
    // 1000000 ns shifted 100 ns, and "FreeRun" (line 121); ConfigData of 16 bytes with a word 7
    // of 0, which the computed checksum replaces (line 139).
    let path = dir.join("test-sm-fmmu.xml");
    let xml = Xml::read(&path);
    let d = esi::load(&path).unwrap().devices.remove(0);
    let dev = d.device_info(2);
    assert_eq!(
        (dev.vendor_id, dev.product_code, dev.revision),
        (
            0xcafe,
            number(xml.attr("<Type ProductCode", "ProductCode")),
            1
        )
    );
    assert_eq!(dev.product_code, 0x5555);
    let bits = |v: &[ecsync_sim::model::PdoEntry]| {
        v.iter()
            .map(|e| (e.index, e.subindex, e.bits))
            .collect::<Vec<_>>()
    };
    assert_eq!(bits(&dev.outputs), [(0x7000, 1, 16)]);
    assert_eq!(bits(&dev.inputs), [(0x6000, 1, 16), (0x6000, 2, 8)]);
    let rx = &d.rx_pdos[0];
    assert_eq!(
        (rx.index, rx.sm, rx.fixed, rx.mandatory),
        (0x1600, Some(2), true, true)
    );
    assert_eq!(d.mailbox_protocols, 0x3f);
    assert_eq!(
        d.dc_opmodes
            .iter()
            .map(|m| (
                m.name.as_str(),
                m.assign_activate,
                m.cycle_time_sync0_ns,
                m.shift_time_sync0_ns
            ))
            .collect::<Vec<_>>(),
        [("Synchron", 0x0300, 1_000_000, 100), ("FreeRun", 0, 0, 0)]
    );
    let esc = esc_of(&dev);
    let config = hex_bytes(xml.between("<Eeprom", "<ConfigData>", "</ConfigData>"));
    assert_eq!(config.len(), 16);
    check_sii_head(&esc, &config);
    assert_ne!(
        esc.sii_image()[14],
        config[14],
        "word 7 is the checksum, not ConfigData's"
    );
    let img = esc.sii_image();
    assert_eq!(sii::word(img, sii::WORD_MAILBOX_PROTOCOL), Ok(0x0004));
    // The PDO categories: the RxPDO on SM2, flags mandatory | default | fixed.
    let rxc = sii::find_category(img, category::RXPDO).unwrap();
    assert_eq!(u16::from_le_bytes([rxc.data[0], rxc.data[1]]), 0x1600);
    assert_eq!((rxc.data[2], rxc.data[3]), (1, 2));
    assert_eq!(u16::from_le_bytes([rxc.data[6], rxc.data[7]]), 0x0013);
    let s = SdoServer::new(&dev);
    // No mapping objects in the dictionary: made from the PDOs.
    assert_eq!(u32_at(&s.od, 0x1600, 1), 0x7000_0110);
    assert_eq!(
        [u32_at(&s.od, 0x1a00, 1), u32_at(&s.od, 0x1a00, 2)],
        [0x6000_0110, 0x6000_0208]
    );
    assert_eq!(
        [u32_at(&s.od, 0x1c12, 1), u32_at(&s.od, 0x1c13, 1)],
        [0x1600, 0x1a00]
    );
}

#[test]
fn malformed_and_foreign_xml_give_errors_with_file_line_and_element() {
    // Not well-formed: </Vendorr> closes <Vendor> on line 3.
    let e = esi::parse(
        "bad.xml",
        "<?xml version=\"1.0\"?>\n<EtherCATInfo>\n<Vendor><Id>1</Id></Vendorr>\n</EtherCATInfo>",
    )
    .unwrap_err();
    assert_eq!((e.kind, e.line), (EsiErrorKind::Xml, Some(3)), "{e}");
    assert_eq!(e.element, "EtherCATInfo/Vendor");
    assert!(
        e.to_string()
            .starts_with("bad.xml:3: <EtherCATInfo/Vendor>: "),
        "{e}"
    );

    // Truncated inside <Descriptions>: the unclosed element and its line.
    let e = esi::parse(
        "cut.xml",
        "<EtherCATInfo>\n<Vendor><Id>1</Id></Vendor>\n<Descriptions>\n<Devices>",
    )
    .unwrap_err();
    assert_eq!(e.kind, EsiErrorKind::Xml, "{e}");
    assert_eq!(e.line, Some(4), "{e}");
    assert!(e.message.contains("Devices"), "{e}");

    // Another schema: a well-formed XML file that is not EtherCATInfo.
    let e = esi::parse(
        "pom.xml",
        "<?xml version=\"1.0\"?>\n<project>\n<a/>\n</project>",
    )
    .unwrap_err();
    assert_eq!(
        (e.kind, e.line, e.element.as_str()),
        (EsiErrorKind::Schema, Some(2), "project"),
        "{e}"
    );
    assert!(e.message.contains("EtherCATInfo"), "{e}");

    // EtherCATInfo without a device.
    let e = esi::parse(
        "empty.xml",
        "<EtherCATInfo>\n<Vendor><Id>1</Id></Vendor>\n<Descriptions>\n<Devices/>\n</Descriptions>\n</EtherCATInfo>",
    )
    .unwrap_err();
    assert_eq!(
        (e.kind, e.line, e.element.as_str()),
        (
            EsiErrorKind::Schema,
            Some(4),
            "EtherCATInfo/Descriptions/Devices"
        ),
        "{e}"
    );

    // The shipped file with a required attribute removed, and with a bad number: the line is
    // where the element is in that file.
    let text = std::fs::read_to_string(shipped_esi()).unwrap();
    let type_line = text
        .lines()
        .position(|l| l.contains("<Type ProductCode"))
        .unwrap()
        + 1;
    let e = esi::parse(
        "no-product.xml",
        &text.replace("ProductCode=\"#x00004024\" ", ""),
    )
    .unwrap_err();
    assert_eq!(e.kind, EsiErrorKind::Missing, "{e}");
    assert_eq!(e.line, Some(type_line));
    assert_eq!(
        e.element,
        "EtherCATInfo/Descriptions/Devices/Device/Type@ProductCode"
    );
    let sm_line = text
        .lines()
        .position(|l| l.contains(">MBoxIn</Sm>"))
        .unwrap()
        + 1;
    let e = esi::parse(
        "bad-number.xml",
        &text.replace("StartAddress=\"#x1080\"", "StartAddress=\"#x1G80\""),
    )
    .unwrap_err();
    assert_eq!(
        (e.kind, e.line),
        (EsiErrorKind::BadValue, Some(sm_line)),
        "{e}"
    );
    assert_eq!(
        e.element,
        "EtherCATInfo/Descriptions/Devices/Device/Sm@StartAddress"
    );
    let id_line = text.lines().position(|l| l.contains("<Id>")).unwrap() + 1;
    let e = esi::parse(
        "bad-id.xml",
        &text.replacen("#x00000E5C", "#x1_0000_0000", 1),
    )
    .unwrap_err();
    assert_eq!(
        (e.kind, e.line),
        (EsiErrorKind::BadValue, Some(id_line)),
        "{e}"
    );
    assert_eq!(e.element, "EtherCATInfo/Vendor/Id");

    // A file that does not exist.
    let e = esi::load(std::path::Path::new("/nonexistent/drive.xml")).unwrap_err();
    assert_eq!(e.kind, EsiErrorKind::Io);
    assert!(e.to_string().starts_with("/nonexistent/drive.xml: "), "{e}");
}

#[test]
#[ignore = "needs ../shared/esi"]
fn a_network_file_builds_slaves_from_esi_files() {
    let dir = esi_dir();
    // A network file in a temporary folder, the ESIs beside it (the shared one by absolute
    // path, the shipped one copied next to it, found relative to the network file).
    let tmp = std::env::temp_dir().join(format!("ecsync-esi-net-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    std::fs::copy(shipped_esi(), tmp.join("virtual.xml")).unwrap();
    let ingenia = dir.join("ingenia-evs-net-01.xml");
    let net = format!(
        r#"[segment]
[[segment.slave]]
name = "a"
upstream = "master"
esi = "{ing}"
serial = 11

[[segment.slave]]
name = "b"
upstream = "a"
esi = "{ing}"
device = "EVS-NET-01"

[[segment.slave]]
name = "c"
upstream = "b"
esi = "virtual.xml"
"#,
        ing = ingenia.display()
    );
    let toml_path = tmp.join("net.toml");
    let file = toml_path.display().to_string();
    let specs = ecsync_sim::config::parse_segment(&file, &net).unwrap();
    assert_eq!(specs.len(), 3);
    assert_eq!(
        (
            specs[0].device.vendor_id,
            specs[0].device.product_code,
            specs[0].device.serial
        ),
        (0x29c, 61_935_618, 11)
    );
    assert_eq!(specs[1].device.serial, 2);
    // The file is parsed once and its device built once: the two drives share the dictionary.
    assert!(std::sync::Arc::ptr_eq(
        specs[0].device.dictionary.as_ref().unwrap(),
        specs[1].device.dictionary.as_ref().unwrap()
    ));
    assert_eq!(specs[2].device.outputs, DeviceInfo::servo_drive(3).outputs);

    // An unknown device name lists the file's devices; a missing file and a broken file name
    // the field and the network file's line.
    let bad = net.replace("device = \"EVS-NET-01\"", "device = \"EVS-NET-02\"");
    let e = ecsync_sim::config::parse_segment(&file, &bad).unwrap_err();
    assert_eq!(e.field, "segment.slave[1].device");
    assert_eq!(e.line, Some(12), "{e}");
    assert!(e.fix.contains("\"EVS-NET-01\""), "{e}");
    let bad = net.replace("esi = \"virtual.xml\"", "esi = \"missing.xml\"");
    let e = ecsync_sim::config::parse_segment(&file, &bad).unwrap_err();
    assert_eq!(
        (e.field.as_str(), e.line),
        ("segment.slave[2].esi", Some(17)),
        "{e}"
    );
    assert!(e.message.contains("missing.xml"), "{e}");
    std::fs::write(tmp.join("broken.xml"), "<EtherCATInfo>\n<Vendor>\n").unwrap();
    let bad = net.replace("esi = \"virtual.xml\"", "esi = \"broken.xml\"");
    let e = ecsync_sim::config::parse_segment(&file, &bad).unwrap_err();
    assert_eq!(e.field, "segment.slave[2].esi");
    assert!(
        e.message.contains("broken.xml:2: <EtherCATInfo/Vendor>"),
        "{e}"
    );

    // A file of two devices: the slave must say which; the second one is built when named.
    let shipped = std::fs::read_to_string(shipped_esi()).unwrap();
    let (a, b) = (
        shipped.find("      <Device ").unwrap(),
        shipped.find("    </Devices>").unwrap(),
    );
    let second = shipped[a..b]
        .replace(">ECSYNC-VIRT<", ">ECSYNC-VIRT-2<")
        .replace("ProductCode=\"#x00004024\"", "ProductCode=\"#x00004025\"");
    let two = format!("{}{second}{}", &shipped[..b], &shipped[b..]);
    std::fs::write(tmp.join("two.xml"), two).unwrap();
    let bad = net.replace("esi = \"virtual.xml\"", "esi = \"two.xml\"");
    let e = ecsync_sim::config::parse_segment(&file, &bad).unwrap_err();
    assert_eq!(
        (e.field.as_str(), e.line),
        ("segment.slave[2].device", Some(17)),
        "{e}"
    );
    assert!(e.message.contains("describes 2 devices"), "{e}");
    assert!(e.fix.contains("\"ECSYNC-VIRT\", \"ECSYNC-VIRT-2\""), "{e}");
    let good = net.replace(
        "esi = \"virtual.xml\"",
        "esi = \"two.xml\"\ndevice = \"ECSYNC-VIRT-2\"",
    );
    let specs = ecsync_sim::config::parse_segment(&file, &good).unwrap();
    assert_eq!(specs[2].device.product_code, 0x4025);
    let _ = std::fs::remove_dir_all(&tmp);
}

/// Two Ingenia drives in a segment: each ESC's SII, read over EtherCAT, with the ESI's
/// ConfigData, a valid checksum and its own serial; and each ESC's CoE
/// server answering CoE messages (ETG.1000.6 5.6.2: an expedited upload of 0x1018:01, a normal
/// upload of the 5-byte STRING 0x58AA, and the SDO Information entry description of 0x6040)
/// with the ESI's values.
#[test]
#[ignore = "needs ../shared/esi"]
fn a_segment_of_esi_drives_answers_coe_with_the_esi_values() {
    let dir = esi_dir();
    let d = esi::load(&dir.join("ingenia-evs-net-01.xml"))
        .unwrap()
        .devices
        .remove(0);
    let spec = |i: usize| SlaveSpec {
        model: EscModel::servo_mii(),
        device: d.device_info(i as u32 + 1),
        crystal: CrystalParams::default(),
        upstream: Upstream::in_line(i),
        entry_port: 0,
        cable_m: 1.0,
        ring: None,
    };
    let seg = Segment::new(&[spec(0), spec(1)]).unwrap();
    // Each drive's SII words 0-15 read over EtherCAT: ConfigData (line 12405) as words 0-6,
    // word 7 its CRC-8, then vendor, product, revision and serial.
    let xml = Xml::read(&dir.join("ingenia-evs-net-01.xml"));
    let config = hex_bytes(xml.between("<Eeprom>", "<ConfigData>", "</ConfigData>"));
    let mut bus = Bus::new(seg);
    for pos in 0..2u16 {
        let words: Vec<u8> = (0..4)
            .flat_map(|k| sii_read(&mut bus, pos, 4 * k))
            .collect();
        assert_eq!(&words[..14], &config[..], "slave {pos}: words 0-6");
        assert_eq!(words[14], crc8(&words[..14]), "slave {pos}: word 7");
        let dword = |w: usize| u32::from_le_bytes(words[2 * w..2 * w + 4].try_into().unwrap());
        assert_eq!(
            [dword(8), dword(10), dword(12), dword(14)],
            [0x29c, 61_935_618, 327_685, u32::from(pos) + 1],
            "slave {pos}: identity"
        );
    }
    let mut seg = bus.seg;
    for i in 0..2 {
        let img = seg.esc(i).sii_image().to_vec();
        assert!(sii::checksum_ok(&img));
        assert_eq!(sii::identity(&img).unwrap().serial, i as u32 + 1);
        let s = seg.esc_mut(i).sdo_server_mut().expect("a mailbox with CoE");
        // CoE header (service 2, SDO request), then the SDO: 0x40 initiate upload.
        let mut ask = |sdo: &[u8]| {
            let mut req = vec![0x00, 0x20];
            req.extend_from_slice(sdo);
            s.handle(&req, AlState::PreOp, 122).unwrap().unwrap()
        };
        let r = ask(&[0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0]);
        // SDO response (service 3), expedited 4 bytes (0x43), 0x029C.
        assert_eq!(r, [0x00, 0x30, 0x43, 0x18, 0x10, 0x01, 0x9c, 0x02, 0, 0]);
        let r = ask(&[0x40, 0x12, 0x1c, 0x01, 0, 0, 0, 0]);
        assert_eq!(
            &r[2..8],
            &[0x4b, 0x12, 0x1c, 0x01, 0x00, 0x16],
            "0x1C12:01 = 0x1600"
        );
        // 0x58AA: normal upload (0x41), size 5, "0.0.1" (DefaultData 302e302e31, line 4412).
        let r = ask(&[0x40, 0xaa, 0x58, 0x00, 0, 0, 0, 0]);
        assert_eq!(&r[2..10], &[0x41, 0xaa, 0x58, 0x00, 5, 0, 0, 0]);
        assert_eq!(&r[10..], b"0.0.1");
        // SDO Information (service 8), get entry description (0x05) of 0x6040:00: UNSIGNED16,
        // 16 bits, read and write in every state (0x3F) and RxPDO-mappable (0x40), the name
        // "Control Word" (line 3633).
        let req = [0x00, 0x80, 0x05, 0, 0, 0, 0x40, 0x60, 0x00, 0x00];
        let r = s.handle(&req, AlState::PreOp, 122).unwrap().unwrap();
        assert_eq!(&r[6..16], &[0x40, 0x60, 0, 0, 0x06, 0, 16, 0, 0x7f, 0]);
        assert_eq!(&r[16..], b"Control Word");
    }
}

/// The elements `<tag ...>text</tag>` of `text` (not nested, `tag` followed by a space or
/// `>`: `<Fmmu>` but not `<FmmuCount>`), as (the opening tag's attributes, the text).
fn elements<'a>(text: &'a str, tag: &str) -> Vec<(&'a str, &'a str)> {
    let open = format!("<{tag}");
    let close = format!("</{tag}>");
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(i) = text[at..].find(&open) {
        let from = at + i + open.len();
        at = from;
        if !matches!(text.as_bytes().get(from), Some(b' ' | b'>')) {
            continue;
        }
        let gt = from + text[from..].find('>').unwrap();
        let end = gt + text[gt..].find(&close).unwrap();
        out.push((&text[from..gt], text[gt + 1..end].trim()));
        at = end;
    }
    out
}

/// Attribute `name` of an opening tag's attributes.
fn attr_of<'a>(attrs: &'a str, name: &str) -> Option<&'a str> {
    let key = format!(" {name}=\"");
    let a = attrs.find(&key)? + key.len();
    Some(&attrs[a..a + attrs[a..].find('"')?])
}

/// Every ESI file in `../shared/esi/` (a file put there is tested too): each `Device` read by
/// the string search above gives the device the crate builds, its SII's identity words, its
/// SyncManager category (ETG.1000.6 table 23 via ETG.2010: start, length, control byte,
/// status 0, enable, type 1 MBoxOut / 2 MBoxIn / 3 Outputs / 4 Inputs; the mailbox's length
/// its DefaultSize, the process data's the bits of the PDOs assigned by default, those with an
/// `Sm` attribute), its FMMU category (1 Outputs, 2 Inputs, 3 MBoxState), its standard
/// mailbox words 0x18-0x1B (MBoxOut and MBoxIn start and DefaultSize) and word 0x1C (CoE, the
/// only protocol served). The KickCAT files' values are also written out by hand with their
/// lines, as a check of the search itself.
#[test]
#[ignore = "needs ../shared/esi"]
fn every_esi_file_of_the_folder_makes_the_sii_its_xml_says() {
    let dir = esi_dir();
    let mut files: Vec<std::path::PathBuf> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("xml")))
        .collect();
    files.sort();
    let names: Vec<String> = files
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect();
    for known in [
        "ingenia-evs-net-01.xml",
        "test-complex.xml",
        "test-sm-fmmu.xml",
    ] {
        assert!(names.iter().any(|n| n == known), "{known} in {names:?}");
    }
    for path in &files {
        let name = path.display();
        let xml = Xml::read(path);
        let file = esi::load(path).unwrap_or_else(|e| panic!("{name}: {e}"));
        let devices: Vec<(&str, &str)> = elements(&xml.0, "Device");
        assert_eq!(file.devices.len(), devices.len(), "{name}");
        let vendor = number(xml.between("<Vendor>", "<Id>", "</Id>"));
        for (d, (_, block)) in file.devices.iter().zip(&devices) {
            let ty = elements(block, "Type")[0].0;
            let dev = d.device_info(9);
            let id = (
                vendor,
                number(attr_of(ty, "ProductCode").unwrap()),
                number(attr_of(ty, "RevisionNo").unwrap()),
            );
            assert_eq!(
                (dev.vendor_id, dev.product_code, dev.revision),
                id,
                "{name}"
            );
            let esc = esc_of(&dev);
            let img = esc.sii_image();
            let w = |k: u16| sii::word(img, k).unwrap();
            let dword = |k: u16| u32::from(w(k)) | u32::from(w(k + 1)) << 16;
            assert_eq!(
                (dword(sii::WORD_VENDOR_ID), dword(sii::WORD_PRODUCT_CODE)),
                (id.0, id.1),
                "{name}"
            );
            assert_eq!(dword(sii::WORD_REVISION), id.2, "{name}");
            // The process data's bytes: the default-assigned PDOs' entries.
            let pdo_bytes = |tag: &str| {
                let bits: u32 = elements(block, tag)
                    .iter()
                    .filter(|(a, _)| attr_of(a, "Sm").is_some())
                    .flat_map(|(_, t)| elements(t, "BitLen"))
                    .map(|(_, b)| number(b))
                    .sum();
                bits.div_ceil(8) as u16
            };
            // The Device's SyncManagers (a `Dc/OpMode/Sm` names one, without StartAddress).
            let sms: Vec<_> = elements(block, "Sm")
                .into_iter()
                .filter(|(a, _)| attr_of(a, "StartAddress").is_some())
                .collect();
            let mut want = Vec::new();
            let mut mailbox = [None, None];
            for (a, text) in &sms {
                let start = number(attr_of(a, "StartAddress").unwrap()) as u16;
                let (ty, len) = match *text {
                    "MBoxOut" | "MBoxIn" => {
                        let len = number(attr_of(a, "DefaultSize").unwrap()) as u16;
                        mailbox[usize::from(*text == "MBoxIn")] = Some((start, len));
                        (if *text == "MBoxOut" { 1 } else { 2 }, len)
                    }
                    "Outputs" => (3, pdo_bytes("RxPdo")),
                    "Inputs" => (4, pdo_bytes("TxPdo")),
                    t => panic!("{name}: an Sm of {t}"),
                };
                want.extend_from_slice(&start.to_le_bytes());
                want.extend_from_slice(&len.to_le_bytes());
                let control = number(attr_of(a, "ControlByte").unwrap()) as u8;
                let enable = attr_of(a, "Enable").map_or(0, number) as u8;
                want.extend_from_slice(&[control, 0, enable, ty]);
            }
            let got = sii::find_category(img, category::SYNC_MANAGER).unwrap();
            assert_eq!(got.data, &want[..], "{name}: SyncManager category");
            let fmmus: Vec<u8> = elements(block, "Fmmu")
                .iter()
                .map(|(_, t)| match *t {
                    "Outputs" => 1,
                    "Inputs" => 2,
                    "MBoxState" => 3,
                    _ => 0,
                })
                .collect();
            // A category is whole words: an odd count is padded with an unused (0) FMMU.
            let got = sii::find_category(img, category::FMMU).unwrap();
            let n = fmmus.len();
            assert_eq!(&got.data[..n], &fmmus[..], "{name}: FMMU category");
            assert_eq!(got.data.len(), n.div_ceil(2) * 2, "{name}");
            assert!(got.data[n..].iter().all(|&b| b == 0), "{name}");
            if let [Some(out), Some(inp)] = mailbox {
                assert_eq!(
                    [w(0x18), w(0x19), w(0x1a), w(0x1b)],
                    [out.0, out.1, inp.0, inp.1],
                    "{name}: mailbox words"
                );
                assert_eq!(
                    w(sii::WORD_MAILBOX_PROTOCOL),
                    if block.contains("<CoE") { 0x0004 } else { 0 },
                    "{name}"
                );
            }
            // By hand from the files: test-sm-fmmu.xml lines 41-47, test-complex.xml 266-272.
            match path.file_name().unwrap().to_str().unwrap() {
                "test-sm-fmmu.xml" => {
                    assert_eq!(fmmus, [1, 2, 3]);
                    assert_eq!(
                        want,
                        [
                            0x00, 0x10, 128, 0, 0x26, 0, 1, 1, // MBoxOut
                            0x00, 0x14, 128, 0, 0x22, 0, 1, 2, // MBoxIn (virtual)
                            0x00, 0x18, 2, 0, 0x64, 0, 1, 3, // Outputs: 0x7000:01, 16 bits
                            0x00, 0x1c, 3, 0, 0x20, 0, 1, 4, // Inputs: 16 + 8 bits
                        ]
                    );
                }
                "test-complex.xml" => {
                    assert_eq!(fmmus, [1, 2, 3]);
                    assert_eq!(mailbox, [Some((0x1000, 0x80)), Some((0x1080, 0x80))]);
                    // No PDOs: the process data SyncManagers are empty.
                    assert_eq!(
                        &want[16..],
                        [
                            0x00, 0x11, 0, 0, 0x64, 0, 1, 3, 0x00, 0x14, 0, 0, 0x20, 0, 1, 4
                        ]
                    );
                }
                _ => {}
            }
        }
    }
}
