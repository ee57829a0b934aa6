//! Whether this host can send at a launch time (SO_TXTIME): the kernel needs the ETF qdisc
//! (CONFIG_NET_SCH_ETF) on the interface, whose queue holds each frame until its launch time
//! less a delta and drops the ones handed over too late (reported on the socket's error
//! queue), or hands them to a NIC with launch-time offload (Intel i210/i225, stmmac). Without
//! it SO_TXTIME is accepted and ignored: frames leave at once, so a master must refuse rather
//! than pretend.

use std::io::Read as _;
use std::process::Command;

/// Why `--send txtime` cannot run on `iface`, naming what is missing (`Ok` when the kernel has
/// the ETF qdisc and the interface runs it).
pub fn txtime_support(iface: &str) -> Result<(), String> {
    if kernel_has_etf() == Some(false) {
        return Err(format!(
            "--send txtime needs the ETF qdisc (the kernel's launch-time queue) on {iface}, and this kernel has none: CONFIG_NET_SCH_ETF is not set (/proc/config.gz); fix: a kernel built with CONFIG_NET_SCH_ETF (and a NIC with launch-time offload for hardware precision), or --send spin"
        ));
    }
    let out = Command::new("tc")
        .args(["qdisc", "show", "dev", iface])
        .output()
        .map_err(|e| {
            format!(
                "--send txtime: cannot read {iface}'s qdiscs with tc ({e}); fix: install iproute2"
            )
        })?;
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!(
            "--send txtime: tc qdisc show dev {iface}: {}",
            String::from_utf8_lossy(&out.stderr).trim()
        ));
    }
    if !text
        .lines()
        .any(|l| l.split_whitespace().nth(1) == Some("etf"))
    {
        return Err(format!(
            "--send txtime needs the ETF qdisc on {iface}, which runs none (tc qdisc show dev {iface}: {}); fix: tc qdisc replace dev {iface} parent root handle 100 mqprio num_tc 1 map 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 0 queues 1@0 hw 0 && tc qdisc add dev {iface} parent 100:1 etf clockid CLOCK_TAI delta 200000 offload",
            text.trim().replace('\n', "; ")
        ));
    }
    Err(format!(
        "--send txtime: {iface} runs the ETF qdisc, but ecsync's SO_TXTIME send path is not built yet (it could not be tested on a kernel without ETF); use --send spin"
    ))
}

/// Whether the running kernel was built with the ETF qdisc, from /proc/config.gz (`None`:
/// the kernel does not say).
fn kernel_has_etf() -> Option<bool> {
    let f = std::fs::File::open("/proc/config.gz").ok()?;
    let mut text = String::new();
    flate2::read::GzDecoder::new(f)
        .read_to_string(&mut text)
        .ok()?;
    config_has(&text, "CONFIG_NET_SCH_ETF")
}

/// `Some(true)` for `KEY=y` or `=m`, `Some(false)` for `# KEY is not set` or no line.
fn config_has(config: &str, key: &str) -> Option<bool> {
    for l in config.lines() {
        if let Some(v) = l.strip_prefix(key).and_then(|r| r.strip_prefix('=')) {
            return Some(v == "y" || v == "m");
        }
    }
    Some(false)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_lines_are_read() {
        let c = "CONFIG_A=y\n# CONFIG_NET_SCH_ETF is not set\nCONFIG_NET_SCH_FQ=m\n";
        assert_eq!(config_has(c, "CONFIG_NET_SCH_ETF"), Some(false));
        assert_eq!(config_has(c, "CONFIG_NET_SCH_FQ"), Some(true));
        assert_eq!(
            config_has("CONFIG_NET_SCH_ETF=m\n", "CONFIG_NET_SCH_ETF"),
            Some(true)
        );
    }
}
