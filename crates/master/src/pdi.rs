//! The logical process image in LRW datagrams of at most a frame each.
//!
//! An image that fits one frame is every slave's outputs, then every slave's inputs, in one LRW.
//! A larger one is split into groups of consecutive slaves, each group's outputs then its inputs
//! in one LRW of at most a frame (as TwinCAT assigns slaves to frames), so that no slave's image
//! is split and a slave's outputs and inputs travel in the same frame: the slave then acts in
//! two frames of the cycle (the first one's DC datagrams and its own LRW), not three. The
//! working counter each LRW must return is known: 2 for every slave whose outputs it writes, 1
//! for every slave whose inputs it reads (datasheet: an LRW counts 1 for a read, 2 for a write,
//! per slave and datagram).

use ecsync_wire::{DATAGRAM_OVERHEAD, ECAT_HEADER_LEN, ETH_HEADER_LEN, MAX_FRAME_LEN};

/// One LRW of the cyclic exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct LrwChunk {
    /// Logical address of its first byte.
    pub logical: u32,
    /// Bytes.
    pub len: u32,
    /// The working counter it returns when every slave it covers answers.
    pub expected_wkc: u16,
}

/// The payload of one frame, bytes.
pub const FRAME_PAYLOAD: usize = MAX_FRAME_LEN - ETH_HEADER_LEN - ECAT_HEADER_LEN;

/// The largest LRW data that fits a frame on its own.
pub const MAX_LRW_DATA: usize = FRAME_PAYLOAD - DATAGRAM_OVERHEAD;

/// Where one slave's process data sits in the logical image: `(logical address, bytes)` of
/// its outputs and of its inputs (0 bytes: none, at the place it would have had).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SlaveImage {
    /// Outputs (RxPDO): logical address and bytes.
    pub outputs: (u32, u16),
    /// Inputs (TxPDO): logical address and bytes.
    pub inputs: (u32, u16),
}

/// The logical image of slaves with `sizes` (output and input bytes each, in network order).
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct ImageLayout {
    /// Each slave's place, in the order of `sizes`.
    pub slaves: Vec<SlaveImage>,
    /// Bytes of the whole image.
    pub pdi_len: u32,
    /// Its LRWs, in logical order, contiguous.
    pub lrw: Vec<LrwChunk>,
}

/// Lays out the image of slaves with `sizes` (see the module docs). A single slave larger than
/// [`MAX_LRW_DATA`] gets an LRW of its own, which then does not fit a frame (the cyclic
/// engine's frame plan refuses it).
pub fn layout(sizes: &[(u16, u16)]) -> ImageLayout {
    let bytes = |&(o, i): &(u16, u16)| u32::from(o) + u32::from(i);
    let total: u32 = sizes.iter().map(bytes).sum();
    let max = MAX_LRW_DATA as u32;
    // Groups of consecutive slaves [from, to): one when everything fits.
    let mut groups: Vec<(usize, usize)> = Vec::new();
    if total <= max {
        groups.push((0, sizes.len()));
    } else {
        let (mut from, mut in_group) = (0, 0u32);
        for (i, s) in sizes.iter().enumerate() {
            if in_group + bytes(s) > max && in_group > 0 {
                groups.push((from, i));
                (from, in_group) = (i, 0);
            }
            in_group += bytes(s);
        }
        groups.push((from, sizes.len()));
    }
    let mut out = ImageLayout {
        slaves: vec![SlaveImage::default(); sizes.len()],
        ..ImageLayout::default()
    };
    let mut logical = 0u32;
    for (from, to) in groups {
        let start = logical;
        let mut expected_wkc = 0u16;
        for (s, &(o, _)) in out.slaves[from..to].iter_mut().zip(&sizes[from..to]) {
            s.outputs = (logical, o);
            logical += u32::from(o);
            if o > 0 {
                expected_wkc = expected_wkc.wrapping_add(2);
            }
        }
        for (s, &(_, i)) in out.slaves[from..to].iter_mut().zip(&sizes[from..to]) {
            s.inputs = (logical, i);
            logical += u32::from(i);
            if i > 0 {
                expected_wkc = expected_wkc.wrapping_add(1);
            }
        }
        if logical > start {
            out.lrw.push(LrwChunk {
                logical: start,
                len: logical - start,
                expected_wkc,
            });
        }
    }
    out.pdi_len = logical;
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_image_is_every_output_then_every_input_in_one_lrw() {
        let l = layout(&[(16, 18), (16, 18), (0, 4), (2, 0)]);
        assert_eq!(
            l.lrw,
            [LrwChunk {
                logical: 0,
                len: 74,
                expected_wkc: 2 + 2 + 2 + 1 + 1 + 1
            }]
        );
        let at: Vec<_> = l.slaves.iter().map(|s| (s.outputs, s.inputs)).collect();
        assert_eq!(
            at,
            [
                ((0, 16), (34, 18)),
                ((16, 16), (52, 18)),
                ((32, 0), (70, 4)),
                ((32, 2), (74, 0)),
            ]
        );
        assert_eq!(l.pdi_len, 74);
    }

    #[test]
    fn a_large_image_is_split_into_groups_of_whole_slaves() {
        // 100 slaves of 16 output and 18 input bytes: 3400 bytes, 43 slaves to a frame.
        let sizes = vec![(16u16, 18u16); 100];
        let l = layout(&sizes);
        assert_eq!(l.pdi_len, 3400);
        assert_eq!(l.lrw.len(), 3, "{:?}", l.lrw);
        let mut at = 0;
        for c in &l.lrw {
            assert_eq!(c.logical, at, "contiguous");
            assert!(c.len as usize <= MAX_LRW_DATA);
            at += c.len;
            // Every slave has both its outputs and its inputs in one chunk, or none there.
            let inside =
                |a: (u32, u16)| a.0 >= c.logical && a.0 + u32::from(a.1) <= c.logical + c.len;
            let held: Vec<_> = l.slaves.iter().filter(|s| inside(s.outputs)).collect();
            assert!(held.iter().all(|s| inside(s.inputs)));
            assert_eq!(c.expected_wkc as usize, 3 * held.len());
            // A frame's worth: the next slave would not have fitted.
            assert!(c.len as usize + 34 > MAX_LRW_DATA || c.logical + c.len == 3400);
        }
        assert_eq!(at, 3400);
        // No byte is two slaves'.
        let mut bytes: Vec<u32> = l
            .slaves
            .iter()
            .flat_map(|s| [s.outputs, s.inputs])
            .flat_map(|(a, n)| a..a + u32::from(n))
            .collect();
        bytes.sort_unstable();
        bytes.dedup();
        assert_eq!(bytes.len(), 3400);
    }
}
