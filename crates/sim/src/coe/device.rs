//! The dictionary a device model serves: the communication objects every CoE device has and
//! the application objects its PDOs map, built from a [`DeviceInfo`].

use super::*;
use crate::model::DeviceInfo;

pub(super) fn var(
    index: u16,
    name: &str,
    data_type: u16,
    access: Access,
    value: Vec<u8>,
) -> Object {
    let bits = (value.len() * 8) as u16;
    Object {
        index,
        name: name.to_string(),
        code: ObjectCode::Var,
        entries: vec![Entry {
            subindex: 0,
            name: name.to_string(),
            data_type,
            bits,
            access,
            value,
            pdo_mapping: 0,
        }],
    }
}

fn entry(subindex: u8, name: &str, data_type: u16, access: Access, value: Vec<u8>) -> Entry {
    Entry {
        subindex,
        name: name.to_string(),
        data_type,
        bits: (value.len() * 8) as u16,
        access,
        value,
        pdo_mapping: 0,
    }
}

fn record(index: u16, name: &str, code: ObjectCode, access0: Access, rest: Vec<Entry>) -> Object {
    let count = rest.iter().map(|e| e.subindex).max().unwrap_or(0);
    let mut entries = vec![entry(
        0,
        "Subindex 000",
        data_type::UINT8,
        access0,
        vec![count],
    )];
    entries.extend(rest);
    Object {
        index,
        name: name.to_string(),
        code,
        entries,
    }
}

fn signed_type(bits: u8) -> u16 {
    match bits {
        8 => data_type::INT8,
        16 => data_type::INT16,
        _ => data_type::INT32,
    }
}

/// The SyncManager parameter object 0x1C32 (outputs) or 0x1C33 (inputs) of ETG.1020 (section
/// 12, "Synchronization"): the sync mode is written by the master in PRE-OP, the rest is the
/// drive's.
fn sm_parameters(index: u16, name: &str, cycle_ns: u32) -> Object {
    let rw = Access::ReadWritePreOp;
    let ro = Access::ReadOnly;
    let u16v = |v: u16| v.to_le_bytes().to_vec();
    record(
        index,
        name,
        ObjectCode::Record,
        Access::ReadOnly,
        vec![
            // 0 free run, 1 synchronous with the SM event, 2 DC SYNC0, 3 DC SYNC1.
            entry(1, "Sync mode", data_type::UINT16, rw, u16v(0)),
            entry(2, "Cycle time", data_type::UINT32, rw, u32v(cycle_ns)),
            entry(3, "Shift time", data_type::UINT32, ro, u32v(0)),
            // Bits 0 free run, 1 SM-synchronous, 2-4 DC (SYNC0, SYNC1, subordinated): free run,
            // SM and DC SYNC0 (0x0007), with the shift settable (bit 5). DC SYNC1 (3) is not
            // among them: a write of 3 to :01 is refused (0x06090030, see `check_sync_mode`).
            entry(
                4,
                "Sync modes supported",
                data_type::UINT16,
                ro,
                u16v(0x0027),
            ),
            // 31.25 us: the virtual drive's application (calc and copy 20 us) keeps up with
            // the fastest cycles fast drives take; SYNC0 faster than this refuses OP (0x0036).
            entry(5, "Minimum cycle time", data_type::UINT32, ro, u32v(31_250)),
            entry(6, "Calc and copy time", data_type::UINT32, ro, u32v(20_000)),
            entry(8, "Get cycle time", data_type::UINT16, rw, u16v(0)),
            entry(9, "Delay time", data_type::UINT32, ro, u32v(0)),
            entry(10, "Sync0 cycle time", data_type::UINT32, rw, u32v(0)),
            entry(11, "SM event missed", data_type::UINT16, ro, u16v(0)),
            entry(12, "Cycle time too small", data_type::UINT16, ro, u16v(0)),
            entry(32, "Sync error", data_type::BOOL, ro, vec![0]),
        ],
    )
}

/// A 32-bit value's bytes.
fn u32v(v: u32) -> Vec<u8> {
    v.to_le_bytes().to_vec()
}

