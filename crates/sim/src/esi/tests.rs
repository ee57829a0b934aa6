use super::*;
use proptest::prelude::*;

/// The ESI the project ships for its virtual drive.
const SHIPPED: &str = include_str!("../../../../esi/ecsync-virtual-drive.xml");

#[test]
fn numbers_are_hex_or_decimal() {
    assert_eq!(parse_int("#x1A00"), Some(0x1a00));
    assert_eq!(parse_int(" #x0CAFE "), Some(0xcafe));
    assert_eq!(parse_int("61935618"), Some(61_935_618));
    assert_eq!(parse_int("-3"), Some(-3));
    for bad in ["", "#x", "#xG1", "1.5", "0x", "#x-1", "one"] {
        assert_eq!(parse_int(bad), None, "{bad:?}");
    }
    assert_eq!(parse_hex("92010200"), Some(vec![0x92, 0x01, 0x02, 0x00]));
    assert_eq!(parse_hex("9 2"), Some(vec![0x92]));
    assert_eq!(parse_hex("920"), None);
    assert_eq!(parse_hex("zz"), None);
}

#[test]
fn the_esi_data_type_names_map_to_cia_codes() {
    for (name, code) in [
        ("BOOL", 0x0001),
        ("SINT", 0x0002),
        ("INT", 0x0003),
        ("DINT", 0x0004),
        ("USINT", 0x0005),
        ("UINT", 0x0006),
        ("UDINT", 0x0007),
        ("REAL", 0x0008),
        ("STRING(10)", 0x0009),
        ("ARRAY [0..511] OF BYTE", 0x000a),
        ("LREAL", 0x0011),
        ("ULINT", 0x001b),
        ("BIT2", 0x0031),
    ] {
        assert_eq!(data_type::from_esi_name(name), Some(code), "{name}");
    }
    assert_eq!(data_type::from_esi_name("DT1018"), None);
    assert_eq!(data_type::from_esi_name("ARRAY [1..4] OF UDINT"), None);
}

#[test]
fn the_shipped_esi_parses_with_its_defaults() {
    let f = parse("ecsync-virtual-drive.xml", SHIPPED).unwrap();
    let d = &f.devices[0];
    assert_eq!(f.vendor_id, 0x0e5c);
    assert_eq!((d.product_code, d.revision), (0x4024, 0x0001_0000));
    let od = d.dictionary();
    assert_eq!(od.read_u32(0x1c32, 2), 1_000_000, "cycle time 40420f00");
    assert_eq!(od.read_u32(0x1c32, 5), 31_250);
    assert_eq!(od.read(0x1008, 0).unwrap(), b"ecsync virtual servo drive");
    // ConfigData's 16 bytes: words 0-6 kept, word 7 dropped.
    assert_eq!(d.config_words, Some([0x0c05, 0, 100, 0, 0, 0, 0]));
}

#[test]
fn long_names_are_cut_for_the_sii() {
    let long = "\u{e9}".repeat(40);
    let text = SHIPPED.replace(
        "ecsync virtual servo drive</Name>",
        &format!("{long}</Name>"),
    );
    let f = parse("long.xml", &text).unwrap();
    assert_eq!(f.devices[0].name, long);
    let dev = f.devices[0].device_info(1);
    assert_eq!(dev.name, "\u{e9}".repeat(32), "64 bytes, whole characters");
}

