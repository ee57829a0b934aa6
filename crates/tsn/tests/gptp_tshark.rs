//! Wireshark's PTP dissector reads our gPTP messages as 802.1AS (PTPv2, majorSdoId 1) with the
//! fields we sent, and finds nothing malformed.

use ecsync_tsn::gptp_msg::{
    Announce, ClockQuality, FollowUpInfo, Header, Message, PortIdentity, Timestamp, ethernet_frame,
    flags,
};
use pcap_file::DataLink;
use pcap_file::pcap::{PcapHeader, PcapPacket, PcapWriter};
use std::process::Command;
use std::time::Duration;

const CLOCK: [u8; 8] = [0x00, 0x1b, 0x21, 0xff, 0xfe, 0x12, 0x34, 0x56];
const PEER: [u8; 8] = [0x00, 0x1b, 0x21, 0xff, 0xfe, 0xab, 0xcd, 0xef];

/// tshark's reading of the capture at `path` with `args`. The test is `#[ignore = "needs
/// tshark"]`: asked for without tshark, it fails saying so.
fn tshark(path: &std::path::Path, args: &[&str]) -> String {
    let out = Command::new("tshark")
        .arg("-r")
        .arg(path)
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("this test needs tshark (apt-get install tshark): {e}"));
    assert!(
        out.status.success(),
        "tshark: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

#[test]
#[ignore = "needs tshark"]
fn tshark_decodes_every_message_with_our_fields() {
    let src = PortIdentity {
        clock_identity: CLOCK,
        port_number: 1,
    };
    let h = |seq: u16, flags: u16, log: i8, corr_ns: i64| Header {
        domain: 0,
        flags,
        correction_scaled_ns: corr_ns << 16,
        source: src,
        sequence_id: seq,
        log_message_interval: log,
    };
    let requesting = PortIdentity {
        clock_identity: PEER,
        port_number: 1,
    };
    let mut announce = Announce {
        current_utc_offset: 37,
        priority1: 246,
        clock_quality: ClockQuality {
            clock_class: 248,
            clock_accuracy: 0xfe,
            offset_scaled_log_variance: 0x4e5d,
        },
        priority2: 248,
        grandmaster_identity: CLOCK,
        steps_removed: 0,
        time_source: 0xa0,
        ..Announce::default()
    };
    announce.path[0] = CLOCK;
    announce.path_len = 1;
    let msgs = [
        (
            h(100, flags::PTP_TIMESCALE, 0, 0),
            Message::Announce(announce),
        ),
        (
            h(200, flags::TWO_STEP | flags::PTP_TIMESCALE, -3, 0),
            Message::Sync,
        ),
        (
            h(200, flags::PTP_TIMESCALE, -3, 1234),
            Message::FollowUp {
                precise_origin: Timestamp {
                    seconds: 1_700_000_000,
                    nanoseconds: 123_456_789,
                },
                info: FollowUpInfo {
                    cumulative_scaled_rate_offset: 21_990,
                    gm_time_base_indicator: 0,
                    last_gm_phase_change_scaled_ns: 0,
                    scaled_last_gm_freq_change: 0,
                },
            },
        ),
        (h(300, 0, 0, 0), Message::PdelayReq),
        (
            h(300, flags::TWO_STEP, 0x7f, 0),
            Message::PdelayResp {
                request_receipt: Timestamp {
                    seconds: 5,
                    nanoseconds: 123,
                },
                requesting,
            },
        ),
        (
            h(300, 0, 0x7f, 0),
            Message::PdelayRespFollowUp {
                response_origin: Timestamp {
                    seconds: 5,
                    nanoseconds: 10_000,
                },
                requesting,
            },
        ),
    ];
    let dir = std::env::temp_dir().join(format!("ecsync-gptp-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("gptp.pcap");
    {
        let file = std::fs::File::create(&path).unwrap();
        let header = PcapHeader {
            datalink: DataLink::ETHERNET,
            ..PcapHeader::default()
        };
        let mut w = PcapWriter::with_header(file, header).unwrap();
        let mut buf = [0u8; 128];
        let mut frame = Vec::new();
        for (i, (h, m)) in msgs.iter().enumerate() {
            let n = m.encode(h, &mut buf).unwrap();
            ethernet_frame([0x00, 0x1b, 0x21, 0x12, 0x34, 0x56], &buf[..n], &mut frame);
            let ts = Duration::from_millis(10 * i as u64);
            w.write_packet(&PcapPacket::new(ts, frame.len() as u32, &frame))
                .unwrap();
        }
    }
    let malformed = tshark(
        &path,
        &["-Y", "_ws.malformed || _ws.expert.severity >= 0x00800000"],
    );
    assert_eq!(malformed.trim(), "", "tshark flags: {malformed}");
    let fields = tshark(
        &path,
        &[
            "-T",
            "fields",
            "-E",
            "separator=;",
            "-e",
            "ptp.v2.majorsdoid",
            "-e",
            "ptp.v2.messagetype",
            "-e",
            "ptp.v2.sequenceid",
            "-e",
            "ptp.v2.clockidentity",
            "-e",
            "ptp.v2.correction.ns",
            "-e",
            "ptp.v2.an.priority1",
            "-e",
            "ptp.v2.an.grandmasterclockclass",
            "-e",
            "ptp.v2.fu.preciseorigintimestamp.seconds",
            "-e",
            "ptp.v2.fu.preciseorigintimestamp.nanoseconds",
            "-e",
            "ptp.as.fu.cumulativeScaledRateOffset",
            "-e",
            "ptp.v2.pdrs.requestreceipttimestamp.nanoseconds",
            "-e",
            "ptp.v2.pdfu.responseorigintimestamp.nanoseconds",
            "-e",
            "ptp.v2.flags.twostep",
        ],
    );
    let rows: Vec<Vec<&str>> = fields.lines().map(|l| l.split(';').collect()).collect();
    println!("{fields}");
    assert_eq!(rows.len(), 6);
    // majorSdoId 1 (802.1AS) and the message types, in order.
    let types: Vec<&str> = rows.iter().map(|r| r[1]).collect();
    assert_eq!(types, ["0x0b", "0x00", "0x08", "0x02", "0x03", "0x0a"]);
    assert!(rows.iter().all(|r| r[0] == "0x01"), "{rows:?}");
    let seqs: Vec<&str> = rows.iter().map(|r| r[2]).collect();
    assert_eq!(seqs, ["100", "200", "200", "300", "300", "300"]);
    assert!(
        rows.iter().all(|r| r[3] == "0x001b21fffe123456"),
        "{rows:?}"
    );
    assert_eq!(rows[2][4], "1234", "Follow_Up correctionField, ns");
    assert_eq!(
        (rows[0][5], rows[0][6]),
        ("246", "248"),
        "Announce priority1, clockClass"
    );
    assert_eq!((rows[2][7], rows[2][8]), ("1700000000", "123456789"));
    assert_eq!(rows[2][9], "21990", "cumulativeScaledRateOffset");
    assert_eq!(rows[4][10], "123", "Pdelay_Resp requestReceiptTimestamp ns");
    assert_eq!(
        rows[5][11], "10000",
        "Pdelay_Resp_Follow_Up responseOriginTimestamp ns"
    );
    assert_eq!(rows[1][12], "1", "Sync twoStepFlag");
}