/// The objects that say what `dev` is: device type 0x1000, name and versions 0x1008-0x100A,
/// identity 0x1018.
fn identity_objects(dev: &DeviceInfo) -> Vec<Object> {
    let ro = Access::ReadOnly;
    vec![
        var(
            0x1000,
            "Device type",
            data_type::UINT32,
            ro,
            u32v(DEVICE_TYPE_SERVO),
        ),
        var(
            0x1008,
            "Device name",
            data_type::VISIBLE_STRING,
            ro,
            dev.name.as_bytes().to_vec(),
        ),
        var(
            0x1009,
            "Hardware version",
            data_type::VISIBLE_STRING,
            ro,
            b"1.0".to_vec(),
        ),
        var(
            0x100a,
            "Software version",
            data_type::VISIBLE_STRING,
            ro,
            b"ecsync".to_vec(),
        ),
        record(
            0x1018,
            "Identity",
            ObjectCode::Record,
            ro,
            vec![
                entry(1, "Vendor ID", data_type::UINT32, ro, u32v(dev.vendor_id)),
                entry(
                    2,
                    "Product code",
                    data_type::UINT32,
                    ro,
                    u32v(dev.product_code),
                ),
                entry(3, "Revision", data_type::UINT32, ro, u32v(dev.revision)),
                entry(4, "Serial number", data_type::UINT32, ro, u32v(dev.serial)),
            ],
        ),
    ]
}

/// ETG.1020's error settings 0x10F1: the local error reaction (0: the ESM's default, to
/// SAFE-OP) and the sync error counter limit past which the drive leaves OP with 0x001A (see
/// esc/sync.rs; 0 here: count, do not react, the virtual drive's default).
fn error_settings() -> Object {
    record(
        0x10f1,
        "Error settings",
        ObjectCode::Record,
        Access::ReadOnly,
        vec![
            entry(
                1,
                "Local error reaction",
                data_type::UINT32,
                Access::ReadWrite,
                u32v(0),
            ),
            entry(
                2,
                "Sync error counter limit",
                data_type::UINT16,
                Access::ReadWrite,
                0u16.to_le_bytes().to_vec(),
            ),
        ],
    )
}

/// A PDO's mapping object (0x1600 outputs, 0x1A00 inputs): an entry per mapped object,
/// index, subindex and bits packed, writable in PRE-OP.
fn pdo_mapping(index: u16, name: &str, pdos: &[crate::model::PdoEntry]) -> Object {
    let rw = Access::ReadWritePreOp;
    record(
        index,
        name,
        ObjectCode::Record,
        rw,
        pdos.iter()
            .enumerate()
            .map(|(k, e)| {
                let v =
                    (u32::from(e.index) << 16) | (u32::from(e.subindex) << 8) | u32::from(e.bits);
                entry(
                    (k + 1) as u8,
                    &format!("SubIndex {:03}", k + 1),
                    data_type::UINT32,
                    rw,
                    u32v(v),
                )
            })
            .collect(),
    )
}

/// The SyncManager communication types 0x1C00: mailbox out and in, outputs, inputs.
fn sm_types() -> Object {
    let ro = Access::ReadOnly;
    let u8v = |v: u8| vec![v];
    record(
        0x1c00,
        "Sync manager type",
        ObjectCode::Array,
        ro,
        vec![
            entry(1, "SubIndex 001", data_type::UINT8, ro, u8v(1)),
            entry(2, "SubIndex 002", data_type::UINT8, ro, u8v(2)),
            entry(3, "SubIndex 003", data_type::UINT8, ro, u8v(3)),
            entry(4, "SubIndex 004", data_type::UINT8, ro, u8v(4)),
        ],
    )
}

/// A SyncManager's PDO assignment (0x1C12 outputs, 0x1C13 inputs): the mapping object `pdo`,
/// if any, writable in PRE-OP.
fn pdo_assign(index: u16, name: &str, pdo: Option<u16>) -> Object {
    let rw = Access::ReadWritePreOp;
    record(
        index,
        name,
        ObjectCode::Array,
        rw,
        pdo.map(|p| {
            entry(
                1,
                "SubIndex 001",
                data_type::UINT16,
                rw,
                p.to_le_bytes().to_vec(),
            )
        })
        .into_iter()
        .collect(),
    )
}

