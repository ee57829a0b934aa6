//! VLAN tags: taken off a request before the segment sees it, put back on its answer.

use crate::sys::{TPID_8021AD, TPID_8021Q, VlanTag};

/// Most VLAN tags a frame may carry (802.1ad S-tag outside, 802.1Q C-tag inside).
pub(super) const MAX_TAGS: usize = 2;

/// The VLAN tags a frame arrived in, outermost first.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(super) struct Tags {
    tags: [Option<VlanTag>; MAX_TAGS],
}

impl Tags {
    pub(super) fn len(&self) -> usize {
        self.tags.iter().flatten().count()
    }

    fn push(&mut self, t: VlanTag) -> bool {
        match self.tags.iter_mut().find(|s| s.is_none()) {
            Some(slot) => {
                *slot = Some(t);
                true
            }
            None => false,
        }
    }
}

/// Takes the frame's VLAN tags off: the one the kernel took off already (`stripped`), then those
/// still in the bytes, in place. Returns the untagged length and the tags, or `None` when there
/// are more tags than [`MAX_TAGS`].
pub(super) fn untag(
    frame: &mut [u8],
    mut len: usize,
    stripped: Option<VlanTag>,
) -> Option<(usize, Tags)> {
    let mut tags = Tags::default();
    if let Some(t) = stripped {
        tags.push(t);
    }
    while len >= 18 {
        let tpid = u16::from_be_bytes([frame[12], frame[13]]);
        if tpid != TPID_8021Q && tpid != TPID_8021AD {
            break;
        }
        let tci = u16::from_be_bytes([frame[14], frame[15]]);
        if !tags.push(VlanTag { tpid, tci }) {
            return None;
        }
        frame.copy_within(16..len, 12);
        len -= 4;
    }
    Some((len, tags))
}

/// Puts `tags` back after the source address of the untagged frame `frame[..len]`; `frame` has
/// room for them. Returns the tagged length.
pub(super) fn retag(frame: &mut [u8], len: usize, tags: &Tags) -> usize {
    let n = 4 * tags.len();
    frame.copy_within(12..len, 12 + n);
    for (i, t) in tags.tags.iter().flatten().enumerate() {
        frame[12 + 4 * i..16 + 4 * i].copy_from_slice(&t.to_bytes());
    }
    len + n
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(tags: &[[u8; 4]]) -> Vec<u8> {
        let mut f = vec![0xff; 6];
        f.extend_from_slice(&[0x02, 0, 0, 0, 0, 1]);
        for t in tags {
            f.extend_from_slice(t);
        }
        f.extend_from_slice(&[0x88, 0xa4, 0x0c, 0x10, 7, 0x5a]);
        f.resize(f.len() + 32, 0);
        f
    }

    #[test]
    fn tags_come_off_and_go_back_where_they_were() {
        // 802.1Q, PCP 5, VID 0x123: TCI 0xa123.
        let q = VlanTag {
            tpid: TPID_8021Q,
            tci: 0xa123,
        };
        assert_eq!((q.vid(), q.pcp()), (0x123, 5));
        let tagged = frame(&[q.to_bytes()]);
        assert_eq!(&tagged[12..18], &[0x81, 0x00, 0xa1, 0x23, 0x88, 0xa4]);
        let plain = frame(&[]);
        // In the bytes.
        let mut buf = tagged.clone();
        buf.resize(tagged.len() + 8, 0);
        let (len, tags) = untag(&mut buf, tagged.len(), None).unwrap();
        assert_eq!(&buf[..len], &plain[..]);
        assert_eq!(tags.len(), 1);
        assert_eq!(retag(&mut buf, len, &tags), tagged.len());
        assert_eq!(&buf[..tagged.len()], &tagged[..]);
        // Taken off by the kernel (auxiliary data): the bytes are untagged.
        let mut buf = plain.clone();
        buf.resize(plain.len() + 8, 0);
        let (len, tags) = untag(&mut buf, plain.len(), Some(q)).unwrap();
        assert_eq!(len, plain.len());
        let n = retag(&mut buf, len, &tags);
        assert_eq!(&buf[..n], &tagged[..]);
        // 802.1ad outside (from the kernel), 802.1Q inside (in the bytes).
        let s = VlanTag {
            tpid: TPID_8021AD,
            tci: 0x0007,
        };
        let qinq = frame(&[s.to_bytes(), q.to_bytes()]);
        let mut buf = frame(&[q.to_bytes()]);
        buf.resize(buf.len() + 8, 0);
        let (len, tags) = untag(&mut buf, qinq.len() - 4, Some(s)).unwrap();
        assert_eq!(&buf[..len], &plain[..]);
        let n = retag(&mut buf, len, &tags);
        assert_eq!(&buf[..n], &qinq[..]);
        // Untagged frames stay as they are.
        let mut buf = plain.clone();
        let (len, tags) = untag(&mut buf, plain.len(), None).unwrap();
        assert_eq!((len, tags.len()), (plain.len(), 0));
        assert_eq!(retag(&mut buf, len, &tags), plain.len());
        assert_eq!(buf, plain);
        // Three tags: refused.
        let mut buf = frame(&[q.to_bytes(), q.to_bytes(), q.to_bytes()]);
        let n = buf.len();
        assert!(untag(&mut buf, n, None).is_none());
    }
}
