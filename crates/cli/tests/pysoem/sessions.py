"""Back-to-back SOEM sessions (through pysoem) against one running segment, as a CI job's
tests would open them one after another: each opens the interface, scans (config_init), reads
0x1018:01 (vendor id) by SDO from every slave and closes. Issue 31's acceptance point 2.

Usage: sessions.py N [IFACE] (IFACE: else $ECSYNC_IFACE). Exit 0 when every session found the
slaves and read every identity within --sdo-limit-ms (SOEM's own SDO timeout is 700 ms: a
dropped request shows as a read that took it, or an error); 1 naming the failures otherwise.
One summary line on stdout.
"""
import argparse
import os
import sys
import time

import pysoem


def session(iface, want_slaves):
    """One session; returns (slowest SDO read in s, error or None)."""
    m = pysoem.Master()
    m.open(iface)
    slowest = 0.0
    try:
        n = m.config_init()
        if n != want_slaves and want_slaves:
            return slowest, f"config_init found {n} slaves, expected {want_slaves}"
        for i, s in enumerate(m.slaves):
            t0 = time.monotonic()
            try:
                vendor = int.from_bytes(s.sdo_read(0x1018, 1), "little")
            except Exception as e:  # pysoem's WkcError, SdoError, MailboxError
                return max(slowest, time.monotonic() - t0), f"slave {i}: {type(e).__name__}: {e}"
            slowest = max(slowest, time.monotonic() - t0)
            if vendor != s.man:
                return slowest, f"slave {i}: 0x1018:01 reads {vendor:#x}, its SII {s.man:#x}"
        return slowest, None
    finally:
        m.close()


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("sessions", type=int)
    p.add_argument("iface", nargs="?", default=os.environ.get("ECSYNC_IFACE"))
    p.add_argument("--slaves", type=int, default=6, help="slaves expected (0: any)")
    p.add_argument("--sdo-limit-ms", type=float, default=300.0)
    a = p.parse_args()
    if not a.iface:
        p.error("no interface: give it after N or in ECSYNC_IFACE")
    failures, slowest, t0 = [], 0.0, time.monotonic()
    for k in range(a.sessions):
        try:
            sdo_s, err = session(a.iface, a.slaves)
        except Exception as e:
            sdo_s, err = 0.0, f"{type(e).__name__}: {e}"
        slowest = max(slowest, sdo_s)
        if err is None and sdo_s * 1000 > a.sdo_limit_ms:
            err = f"an SDO read took {sdo_s * 1000:.0f} ms"
        if err:
            failures.append(f"session {k + 1}: {err}")
    print(f"sessions: {a.sessions - len(failures)} of {a.sessions} ok in "
          f"{time.monotonic() - t0:.1f} s, slowest SDO read {slowest * 1000:.1f} ms")
    if failures:
        print("sessions: FAILED: " + "; ".join(failures), file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
