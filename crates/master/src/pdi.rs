//! The logical process image in LRW datagrams of at most a frame each.
//!
//! The bring-up maps every slave's outputs, then every slave's inputs, one after the other into
//! the logical address space. A network whose image is larger than a frame's payload needs
//! several LRWs: each covers a contiguous range that ends on a slave's boundary, so that no
//! slave's image is split, and the working counter each must return is known: 2 for every
//! slave whose outputs it writes, 1 for every slave whose inputs it reads (datasheet: an LRW
//! counts 1 for a read, 2 for a write, per slave and datagram).

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

/// Splits the image of `ranges` (each slave's `(logical, len, wkc)` range, in logical order,
/// outputs with wkc 2, inputs with 1) into LRWs of at most [`MAX_LRW_DATA`] bytes. One chunk
/// when the whole image fits.
pub fn lrw_chunks(pdi_len: u32, ranges: &[(u32, u32, u16)]) -> Vec<LrwChunk> {
    if pdi_len == 0 {
        return Vec::new();
    }
    let max = MAX_LRW_DATA as u32;
    if pdi_len <= max {
        return vec![LrwChunk {
            logical: 0,
            len: pdi_len,
            expected_wkc: ranges.iter().map(|r| r.2).sum(),
        }];
    }
    let mut out: Vec<LrwChunk> = Vec::new();
    let mut cur = LrwChunk {
        logical: 0,
        len: 0,
        expected_wkc: 0,
    };
    for &(logical, len, wkc) in ranges {
        let end = logical + len;
        if end - cur.logical > max && cur.len > 0 {
            out.push(cur);
            cur = LrwChunk {
                logical: cur.logical + cur.len,
                len: 0,
                expected_wkc: 0,
            };
        }
        cur.len = end - cur.logical;
        cur.expected_wkc += wkc;
    }
    if cur.len > 0 || out.is_empty() {
        out.push(cur);
    }
    // Gaps after the last range (none in the bring-up's packed image) stay out.
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_small_image_is_one_lrw() {
        let r = [(0, 16, 2), (16, 16, 2), (32, 18, 1), (50, 18, 1)];
        assert_eq!(
            lrw_chunks(68, &r),
            [LrwChunk {
                logical: 0,
                len: 68,
                expected_wkc: 6
            }]
        );
    }

    #[test]
    fn a_large_image_is_split_on_slave_boundaries() {
        // 100 slaves of 16 output and 18 input bytes: 3400 bytes.
        let mut r = Vec::new();
        for i in 0..100u32 {
            r.push((16 * i, 16, 2));
        }
        for i in 0..100u32 {
            r.push((1600 + 18 * i, 18, 1));
        }
        let c = lrw_chunks(3400, &r);
        assert!(c.len() >= 3, "{c:?}");
        let mut at = 0;
        for k in &c {
            assert_eq!(k.logical, at, "contiguous");
            assert!(k.len as usize <= MAX_LRW_DATA);
            // Ends on a slave's boundary.
            assert!(r.iter().any(|x| x.0 + x.1 == k.logical + k.len));
            at += k.len;
        }
        assert_eq!(at, 3400);
        assert_eq!(
            c.iter().map(|k| u32::from(k.expected_wkc)).sum::<u32>(),
            300
        );
    }
}
