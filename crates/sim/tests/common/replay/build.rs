//! A segment built like the captured network: per slave an ESC of its silicon family with the
//! registers the capture read, its SII EEPROM as the capture read it, its mailbox and the
//! object dictionary its CoE answers show; cabled as its DL status says.

use super::network::{Network, SlaveFacts};
use ecsync_sim::clock::CrystalParams;
use ecsync_sim::coe::ObjectDictionary;
use ecsync_sim::model::{
    AlBehaviour, AlFirmware, DcSupport, DeviceInfo, ESC_TYPE_AKD, ESC_TYPE_LAN9252, EscModel,
    MailboxLayout, PdoDescription, PdoEntry, PortKind, SiiContents, SmDescription,
};
use ecsync_sim::{AnswerBufferHabit, Segment, SlaveSpec, Upstream, catalog};
use ecsync_wire::sii::{self, SmCategoryEntry, category};

/// Beckhoff's vendor ID (ETG vendor list) and the low half of its product codes: "EK"
/// couplers (0x2C52) and "EL" terminals (0x3052), e.g. EK1100 = 0x044C2C52 (1100 = 0x044C).
const BECKHOFF: u32 = 0x0000_0002;
const BECKHOFF_EK: u32 = 0x2c52;
const BECKHOFF_EL: u32 = 0x3052;

/// What a slave is built of.
#[derive(Debug, Clone)]
pub struct Slave {
    pub spec: SlaveSpec,
    /// Its SII EEPROM image.
    pub image: Vec<u8>,
    /// Its object dictionary, if it has a mailbox with CoE.
    pub dictionary: Option<ObjectDictionary>,
    /// What its application does with the answer buffer after the master read an answer.
    pub habit: AnswerBufferHabit,
}

/// The SII EEPROM of a slave from the words the capture read (an erased EEPROM, 0xFFFF,
/// elsewhere), as long as word 0x3E says (2 KiB if it was not read); word 0 (PDI control) as
/// the ESC loaded it into 0x0140 if the master read that, else the family's (`model`).
pub fn sii_image(f: &SlaveFacts, model: &EscModel) -> Vec<u8> {
    let bytes = f
        .sii_word(sii::WORD_SIZE)
        .filter(|&w| w < 0x100)
        .map_or(2048, |w| (usize::from(w) + 1) * 128);
    let mut img = vec![0xffu8; bytes];
    // Word 0 (PDI control, ESC configuration) as the ESC loaded it into 0x0140-0x0141,
    // where the master read those but not the word.
    if let Some(v) = f.reg16(0x0140).or(model.pdi_control) {
        img[..2].copy_from_slice(&v.to_le_bytes());
    }
    for (&w, &v) in &f.sii {
        let at = usize::from(w) * 2;
        if let Some(b) = img.get_mut(at..at + 2) {
            b.copy_from_slice(&v.to_le_bytes());
        }
    }
    img
}

