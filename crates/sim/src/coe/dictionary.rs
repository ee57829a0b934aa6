//! The object dictionary: objects by index, reads and writes with the aborts a drive gives.

use super::*;
use ecsync_wire::AlState;
use ecsync_wire::mailbox::coe::SdoAbortCode;

/// The object dictionary of a device.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectDictionary {
    pub(super) objects: Vec<Object>,
}

/// CiA 402 device type of a servo drive: profile 402, type 2 (servo) in bits 16-23.
pub const DEVICE_TYPE_SERVO: u32 = 0x0002_0192;
impl ObjectDictionary {
    /// A dictionary of `objects` (a device description's), in index order; of two objects with
    /// one index the first is kept.
    pub fn from_objects(mut objects: Vec<Object>) -> Self {
        objects.sort_by_key(|o| o.index);
        objects.dedup_by_key(|o| o.index);
        ObjectDictionary { objects }
    }

    /// The objects, in index order.
    pub fn objects(&self) -> &[Object] {
        &self.objects
    }

    /// Object `index`.
    pub fn object(&self, index: u16) -> Option<&Object> {
        self.objects.iter().find(|o| o.index == index)
    }

    fn object_mut(&mut self, index: u16) -> Option<&mut Object> {
        self.objects.iter_mut().find(|o| o.index == index)
    }

