"""SOEM (through pysoem) against `ecsync serve`: the scan, CoE reads, SDO Information, the
mapping and OP, as `slaveinfo -sdo` and SOEM's simple_test do them. Prints one JSON object.

Every other drive (the 2nd, 4th, 6th) is mapped anew in PRE-OP by a config function (SOEM's
PO2SOconfig hook, which `config_map` calls before it reads the mapping): 0x1600 and 0x1A00
cut to controlword/statusword, mode, padding and target/actual position, 8 bytes each way
instead of 16 and 18. SOEM reads the PDO assignment and mapping over CoE; from the SII it would
get the default 16 + 18 bytes for every drive, so the io_map's size tells which it used."""
import json
import struct
import sys
import time

import pysoem

iface = sys.argv[1]
m = pysoem.Master()
m.open(iface)
out = {"slaves": m.config_init(), "drives": []}
u = lambda b: int.from_bytes(b, "little")
for s in m.slaves:
    d = {"name": s.name, "man": s.man, "id": s.id, "rev": s.rev}
    d["vendor_sdo"] = u(s.sdo_read(0x1018, 1))
    d["product_sdo"] = u(s.sdo_read(0x1018, 2))
    d["rx_assign"] = u(s.sdo_read(0x1C12, 1))
    d["tx_assign"] = u(s.sdo_read(0x1C13, 1))
    d["rx_map_count"] = u(s.sdo_read(0x1600, 0))
    od = s.od
    d["od"] = [o.index for o in od]
    named = {o.index: o for o in od}
    ident = named.get(0x1018)
    d["identity_name"] = ident.name.decode() if ident is not None else None
    d["identity_entries"] = [e.name.decode() for e in ident.entries] if ident is not None else []
    out["drives"].append(d)
# (index << 16) | (subindex << 8) | bits, as a mapping entry holds it.
SHORT_RX = [0x60400010, 0x60600008, 0x00000008, 0x607A0020]
SHORT_TX = [0x60410010, 0x60610008, 0x00000008, 0x60640020]


def remap(s):
    """PRE-OP: a mapping is written with its subindex 0 at 0 first, then its count."""
    for index, entries in ((0x1600, SHORT_RX), (0x1A00, SHORT_TX)):
        s.sdo_write(index, 0, bytes([0]))
        for k, e in enumerate(entries):
            s.sdo_write(index, k + 1, struct.pack("<I", e))
        s.sdo_write(index, 0, bytes([len(entries)]))


short = [k % 2 == 1 for k in range(len(m.slaves))]
for k, s in enumerate(m.slaves):
    if short[k]:
        # pysoem's setup_func: SOEM's PO2SOconfigx, called with the slave.
        s.setup_func = remap
out["short"] = short
out["io_map"] = m.config_map()
out["mapped"] = [[len(bytes(s.output)), len(bytes(s.input))] for s in m.slaves]
out["expected_wkc"] = m.expected_wkc
for s in m.slaves:
    s.state_check(pysoem.SAFEOP_STATE, 50_000)
m.state = pysoem.OP_STATE
m.send_processdata()
m.receive_processdata(2_000)
m.write_state()
wkc = 0
t0 = time.monotonic()
while time.monotonic() - t0 < 5.0:
    m.send_processdata()
    wkc = m.receive_processdata(2_000)
    if m.state_check(pysoem.OP_STATE, 5_000) == pysoem.OP_STATE and wkc == m.expected_wkc:
        break
    time.sleep(0.001)
m.read_state()
out["op"] = all(s.state == pysoem.OP_STATE for s in m.slaves)
out["wkc"] = wkc
# The CiA 402 drives: shutdown, switch on, enable operation (controlword 0x6040), cyclic
# synchronous position (0x6060 = 8) to a target position of 1000 x (k + 1) counts (0x607A),
# as the default mapping lays them out (controlword, mode, padding, target position, ...).
for c in range(30):
    cw = 0x0006 if c < 5 else 0x0007 if c < 10 else 0x000F
    for k, s in enumerate(m.slaves):
        if short[k]:
            s.output = struct.pack("<HBxi", cw, 8, 1000 * (k + 1))
        else:
            s.output = struct.pack("<HBxiihh", cw, 8, 1000 * (k + 1), 0, 0, 0)
    m.send_processdata()
    wkc = m.receive_processdata(2_000)
    time.sleep(0.001)
# Statusword, modes display, position actual (0x6041, 0x6061, 0x6064).
out["drive_inputs"] = [list(struct.unpack_from("<HBxi", bytes(s.input))) for s in m.slaves]
out["sm_event_missed"] = [u(s.sdo_read(0x1C32, 0x0B)) for s in m.slaves]
m.state = pysoem.INIT_STATE
m.write_state()
m.close()
print(json.dumps(out))
