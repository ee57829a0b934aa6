//! The merge and the second copy, worked out by hand on frames built byte by byte.

use super::*;

/// An Ethernet + EtherCAT frame of `datagrams` (command, index, ADO, data, wkc), the source
/// address ending in `src_last`.
fn frame(datagrams: &[(u8, u8, u16, &[u8], u16)], src_last: u8) -> Vec<u8> {
    let mut f = vec![0xff; 6];
    f.extend_from_slice(&[0x02, 0, 0, 0, 0, src_last]);
    f.extend_from_slice(&[0x88, 0xa4]);
    let body: usize = datagrams.iter().map(|d| 12 + d.3.len()).sum();
    f.extend_from_slice(&((body as u16) | 0x1000).to_le_bytes());
    for (i, &(cmd, idx, ado, data, wkc)) in datagrams.iter().enumerate() {
        f.extend_from_slice(&[cmd, idx, 0, 0]);
        f.extend_from_slice(&ado.to_le_bytes());
        let more = if i + 1 < datagrams.len() { 0x8000 } else { 0 };
        f.extend_from_slice(&((data.len() as u16) | more).to_le_bytes());
        f.extend_from_slice(&[0, 0]);
        f.extend_from_slice(data);
        f.extend_from_slice(&wkc.to_le_bytes());
    }
    f
}

/// An LRW of 4 bytes (outputs 0xAA 0xBB for a drive on the near side, inputs in bytes 2 and
/// 3: byte 2 the near drive's, byte 3 the far one's) and a BRD of the AL status: the near
/// side returns its input and wkc 3 (LRW) and 1 (BRD, status 0x08), the far side its input
/// and 3 and 1 (status 0x12, an error flag): merged, both inputs, wkc 6 and 2, 0x08 | 0x12.
#[test]
fn two_sides_merge_into_the_intact_lines_frame() {
    let sent = frame(
        &[
            (12, 7, 0, &[0xaa, 0xbb, 0, 0], 0),
            (7, 8, 0x130, &[0, 0], 0),
        ],
        1,
    );
    let near = frame(
        &[
            (12, 7, 0, &[0xaa, 0xbb, 0x11, 0], 3),
            (7, 8, 0x130, &[0x08, 0], 1),
        ],
        1,
    );
    let far = frame(
        &[
            (12, 7, 0, &[0xaa, 0xbb, 0, 0x22], 3),
            (7, 8, 0x130, &[0x12, 0], 1),
        ],
        0,
    );
    let mut out = vec![0; sent.len()];
    merge(&sent, &near, &far, &mut out);
    let want = frame(
        &[
            (12, 7, 0, &[0xaa, 0xbb, 0x11, 0x22], 6),
            (7, 8, 0x130, &[0x1a, 0], 2),
        ],
        1,
    );
    assert_eq!(out, want);
}

/// The second copy: its source's last byte flipped, FRMW (14) and ARMW (13) and a BWR (8) of
/// 0x0900 made NOPs, an LRW (12) and a BWR elsewhere kept.
#[test]
fn the_second_copy_carries_no_clock_write() {
    let sent = frame(
        &[
            (14, 1, 0x910, &[0; 8], 0),
            (12, 2, 0, &[1, 2], 0),
            (8, 3, 0x900, &[0; 4], 0),
            (8, 4, 0x120, &[8, 0], 0),
            (13, 5, 0x910, &[0; 8], 0),
        ],
        0x10,
    );
    let mut out = vec![0; sent.len()];
    second_copy(&sent, &mut out);
    let want = frame(
        &[
            (0, 1, 0x910, &[0; 8], 0),
            (12, 2, 0, &[1, 2], 0),
            (0, 3, 0x900, &[0; 4], 0),
            (8, 4, 0x120, &[8, 0], 0),
            (0, 5, 0x910, &[0; 8], 0),
        ],
        0x11,
    );
    assert_eq!(out, want);
}

/// A malformed chain (a length past the frame's end) is left as it is, and never panics.
#[test]
fn malformed_frames_pass_untouched() {
    let mut f = frame(&[(14, 1, 0x910, &[0; 8], 0)], 0);
    f[16 + 6] = 0xff; // length 2047
    let mut out = vec![0; f.len()];
    second_copy(&f, &mut out);
    assert_eq!(out[16], 14, "not walked");
    let mut m = vec![0; f.len()];
    merge(&f, &f, &f, &mut m);
    assert_eq!(m, f);
    for n in 0..f.len() {
        let mut o = vec![0; n];
        second_copy(&f[..n], &mut o);
    }
}

/// Two ports that give back what the test queued, at once, then nothing until the deadline.
struct TwoPorts {
    back: Vec<(Vec<u8>, u8)>,
}

impl Transport for TwoPorts {
    type Error = std::io::Error;
    fn now(&mut self) -> MasterInstant {
        MasterInstant::from_ns(0)
    }
    fn sleep_until(&mut self, _: MasterInstant) {}
    fn send_with<F: FnOnce(&mut [u8])>(
        &mut self,
        len: usize,
        at: MasterInstant,
        fill: F,
    ) -> Result<MasterInstant, std::io::Error> {
        let mut b = vec![0; len];
        fill(&mut b);
        Ok(at)
    }
    fn recv(
        &mut self,
        buf: &mut Vec<u8>,
        _: MasterInstant,
    ) -> Result<Option<Received>, std::io::Error> {
        let Some((f, port)) = self.back.pop() else {
            return Ok(None);
        };
        buf.clear();
        buf.extend_from_slice(&f);
        Ok(Some(Received {
            len: f.len(),
            received: MasterInstant::from_ns(0),
            tx_stamp: None,
            stamped: false,
            truncated: false,
            port,
        }))
    }
}

impl SecondPort for TwoPorts {
    fn send_secondary(&mut self, _: &[u8], _: MasterInstant) -> Result<(), std::io::Error> {
        Ok(())
    }
}

/// At the deadline: the second port's copy alone, back on the first port (it went round the
/// whole ring's ports: the ring is whole, the first copy late) is no frame, and no break; the
/// second copy alone back on the second port (the ring broken, the near side's copy late) is
/// the far side's frame, and a break.
#[test]
fn a_second_copy_alone_is_a_frame_only_where_the_far_side_processed_it() {
    let sent = frame(&[(12, 7, 0, &[0xaa, 0, 0, 0], 0)], 1);
    let round = frame(&[(12, 7, 0, &[0xaa, 0, 0, 0], 0)], 0);
    let far = frame(&[(12, 7, 0, &[0xaa, 0, 0, 0x22], 3)], 0);
    let mut tr = TwoPorts { back: Vec::new() };
    let mut red = Redundant::new(&mut tr);
    let mut buf = Vec::new();
    let at = MasterInstant::from_ns(0);
    red.send(&sent, at).unwrap();
    red.inner().back.push((round, 0));
    assert!(red.recv(&mut buf, at).unwrap().is_none());
    assert_eq!((red.stats().partial, red.stats().breaks), (0, 0));
    let sent = frame(&[(12, 8, 0, &[0xaa, 0, 0, 0], 0)], 1);
    let far = {
        let mut f = far;
        f[FIRST_DATAGRAM + 1] = 8;
        f
    };
    red.send(&sent, at).unwrap();
    red.inner().back.push((far, 1));
    let r = red
        .recv(&mut buf, at)
        .unwrap()
        .expect("the far side's frame");
    assert_eq!(
        &buf[..r.len],
        &frame(&[(12, 8, 0, &[0xaa, 0, 0, 0x22], 3)], 1)[..]
    );
    assert_eq!((red.stats().partial, red.stats().breaks), (1, 1));
}
