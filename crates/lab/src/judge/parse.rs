//! What the judge reads of a frame, without allocating: its process data datagrams and their
//! working counter, the first datagram's index and the shape of its headers (retries), and the
//! AL status the master read in it.

use ecsync_wire::register as reg;
use ecsync_wire::{Command, EcatFrame};

/// A frame as the judge sees it.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct FrameInfo {
    /// It holds an LRW, LRD or LWR datagram.
    pub(crate) process_data: bool,
    /// It holds an LRW or LWR (it carries outputs).
    pub(crate) outputs: bool,
    /// The sum of its process data datagrams' working counters.
    pub(crate) pd_wkc: u32,
    /// The first datagram's index.
    pub(crate) index: u8,
    /// Datagrams read.
    pub(crate) datagrams: u16,
    /// The datagrams' headers (command, index, address, length) hashed: a retry repeats them.
    pub(crate) shape: u64,
}

/// An AL status the master read: the slave (by configured address or auto-increment
/// position, as the datagram named it), the status byte and the code if the read covered it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct AlRead {
    pub(crate) station: Option<u16>,
    /// The position field as the frame came back (the slaves it passed have incremented it).
    pub(crate) returned_adp: Option<u16>,
    pub(crate) status: u8,
    pub(crate) code: Option<u16>,
}

/// The most AL status reads taken from one frame.
pub(crate) const MAX_AL_READS: usize = 16;

/// Reads `frame` (the segment's answer); AL status reads go to `al` (their count returned in
/// the second field). A frame that is not EtherCAT reads as no datagrams.
pub(crate) fn parse(frame: &[u8], al: &mut [Option<AlRead>; MAX_AL_READS]) -> (FrameInfo, usize) {
    let mut info = FrameInfo::default();
    let mut n_al = 0;
    let Ok(f) = EcatFrame::new_checked(frame) else {
        return (info, 0);
    };
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut first = true;
    for d in f.datagrams() {
        let Ok(d) = d else { break };
        let code = d.command_code();
        if first {
            info.index = d.index();
            first = false;
        }
        info.datagrams += 1;
        // The position field comes back incremented by every slave passed: a retry of a frame
        // lost on its way out (the request) is recognised by the rest.
        let positional = matches!(
            d.command(),
            Ok(Command::Aprd | Command::Apwr | Command::Aprw | Command::Armw)
        );
        let adp = if positional { 0 } else { d.adp() };
        for b in [code, d.index()]
            .into_iter()
            .chain(adp.to_le_bytes())
            .chain(d.ado().to_le_bytes())
            .chain((d.data_len() as u16).to_le_bytes())
        {
            h = (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3);
        }
        let Ok(cmd) = d.command() else { continue };
        match cmd {
            Command::Lrw | Command::Lwr | Command::Lrd => {
                info.process_data = true;
                info.outputs |= cmd != Command::Lrd;
                info.pd_wkc += u32::from(d.wkc());
            }
            Command::Aprd | Command::Fprd | Command::Aprw | Command::Fprw if d.wkc() > 0 => {
                let (ado, data) = (d.ado(), d.data());
                let end = u32::from(ado) + data.len() as u32;
                let covers = |a: u16| u32::from(a) >= u32::from(ado) && u32::from(a) < end;
                if !covers(reg::AL_STATUS) || n_al == MAX_AL_READS {
                    continue;
                }
                let at = |a: u16| usize::from(a - ado);
                let code =
                    (covers(reg::AL_STATUS_CODE) && covers(reg::AL_STATUS_CODE + 1)).then(|| {
                        let i = at(reg::AL_STATUS_CODE);
                        u16::from_le_bytes([data[i], data[i + 1]])
                    });
                let positional = matches!(cmd, Command::Aprd | Command::Aprw);
                al[n_al] = Some(AlRead {
                    station: (!positional).then(|| d.adp()),
                    returned_adp: positional.then(|| d.adp()),
                    status: data[at(reg::AL_STATUS)],
                    code,
                });
                n_al += 1;
            }
            _ => {}
        }
    }
    info.shape = h;
    (info, n_al)
}