/// The application's objects that `dev`'s PDOs map, each once: the outputs writable, the
/// inputs read-only, zero.
fn application_objects(dev: &DeviceInfo) -> Vec<Object> {
    let mut app: Vec<Object> = Vec::new();
    for (e, mapping) in dev
        .outputs
        .iter()
        .map(|e| (e, 0x0040u16))
        .chain(dev.inputs.iter().map(|e| (e, 0x0080u16)))
    {
        if e.index == 0 || app.iter().any(|o| o.index == e.index) {
            continue;
        }
        let access = if mapping == 0x0040 {
            Access::ReadWrite
        } else {
            Access::ReadOnly
        };
        let dt = match (e.index, e.bits) {
            // The CiA 402 words are unsigned, the positions and velocities signed.
            (0x6040 | 0x6041 | 0x60b8, _) => data_type::UINT16,
            (_, 8) if e.index == 0x6060 || e.index == 0x6061 => data_type::INT8,
            (_, b) => signed_type(b),
        };
        let mut o = var(
            e.index,
            &e.name,
            dt,
            access,
            vec![0; usize::from(e.bits).div_ceil(8)],
        );
        o.entries[0].pdo_mapping = mapping;
        app.push(o);
    }
    app
}

impl ObjectDictionary {
    /// The dictionary of `dev`: the communication objects and an object per PDO entry.
    pub fn for_device(dev: &DeviceInfo) -> Self {
        let mut objects = identity_objects(dev);
        objects.push(error_settings());
        if !dev.outputs.is_empty() {
            objects.push(pdo_mapping(0x1600, "RxPDO map", &dev.outputs));
        }
        if !dev.inputs.is_empty() {
            objects.push(pdo_mapping(0x1a00, "TxPDO map", &dev.inputs));
        }
        objects.push(sm_types());
        objects.push(pdo_assign(
            0x1c12,
            "RxPDO assign",
            (!dev.outputs.is_empty()).then_some(0x1600),
        ));
        objects.push(pdo_assign(
            0x1c13,
            "TxPDO assign",
            (!dev.inputs.is_empty()).then_some(0x1a00),
        ));
        objects.push(sm_parameters(0x1c32, "SM output parameter", 1_000_000));
        objects.push(sm_parameters(0x1c33, "SM input parameter", 1_000_000));
        objects.extend(application_objects(dev));
        objects.sort_by_key(|o| o.index);
        let mut od = ObjectDictionary { objects };
        if dev.oversampling > 0 {
            // An oversampling terminal runs on SYNC1 too (bit 3), a sample every SYNC0 down
            // to 10 us (the EL4732's 100 kHz).
            od.set(0x1c32, 4, &0x002fu16.to_le_bytes());
            od.set(0x1c32, 5, &10_000u32.to_le_bytes());
        }
        od
    }

    /// This dictionary (a device description's) made fit to serve `dev`: the communication
    /// objects (below 0x2000) that [`ObjectDictionary::for_device`] has and this one lacks are
    /// added (the ESC reads 0x1C32:01, a master 0x1018 and the PDO assignment), and the identity
    /// 0x1018:01-04 is the device's own (its SII's): a real device answers its identity there,
    /// while an ESI's DefaultData for 0x1018 are what its generator wrote (Ingenia's EVS-NET-01
    /// gives product code 0x32 and revision 0 beside a `Type` of 0x03B11002 / 0x00050005).
    pub fn completed_for(mut self, dev: &DeviceInfo) -> Self {
        for o in ObjectDictionary::for_device(dev).objects {
            if o.index < 0x2000 && self.object(o.index).is_none() {
                self.objects.push(o);
            }
        }
        self.objects.sort_by_key(|o| o.index);
        for (sub, v) in [
            (1u8, dev.vendor_id),
            (2, dev.product_code),
            (3, dev.revision),
            (4, dev.serial),
        ] {
            self.set(0x1018, sub, &v.to_le_bytes());
        }
        self
    }
}