#[test]
fn latin1_files_and_byte_order_marks_are_read() {
    let mut b = b"<?xml version=\"1.0\" encoding=\"ISO-8859-1\"?>\n".to_vec();
    let body = SHIPPED.split_once("?>").unwrap().1.replace(
        "ecsync virtual servo drive</Name>",
        "drive 5 \u{b5}s</Name>",
    );
    // The body in ISO-8859-1: the one non-ASCII character as its single byte 0xB5.
    b.extend(body.chars().map(|c| u8::try_from(u32::from(c)).unwrap()));
    let f = parse_bytes("latin1.xml", &b).unwrap();
    assert_eq!(f.devices[0].name, "drive 5 \u{b5}s");
    // Not UTF-8 and not declared otherwise: an error at the line of the bad byte.
    let bad = [
        b"<EtherCATInfo>\n<Vendor>".as_slice(),
        &[0xb5],
        b"</Vendor>",
    ]
    .concat();
    let e = parse_bytes("bad.xml", &bad).unwrap_err();
    assert_eq!((e.kind, e.line), (EsiErrorKind::Xml, Some(2)), "{e}");
    let bom = format!("\u{feff}{SHIPPED}");
    assert_eq!(parse("bom.xml", &bom).unwrap().vendor_id, 0x0e5c);
}

/// Parses `bytes` and, if it is a description, builds everything from it: the device, its
/// SDO server, its SII image, and reads every object with complete access.
fn exercise(bytes: &[u8]) -> Result<(), EsiError> {
    let f = parse_bytes("fuzz.xml", bytes)?;
    for d in &f.devices {
        let dev = d.device_info(1);
        let server = crate::coe::SdoServer::new(&dev);
        for o in server.od.objects() {
            let _ = server.od.read_complete(o.index, 0);
            for e in &o.entries {
                let _ = server.od.read(o.index, e.subindex);
            }
        }
        let img = crate::sii_image::build(&crate::model::EscModel::servo_mii(), &dev);
        assert!(ecsync_wire::sii::checksum_ok(&img));
    }
    Ok(())
}

fn lines(b: &[u8]) -> usize {
    b.iter().filter(|&&c| c == b'\n').count() + 1
}

#[test]
fn every_truncation_of_the_shipped_esi_is_an_error_with_a_line() {
    let b = SHIPPED.as_bytes();
    // Cut everywhere up to the last element's end tag (a cut after it leaves a whole file).
    let end = SHIPPED.rfind("</EtherCATInfo>").unwrap();
    for n in (0..end).step_by(7) {
        let e = exercise(&b[..n]).expect_err("a cut file is an error");
        let line = e.line.expect("a line");
        assert!((1..=lines(&b[..n])).contains(&line), "cut at {n}: {e}");
    }
    exercise(b).unwrap();
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Bytes of the shipped file replaced by XML's special characters, digits or anything:
    /// an error naming a line in the file, or a device built, never a panic.
    #[test]
    fn mutated_esi_never_panics(
        edits in proptest::collection::vec(
            (any::<proptest::sample::Index>(), prop_oneof![
                Just(b'<'), Just(b'>'), Just(b'/'), Just(b'"'), Just(b'='), Just(b'#'),
                Just(b'&'), Just(b';'), Just(b'x'), Just(b'0'), Just(b'F'), Just(b'\n'),
                Just(b' '), any::<u8>(),
            ]),
            1..8,
        ),
        cut in any::<proptest::sample::Index>(),
        do_cut in any::<bool>(),
    ) {
        let mut b = SHIPPED.as_bytes().to_vec();
        for (at, v) in edits {
            let i = at.index(b.len());
            b[i] = v;
        }
        if do_cut {
            b.truncate(cut.index(b.len()));
        }
        if let Err(e) = exercise(&b) {
            let line = e.line.unwrap_or(1);
            prop_assert!((1..=lines(&b)).contains(&line), "{e}");
            prop_assert!(!e.to_string().is_empty());
        }
    }

    /// Elements of the shipped file duplicated or removed (whole lines): never a panic.
    #[test]
    fn reshuffled_lines_never_panic(
        ops in proptest::collection::vec((any::<proptest::sample::Index>(), any::<bool>()), 1..6),
    ) {
        let mut ls: Vec<&str> = SHIPPED.lines().collect();
        for (at, dup) in ops {
            let i = at.index(ls.len());
            if dup {
                ls.insert(i, ls[i]);
            } else if ls.len() > 1 {
                ls.remove(i);
            }
        }
        let _ = exercise(ls.join("\n").as_bytes());
    }
}