/// The ESC model of a slave: its device family (crate::model's families) by its identity or
/// ESC type, with the DC unit the capture shows; a device of no family gets a generic model
/// with the registers the capture read over it.
fn model(f: &SlaveFacts, first: bool) -> EscModel {
    let vendor = f.sii_dword(sii::WORD_VENDOR_ID).unwrap_or(0);
    let product = f.sii_dword(sii::WORD_PRODUCT_CODE).unwrap_or(0);
    let esc_type = f.regs.get(&0x0000).copied();
    let dc = dc_support(f);
    let family = match (vendor, product & 0xffff, esc_type) {
        // Beckhoff's couplers (EK1100, EK1914) are ET1100 couplers, its terminals ET1200s; the
        // EL2889's ET1200 lacks 0x0008 bit 8 (the catalog's EL2889).
        (BECKHOFF, BECKHOFF_EK, _) => Some(EscModel::et1100_coupler()),
        (BECKHOFF, BECKHOFF_EL, _) if product == catalog::EL2889_PRODUCT.0 => Some(EscModel {
            enhanced_dc_sync: catalog::el2889_model().enhanced_dc_sync,
            ..EscModel::et1200_terminal(dc)
        }),
        (BECKHOFF, BECKHOFF_EL, _) => Some(EscModel::et1200_terminal(dc)),
        // By the ESC type of a network of one (BRD 0x0000): the AKD's, the LAN9252's.
        (_, _, Some(ESC_TYPE_AKD)) => Some(EscModel::akd_drive()),
        (_, _, Some(ESC_TYPE_LAN9252)) => Some(EscModel::lan9252()),
        _ => None,
    };
    let mut m = family.clone().unwrap_or_else(EscModel::servo_mii);
    // What the capture shows of the DC unit goes before the family's (the EK1914, an ET1100
    // coupler, keeps no system time).
    m.dc = dc;
    if f.mailbox.is_some() && m.al == AlBehaviour::DeviceEmulation {
        // A mailbox needs an application behind the PDI: a firmware runs AL, not the ESC's
        // device emulation (ESC datasheet section II, 0x0140 bit 8), whatever the family of
        // its ESC (the EK1914 is an ET1100 coupler with a microcontroller: written 0x11, its
        // AL status reads 0x01). How fast it answers is not the family's (taken within the
        // frame), nor is its PDI control word.
        m.al = AlBehaviour::Firmware(AlFirmware::INSTANT);
        m.pdi_control = None;
    }
    if m.al == AlBehaviour::Firmware(AlFirmware::INSTANT) && !f.al_windows.is_empty() {
        // A firmware whose time no family gives: the one that fits most of the capture's AL
        // transitions (the EK1914's), as the mailbox's answer time is fitted.
        m.al = AlBehaviour::Firmware(AlFirmware {
            response_ns: super::response_time(&f.al_windows),
            control_handshake: false,
        });
    }
    if family.is_none() {
        registers(&mut m, f);
    }
    ports_with_links(&mut m, f, first);
    m
}

/// The registers the capture read from the slave, over a generic model's.
fn registers(m: &mut EscModel, f: &SlaveFacts) {
    // 0x0008 bit 8, enhanced DC SYNC activation, as read (the EL2889's ET1200 lacks it).
    if let Some(v) = f.reg16(0x0008) {
        m.enhanced_dc_sync = v & 0x0100 != 0;
    }
    for (addr, field) in [
        (0x0000u16, 0usize),
        (0x0001, 1),
        (0x0004, 4),
        (0x0005, 5),
        (0x0006, 6),
    ] {
        if let Some(&v) = f.regs.get(&addr) {
            match field {
                0 => m.esc_type = v,
                1 => m.revision = v,
                4 => m.fmmu_count = v,
                5 => m.sm_count = v,
                _ => m.ram_kib = v,
            }
        }
    }
    if let Some(b) = f.reg16(0x0002) {
        m.build = b;
    }
    if let Some(&d) = f.regs.get(&0x0007) {
        for (p, k) in m.ports.iter_mut().enumerate() {
            *k = match (d >> (2 * p)) & 3 {
                0b10 => PortKind::Ebus,
                0b11 => PortKind::Mii,
                _ => PortKind::None,
            };
        }
    }
}

/// Whatever the model, a port with a link exists (and the first slave's port 0).
fn ports_with_links(m: &mut EscModel, f: &SlaveFacts, first: bool) {
    let links = links(f);
    for (p, (&link, kind)) in links.iter().zip(m.ports.iter_mut()).enumerate() {
        if (link || (first && p == 0)) && *kind == PortKind::None {
            *kind = PortKind::Mii;
        }
    }
}

