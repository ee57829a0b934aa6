//! `ip` (iproute2) for the tests that make network namespaces and veth pairs: the realnet
//! test here, and the CLI's net tests, which include this file.

use std::process::Command;

/// Runs `ip args...`; when it fails, the error names the command and what `ip` said.
pub fn ip(args: &[&str]) -> Result<(), String> {
    let o = Command::new("ip")
        .args(args)
        .output()
        .map_err(|e| format!("ip: {e}"))?;
    if o.status.success() {
        Ok(())
    } else {
        Err(format!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&o.stderr).trim()
        ))
    }
}