    /// The value of `index:sub`.
    pub fn read(&self, index: u16, sub: u8) -> Result<Vec<u8>, SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        let e = o.entry(sub).ok_or(SdoAbortCode::NoSubindex)?;
        Ok(e.value.clone())
    }

    /// An unsigned value of up to 32 bits at `index:sub` (0 if absent).
    pub fn read_u32(&self, index: u16, sub: u8) -> u32 {
        self.read(index, sub).map_or(0, |v| {
            let mut b = [0u8; 4];
            let n = v.len().min(4);
            b[..n].copy_from_slice(&v[..n]);
            u32::from_le_bytes(b)
        })
    }

    /// Sets `index:sub` from the drive's side (counters, status), whatever its access.
    pub fn set(&mut self, index: u16, sub: u8, value: &[u8]) {
        if let Some(e) = self.object_mut(index).and_then(|o| o.entry_mut(sub))
            && e.value.len() == value.len()
        {
            e.value.copy_from_slice(value);
        }
    }

    /// The master writes `data` to `index:sub` in state `state`.
    pub fn write(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        let mapping_object = matches!(index, 0x1600..=0x17ff | 0x1a00..=0x1bff | 0x1c12 | 0x1c13);
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        let count = o
            .entries
            .first()
            .and_then(|e| e.value.first().copied())
            .unwrap_or(0);
        let max = o_max_sub(Some(o));
        let e = o.entry(sub).ok_or(SdoAbortCode::NoSubindex)?;
        match e.access {
            Access::ReadOnly => return Err(SdoAbortCode::ReadOnly),
            Access::ReadWritePreOp if state != AlState::PreOp => {
                return Err(SdoAbortCode::DeviceState);
            }
            _ => {}
        }
        let is_string = e.data_type == data_type::VISIBLE_STRING;
        if !is_string && data.len() != e.value.len() {
            return Err(if data.len() > e.value.len() {
                SdoAbortCode::LengthTooHigh
            } else {
                SdoAbortCode::LengthTooLow
            });
        }
        if mapping_object && sub > 0 && count != 0 {
            // ETG.1000.6: a mapping or assignment is changed with subindex 0 set to 0 first.
            return Err(SdoAbortCode::SubindexZeroMustBeZero);
        }
        if mapping_object && sub == 0 && data.first().is_some_and(|&c| c > max) {
            return Err(SdoAbortCode::ValueTooHigh);
        }
        if matches!(index, 0x1c32 | 0x1c33) && sub == 1 && data.len() == 2 {
            self.check_sync_mode(index, u16::from_le_bytes([data[0], data[1]]))?;
        }
        if let Some(e) = self.object_mut(index).and_then(|o| o.entry_mut(sub)) {
            if is_string {
                e.value = data.to_vec();
                e.bits = (data.len() * 8) as u16;
            } else {
                e.value.copy_from_slice(data);
            }
        }
        Ok(())
    }

    /// Whether the drive takes sync mode `mode` in 0x1C32:01 or 0x1C33:01 (`index`), as SSC's
    /// `CheckSyncTypeValue` decides from the supported modes of :04 (ETG.1020, "Sync modes
    /// supported": bit 0 free run, bit 1 synchronous with the SM event, bit 2 DC SYNC0, bit 3
    /// DC SYNC1): free run always; 1 (SM-synchronous) on 0x1C32 with outputs mapped, on 0x1C33
    /// of an input-only device; 0x22 (synchronous with SM2) on 0x1C33 with outputs mapped; 2
    /// and 3 where :04 has their bit. Any other value: 0x06090030, value range exceeded
    /// (SSC's ABORTIDX_VALUE_EXCEEDED). A dictionary without :04 (a device description that
    /// leaves it out) is not checked.
    fn check_sync_mode(&self, index: u16, mode: u16) -> Result<(), SdoAbortCode> {
        let Ok(supported) = self.read(index, 4) else {
            return Ok(());
        };
        let bits = supported.first().copied().unwrap_or(0);
        let outputs = !self.assigned_entries(0x1c12).is_empty();
        let inputs = !self.assigned_entries(0x1c13).is_empty();
        let ok = match mode {
            0 => true,
            1 if index == 0x1c32 => outputs && bits & 0x02 != 0,
            1 => !outputs && inputs && bits & 0x02 != 0,
            0x22 => index == 0x1c33 && outputs && bits & 0x02 != 0,
            2 => bits & 0x04 != 0,
            3 => bits & 0x08 != 0,
            _ => false,
        };
        if ok {
            Ok(())
        } else {
            Err(SdoAbortCode::ValueRange)
        }
    }

    /// A write of one entry, or with `complete_access` of the object from `sub`.
    pub fn write_access(
        &mut self,
        index: u16,
        sub: u8,
        complete_access: bool,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        if complete_access {
            self.write_complete(index, sub, data, state)
        } else {
            self.write(index, sub, data, state)
        }
    }

    /// A complete access read from `sub` (0 or 1).
    pub fn read_complete(&self, index: u16, sub: u8) -> Result<Vec<u8>, SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        if o.code == ObjectCode::Var || sub > 1 {
            return Err(SdoAbortCode::UnsupportedAccess);
        }
        Ok(o.complete(sub))
    }

    /// A complete access write from `sub` (0 or 1): subindex 0 (16 bits) and the entries up
    /// to the count it gives, each as long as it is.
    pub fn write_complete(
        &mut self,
        index: u16,
        sub: u8,
        data: &[u8],
        state: AlState,
    ) -> Result<(), SdoAbortCode> {
        let o = self.object(index).ok_or(SdoAbortCode::NoObject)?;
        if o.code == ObjectCode::Var || sub > 1 {
            return Err(SdoAbortCode::UnsupportedAccess);
        }
        let mut at = 0usize;
        let mut writes: Vec<(u8, Vec<u8>)> = Vec::new();
        let count = if sub == 0 {
            let Some(&c) = data.first() else {
                return Err(SdoAbortCode::LengthTooLow);
            };
            at = 2;
            c
        } else {
            o.entries
                .first()
                .and_then(|e| e.value.first().copied())
                .unwrap_or(0)
        };
        for s in 1..=count {
            let e = o.entry(s).ok_or(SdoAbortCode::ValueTooHigh)?;
            let n = e.value.len();
            let Some(v) = data.get(at..at + n) else {
                return Err(SdoAbortCode::LengthTooLow);
            };
            writes.push((s, v.to_vec()));
            at += n;
        }
        if at != data.len() {
            return Err(SdoAbortCode::LengthTooHigh);
        }
        // Subindex 0 to 0, the entries, then the count: the order a master writes them in.
        if sub == 0 {
            self.write(index, 0, &[0], state)?;
        }
        for (s, v) in &writes {
            self.write(index, *s, v, state)?;
        }
        if sub == 0 {
            self.write(index, 0, &[count], state)?;
        }
        Ok(())
    }

    /// The PDO entries (index, subindex, bits) the assignment `assign` (0x1C12 or 0x1C13)
    /// and the mappings it names lay out, in order.
    pub fn assigned_entries(&self, assign: u16) -> Vec<(u16, u8, u8)> {
        let mut out = Vec::new();
        let n = self.read_u32(assign, 0) as u8;
        for s in 1..=n {
            let pdo = self.read_u32(assign, s) as u16;
            let m = self.read_u32(pdo, 0) as u8;
            for k in 1..=m {
                let v = self.read_u32(pdo, k);
                out.push(((v >> 16) as u16, (v >> 8) as u8, v as u8));
            }
        }
        out
    }

    /// Adds `object`, in index order, in place of one with the same index (a device
    /// description's own objects over the communication objects [`Self::for_device`] makes).
    pub fn insert(&mut self, object: Object) {
        match self
            .objects
            .binary_search_by_key(&object.index, |o| o.index)
        {
            Ok(i) => self.objects[i] = object,
            Err(i) => self.objects.insert(i, object),
        }
    }
}

pub(super) fn o_max_sub(o: Option<&Object>) -> u8 {
    o.and_then(|o| o.entries.iter().map(|e| e.subindex).max())
        .unwrap_or(0)
}
