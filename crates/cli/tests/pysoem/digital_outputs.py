"""SOEM (through pysoem) against a network of digital output terminals, as a master developer's
test would run it against `ecsync serve --sandbox -- python3 digital_outputs.py`: the scan, the
process data mapped from the terminals' SII (their outputs through SyncManagers at the digital
output register 0x0F00), DC configured, SAFE-OP and OP, then a number of cycles writing a count
to the outputs, the working counter of every cycle's LRW kept.

The interface: the first argument, else $ECSYNC_IFACE. Exit 0 when every slave reached OP; 1
with the reason on stderr otherwise. One line of JSON on stdout: the slaves (name, vendor,
product, output bytes), SOEM's expected working counter, and the working counter of every
cycle in OP.
"""
import argparse
import json
import os
import sys
import time

import pysoem


def fail(msg):
    print(f"digital_outputs: FAILED: {msg}", file=sys.stderr)
    sys.exit(1)


def parse():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("iface", nargs="?", default=os.environ.get("ECSYNC_IFACE"))
    p.add_argument("--cycles", type=int, default=64, help="cycles in OP")
    p.add_argument("--cycle-us", type=int, default=2000)
    p.add_argument("--recv-timeout-us", type=int, default=3000)
    a = p.parse_args()
    if not a.iface:
        p.error("no interface: give it as the first argument or in ECSYNC_IFACE")
    return a


def states(m):
    m.read_state()
    return ", ".join(f"{i}: {s.state:#x} (AL status {s.al_status:#06x})"
                     for i, s in enumerate(m.slaves))


def main():
    a = parse()
    m = pysoem.Master()
    m.open(a.iface)
    n = m.config_init()
    if n <= 0:
        fail(f"config_init found no slave on {a.iface}")
    m.config_map()
    m.config_dc()
    if m.state_check(pysoem.SAFEOP_STATE, 50_000) != pysoem.SAFEOP_STATE:
        fail("not every slave in SAFE-OP: " + states(m))
    cycle = a.cycle_us / 1e6
    # A few cycles of process data before OP is asked for, as SOEM's examples run.
    for _ in range(10):
        m.send_processdata()
        m.receive_processdata(a.recv_timeout_us)
        time.sleep(cycle)
    m.state = pysoem.OP_STATE
    m.write_state()
    for _ in range(1000):
        m.send_processdata()
        m.receive_processdata(a.recv_timeout_us)
        if m.state_check(pysoem.OP_STATE, 0) == pysoem.OP_STATE:
            break
        time.sleep(cycle)
    else:
        fail("not every slave in OP: " + states(m))
    wkcs = []
    for k in range(a.cycles):
        for i, s in enumerate(m.slaves):
            s.output = bytes(((k + i) & 0xFF,) * len(s.output))
        m.send_processdata()
        wkcs.append(m.receive_processdata(a.recv_timeout_us))
        time.sleep(cycle)
    slaves = [{"name": s.name, "vendor": s.man, "product": s.id, "outputs": len(s.output)}
              for s in m.slaves]
    expected = m.expected_wkc
    m.state = pysoem.INIT_STATE
    m.write_state()
    m.close()
    print(json.dumps({"slaves": slaves, "expected_wkc": expected, "wkc": wkcs}))


if __name__ == "__main__":
    try:
        main()
    except Exception as e:  # pysoem's errors and the OS's
        fail(f"{type(e).__name__}: {e}")
