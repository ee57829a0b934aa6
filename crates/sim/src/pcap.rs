//! Capture of the frames a segment sees, as a classic pcap file with the Ethernet link type
//! (Wireshark's EtherCAT dissector decodes EtherType 0x88A4).

use pcap_file::DataLink;
use pcap_file::pcap::{PcapHeader, PcapPacket, PcapWriter};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::time::Duration;

/// A capture that could not be written, in the OS's words for an I/O error (pcap-file's own
/// text for one is "Error reading bytes", a failed create or write included).
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// The file could not be created or written.
    #[error("{0}")]
    Io(std::io::Error),
    /// pcap-file refused the data.
    #[error("{0}")]
    Pcap(pcap_file::PcapError),
}

impl From<pcap_file::PcapError> for CaptureError {
    fn from(e: pcap_file::PcapError) -> Self {
        match e {
            pcap_file::PcapError::IoError(io) => CaptureError::Io(io),
            e => CaptureError::Pcap(e),
        }
    }
}

/// A pcap writer with nanosecond timestamps.
pub struct PcapCapture<W: Write> {
    writer: PcapWriter<W>,
    frames: u64,
}

impl<W: Write> std::fmt::Debug for PcapCapture<W> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PcapCapture")
            .field("frames", &self.frames)
            .finish()
    }
}

impl PcapCapture<BufWriter<File>> {
    /// Creates (truncates) a capture file.
    pub fn create(path: &Path) -> Result<Self, CaptureError> {
        let file = File::create(path).map_err(CaptureError::Io)?;
        Self::new(BufWriter::new(file))
    }
}

impl<W: Write> PcapCapture<W> {
    /// Starts a capture on any writer.
    pub fn new(w: W) -> Result<Self, CaptureError> {
        let header = PcapHeader {
            datalink: DataLink::ETHERNET,
            ts_resolution: pcap_file::TsResolution::NanoSecond,
            snaplen: 65535,
            ..Default::default()
        };
        Ok(PcapCapture {
            writer: PcapWriter::with_header(w, header)?,
            frames: 0,
        })
    }

    /// Records a frame seen at `t_ps` (picoseconds; pcap keeps nanoseconds).
    pub fn record(&mut self, t_ps: u64, frame: &[u8]) -> Result<(), CaptureError> {
        let ts = Duration::from_nanos(t_ps / 1000);
        let pkt = PcapPacket::new(ts, frame.len() as u32, frame);
        self.writer.write_packet(&pkt)?;
        self.frames += 1;
        Ok(())
    }

    /// Frames recorded.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    /// Flushes and returns the writer.
    pub fn finish(self) -> Result<W, std::io::Error> {
        let mut w = self.writer.into_writer();
        w.flush()?;
        Ok(w)
    }
}
