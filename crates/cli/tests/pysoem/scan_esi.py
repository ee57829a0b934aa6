"""SOEM (through pysoem) against `ecsync serve` of drives built from ESI files: the scan's
identity from the SII, the identity and the PDO assignment over CoE, the process image SOEM maps
from the CoE PDO mapping. Prints one JSON object."""
import json
import sys

import pysoem

m = pysoem.Master()
m.open(sys.argv[1])
out = {"slaves": m.config_init(), "drives": []}
u = lambda b: int.from_bytes(b, "little")
for s in m.slaves:
    out["drives"].append(
        {
            "name": s.name,
            "man": s.man,
            "id": s.id,
            "rev": s.rev,
            "vendor_sdo": u(s.sdo_read(0x1018, 1)),
            "product_sdo": u(s.sdo_read(0x1018, 2)),
            "rx_assign": u(s.sdo_read(0x1C12, 1)),
            "tx_assign": u(s.sdo_read(0x1C13, 1)),
            "rx_map": [u(s.sdo_read(0x1600, k)) for k in range(1, u(s.sdo_read(0x1600, 0)) + 1)],
        }
    )
out["io_map"] = m.config_map()
m.close()
print(json.dumps(out))
