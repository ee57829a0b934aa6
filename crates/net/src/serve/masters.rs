//! Two masters on one segment: a real segment answers both, and each sees the other's writes
//! as its slaves misbehaving. The served segment answers both too (as the wire would), but
//! says so once: a second source address, or two index streams interleaved from one address
//! (two master processes on one interface).

/// Frames in a window of the index watch.
const WINDOW: u32 = 256;
/// Backward steps of the first datagram's index in a window that mean two streams: one
/// master's index only moves forward (a retry repeats it), two interleaved ones step back
/// about every other frame.
const BACKWARD_STEPS: u32 = 96;

/// What the watch found, once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SecondMaster {
    /// Frames from a second source address.
    Address {
        /// The first master's address.
        first: [u8; 6],
        /// The other one.
        other: [u8; 6],
    },
    /// From one address, the datagram indices of two interleaved streams.
    Interleaved {
        /// The address.
        address: [u8; 6],
        /// Backward steps of the index in the window that showed it.
        backward_steps: u32,
    },
}

fn mac(a: &[u8; 6]) -> String {
    a.iter()
        .map(|b| format!("{b:02x}"))
        .collect::<Vec<_>>()
        .join(":")
}

impl std::fmt::Display for SecondMaster {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SecondMaster::Address { first, other } => write!(
                f,
                "a second master on the segment: frames from {} besides {}; the slaves answer both, and each master sees the other's writes (stop one of them)",
                mac(other),
                mac(first)
            ),
            SecondMaster::Interleaved {
                address,
                backward_steps,
            } => write!(
                f,
                "a second master on the segment: from {} the datagram index stepped back {backward_steps} times in {WINDOW} frames, as two master processes on one interface interleave; the slaves answer both (stop one of them)",
                mac(address)
            ),
        }
    }
}

/// Watches the requests' source addresses and index streams.
#[derive(Debug, Default)]
pub struct MasterWatch {
    first: Option<[u8; 6]>,
    last_index: Option<u8>,
    in_window: u32,
    backward: u32,
    /// Frames from a source address other than the first master's.
    pub other_address_frames: u64,
    found: bool,
}

impl MasterWatch {
    /// Looks at one request (Ethernet, untagged). Returns what it found, the first time only.
    pub fn see(&mut self, frame: &[u8]) -> Option<SecondMaster> {
        if frame.len() < 18 {
            return None;
        }
        let mut src = [0u8; 6];
        src.copy_from_slice(&frame[6..12]);
        // Bit 0x02 of the first byte is set by the ESCs on a frame that passed them: the same
        // master either way.
        src[0] &= !0x02;
        let first = *self.first.get_or_insert(src);
        if src != first {
            self.other_address_frames += 1;
            return self.report(SecondMaster::Address { first, other: src });
        }
        // The first datagram's index: after the Ethernet header (14), the EtherCAT header
        // (2) and the command (1).
        let index = frame[17];
        if let Some(last) = self.last_index.replace(index)
            && index.wrapping_sub(last) >= 128
        {
            self.backward += 1;
        }
        self.in_window += 1;
        if self.in_window == WINDOW {
            let backward_steps = self.backward;
            (self.in_window, self.backward) = (0, 0);
            if backward_steps >= BACKWARD_STEPS {
                return self.report(SecondMaster::Interleaved {
                    address: first,
                    backward_steps,
                });
            }
        }
        None
    }

    fn report(&mut self, s: SecondMaster) -> Option<SecondMaster> {
        (!std::mem::replace(&mut self.found, true)).then_some(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(src0: u8, index: u8) -> Vec<u8> {
        let mut f = vec![0xff; 6];
        f.extend_from_slice(&[src0, 0, 0, 0, 0, 1, 0x88, 0xa4, 0x0c, 0x10, 7, index]);
        f.resize(60, 0);
        f
    }

    #[test]
    fn one_master_is_one_master_whatever_its_index_does() {
        let mut w = MasterWatch::default();
        // Forward steps, wraps, retries (the same index again), a passed-ESC bit.
        for i in 0..5000u32 {
            let index = (i / 2) as u8;
            let src0 = if i % 7 == 0 { 0x02 } else { 0x00 };
            assert_eq!(w.see(&frame(src0, index)), None, "frame {i}");
        }
    }

    #[test]
    fn a_second_address_or_two_interleaved_streams_are_found_once() {
        let mut w = MasterWatch::default();
        assert_eq!(w.see(&frame(0x00, 1)), None);
        let found = w.see(&frame(0x10, 1));
        assert!(
            matches!(found, Some(SecondMaster::Address { .. })),
            "{found:?}"
        );
        assert!(found.unwrap().to_string().contains("10:00:00:00:00:01"));
        assert_eq!(w.see(&frame(0x10, 2)), None);
        assert_eq!(w.other_address_frames, 2);
        // Two SOEM processes on one interface: indices 0,1,2... and 100,101,... interleaved.
        let mut w = MasterWatch::default();
        let mut found = None;
        for i in 0..2 * WINDOW {
            let index = if i % 2 == 0 { i / 2 } else { 100 + i / 2 } as u8;
            if let Some(f) = w.see(&frame(0, index)) {
                found = Some((i, f));
            }
        }
        let (at, f) = found.expect("interleaved streams found");
        assert_eq!(at, WINDOW - 1, "at the end of the first window");
        assert!(
            matches!(f, SecondMaster::Interleaved { backward_steps, .. } if backward_steps >= BACKWARD_STEPS)
        );
    }
}