/// The DC unit the capture shows: a system time where an access of 0x0910-0x0937 counted,
/// receive times only where those did not and 0x0900 did (or 0x0008 says DC), none where
/// 0x0008 says none.
fn dc_support(f: &SlaveFacts) -> DcSupport {
    let features = f.reg16(0x0008);
    let dc_bit = features.map(|v| v & 0x0004 != 0);
    let dc64 = features.is_none_or(|v| v & 0x0008 != 0);
    match (f.system_time, f.receive_times, dc_bit) {
        (Some(true), _, _) | (None, _, Some(true)) if dc64 => DcSupport::Full64,
        (Some(true), _, _) | (None, _, Some(true)) => DcSupport::Full32,
        (Some(false), Some(true), _) | (Some(false), _, Some(true)) => DcSupport::ReceiveTimes,
        (_, Some(true), _) => DcSupport::ReceiveTimes,
        _ => DcSupport::None,
    }
}

/// Which ports have a link (DL status 0x0110 bits 4-7); unread: ports 0 and 1.
pub fn links(f: &SlaveFacts) -> [bool; 4] {
    match f.reg16(0x0110) {
        Some(s) => std::array::from_fn(|p| s & (0x10 << p) != 0),
        None => [true, true, false, false],
    }
}

/// The PDOs of the SII's PDO categories (`kind` TXPDO or RXPDO).
fn pdos(img: &[u8], kind: u16) -> Vec<PdoDescription> {
    let mut out = Vec::new();
    for c in sii::categories(img)
        .filter_map(Result::ok)
        .filter(|c| c.kind == kind)
    {
        let mut d = c.data;
        while d.len() >= 8 {
            let n = usize::from(d[2]);
            let entries: Vec<PdoEntry> = d[8..]
                .chunks_exact(8)
                .take(n)
                .map(|e| PdoEntry {
                    index: u16::from_le_bytes([e[0], e[1]]),
                    subindex: e[2],
                    bits: e[5],
                    name: String::new(),
                })
                .collect();
            out.push(PdoDescription {
                index: u16::from_le_bytes([d[0], d[1]]),
                name: String::new(),
                sm: (d[3] != 0xff).then_some(d[3]),
                fixed: false,
                mandatory: false,
                entry_data_types: vec![0; entries.len()],
                entries,
            });
            d = d.get(8 + 8 * n..).unwrap_or_default();
        }
    }
    out
}

/// The device behind the ESC: identity, process data and SyncManagers from its SII, its
/// mailbox as the master set it up, answered `response_ns` after a request.
fn device(f: &SlaveFacts, img: &[u8], position: usize, response_ns: u64) -> DeviceInfo {
    let mut d = DeviceInfo::coupler(&format!("captured slave {position}"), 0);
    d.vendor_id = f.sii_dword(sii::WORD_VENDOR_ID).unwrap_or(0);
    d.product_code = f.sii_dword(sii::WORD_PRODUCT_CODE).unwrap_or(0);
    d.revision = f.sii_dword(sii::WORD_REVISION).unwrap_or(0);
    d.serial = f.sii_dword(sii::WORD_SERIAL).unwrap_or(0);
    d.alias = f.sii_word(sii::WORD_ALIAS).unwrap_or(0);
    d.mailbox = f.mailbox.map(|m| MailboxLayout {
        out_start: m.out_start,
        out_len: m.out_len,
        in_start: m.in_start,
        in_len: m.in_len,
        response_ns,
    });
    let sms: Vec<SmDescription> = sii::find_category(img, category::SYNC_MANAGER)
        .map(|c| {
            SmCategoryEntry::entries(c.data)
                .map(|e| SmDescription {
                    start: e.physical_start,
                    default_len: e.length_bytes,
                    control: e.control,
                    enable: e.enable & 1 != 0,
                    sm_type: e.kind,
                })
                .collect()
        })
        .unwrap_or_default();
    let (rx, tx) = (pdos(img, category::RXPDO), pdos(img, category::TXPDO));
    let assigned = |p: &[PdoDescription]| -> Vec<PdoEntry> {
        p.iter()
            .filter(|p| p.sm.is_some())
            .flat_map(|p| p.entries.clone())
            .collect()
    };
    d.outputs = assigned(&rx);
    d.inputs = assigned(&tx);
    if !sms.is_empty() {
        d.sii = Some(std::sync::Arc::new(SiiContents {
            config_words: None,
            eeprom_bytes: img.len(),
            mailbox_protocols: f.sii_word(sii::WORD_MAILBOX_PROTOCOL).unwrap_or(0),
            coe_details: 0,
            group: String::new(),
            order: String::new(),
            fmmus: Vec::new(),
            sync_managers: sms,
            rx_pdos: rx,
            tx_pdos: tx,
        }));
    }
    d
}

/// Cables: the first slave to the master; each slave's ports with a link, in the order a
/// frame leaves them (3, 1, 2), lead to the next slaves in auto-increment order, as a frame
/// reaches them (ESC datasheet section I, "Frame processing order").
fn upstreams(net: &Network) -> Vec<(Upstream, u8)> {
    let n = net.slaves.len();
    let links: Vec<[bool; 4]> = net.slaves.iter().map(links).collect();
    let mut up = vec![(Upstream::Master, 0u8); n];
    let mut next = 1;
    fn visit(p: usize, links: &[[bool; 4]], up: &mut [(Upstream, u8)], next: &mut usize) {
        for port in [3u8, 1, 2] {
            if links[p][usize::from(port)] && *next < up.len() {
                let c = *next;
                *next += 1;
                up[c] = (Upstream::Slave { index: p, port }, 0);
                visit(c, links, up, next);
            }
        }
    }
    visit(0, &links, &mut up, &mut next);
    // Slaves the link bits did not reach (DL status unread): in a line behind the last.
    for (c, u) in up.iter_mut().enumerate().skip(next) {
        *u = (
            Upstream::Slave {
                index: c - 1,
                port: 1,
            },
            0,
        );
    }
    up
}

/// The slaves of the captured network; `response_ns[p]` is slave `p`'s mailbox answer time.
pub fn slaves(
    net: &Network,
    dictionaries: Vec<Option<ObjectDictionary>>,
    response_ns: &[u64],
) -> Vec<Slave> {
    let up = upstreams(net);
    net.slaves
        .iter()
        .zip(dictionaries)
        .enumerate()
        .map(|(p, (f, dictionary))| {
            let mut model = model(f, p == 0);
            let image = sii_image(f, &model);
            // The port towards the upstream device exists.
            if model.ports[0] == PortKind::None {
                model.ports[0] = PortKind::Mii;
            }
            Slave {
                spec: SlaveSpec {
                    model,
                    device: device(f, &image, p, response_ns[p]),
                    crystal: CrystalParams {
                        seed: p as u64 + 1,
                        initial_local_ns: 1_000_000_000 * (p as u64 + 1),
                        ..Default::default()
                    },
                    upstream: up[p].0,
                    entry_port: up[p].1,
                    cable_m: 1.0,
                    ring: None,
                },
                image,
                dictionary,
                habit: AnswerBufferHabit::default(),
            }
        })
        .collect()
}

/// The segment of `slaves`: each ESC with its SII image and dictionary in place.
pub fn segment(slaves: &[Slave]) -> Segment {
    let specs: Vec<SlaveSpec> = slaves.iter().map(|s| s.spec.clone()).collect();
    let mut seg = Segment::new(&specs).expect("a segment like the captured one");
    for pos in 0..seg.len() {
        let s = &slaves[seg.spec_index(pos)];
        let esc = seg.esc_mut(pos);
        esc.load_sii_image(s.image.clone());
        esc.set_answer_buffer_habit(s.habit);
        if let (Some(od), Some(server)) = (&s.dictionary, esc.sdo_server_mut()) {
            server.od = od.clone();
        }
    }
    seg
}
