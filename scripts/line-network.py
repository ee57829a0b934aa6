#!/usr/bin/env python3
"""Writes a network of N servo drives in a line (or a tree) as an `ecsync compare --config` file.

The host, run and method sections are presets/twelve-drives.toml's; the drives get cables of
0.3 to 3 m and crystals drawn uniformly within +-50 ppm (seeded, so the file is the same on
every machine). A large line needs a later SYNC0 than the letter's 30 %: its frames take
milliseconds on the wire (25 frames of 1 500 bytes for 1 000 drives), so the cycle and the
shift are options.

    python3 scripts/line-network.py 1000 --cycle-us 4000 --sync0-shift-pct 85 > line-1000.toml

With `--branches B` (B > 1) the drives hang in B lines off a backbone of ET1100 junctions
(`junction-mii`, couplers): each junction's port 3 and then port 2 carry a line of drives, port
1 the next junction, as a cabinet of EK1122-style junctions would (the frame visits port 3's
line before port 2's, the datasheet's processing order 0 -> 3 -> 1 -> 2). The drives are spread
over the branches as evenly as they go.

    python3 scripts/line-network.py 2000 --branches 20 --cycle-us 8000 > tree-2000.toml
"""
import argparse
import random
import re
import sys
from pathlib import Path


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("drives", type=int)
    ap.add_argument("--cycle-us", type=int, default=4000)
    ap.add_argument("--sync0-shift-pct", type=int, default=85)
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--branches", type=int, default=1,
                    help="lines of drives off a backbone of junctions (1: one line, no junction)")
    a = ap.parse_args()
    if a.drives < 1:
        sys.exit("line-network.py: drives: at least 1")
    if not 1 <= a.branches <= a.drives:
        sys.exit("line-network.py: --branches: between 1 and the number of drives")
    base = (Path(__file__).resolve().parent.parent / "presets" / "twelve-drives.toml").read_text()
    # Everything from the host section on is kept; the segment is written anew.
    rest = base[base.index("# ---------------------------------------------------------------------------------------------\n# The master host"):]
    # The warm-up must hold the methods' 10 000 initialisation frames: 120 s at up to 10 ms,
    # longer beyond (with a fifth to spare, as the preset's 120 s at 1 ms).
    warmup_s = max(120, -(-12_000 * a.cycle_us // 1_000_000))
    for key, value in [("cycle_us", a.cycle_us), ("sync0_shift_pct", a.sync0_shift_pct),
                       ("cycles", a.cycles), ("runs", a.runs), ("warmup_s", warmup_s)]:
        rest, n = re.subn(rf"(?m)^{key} = \S+", f"{key} = {value}", rest, count=1)
        if n != 1:
            sys.exit(f"line-network.py: presets/twelve-drives.toml has no [run] {key}")
    rng = random.Random(a.seed)
    shape = "a line" if a.branches == 1 else f"{a.branches} lines off {-(-a.branches // 2)} junctions"
    flags = "" if a.branches == 1 else f" --branches {a.branches}"
    out = [f"# {a.drives} servo drives in {shape}, written by scripts/line-network.py "
           f"{a.drives}{flags} --cycle-us {a.cycle_us} --sync0-shift-pct {a.sync0_shift_pct}.\n",
           "# Host, run and methods: presets/twelve-drives.toml's.\n\n[segment]\nseed = 2024\n"]

    def slave(name, model, up, port, power_up_ns, device=True):
        port_line = "" if port is None else f"upstream_port = {port}\n"
        device_line = 'device = "servo-drive"\n' if device else ""
        out.append(f"""
[[segment.slave]]
name = "{name}"
model = "{model}"
{device_line}upstream = "{up}"
{port_line}cable_m = {rng.uniform(0.3, 3.0):.1f}
ppm = {rng.uniform(-50.0, 50.0):.1f}
power_up_ns = {power_up_ns}
wander_ppm_per_sqrt_s = 0.005
""")

    def drive(k, up, port):
        slave(f"drive-{k}", "servo-mii", up, port, 1_000_000_000 + 123_456_789 * (k - 1) % 900_000_000)

    if a.branches == 1:
        for k in range(1, a.drives + 1):
            drive(k, "master" if k == 1 else f"drive-{k - 1}", None if k == 1 else 1)
    else:
        k = 0
        for b in range(a.branches):
            j = b // 2 + 1
            if b % 2 == 0:
                up, port = ("master", None) if j == 1 else (f"junction-{j - 1}", 1)
                slave(f"junction-{j}", "junction-mii", up, port,
                      1_000_000_000 + 987_654_321 * j % 900_000_000, device=False)
            n = a.drives // a.branches + (1 if b < a.drives % a.branches else 0)
            for i in range(n):
                k += 1
                if i == 0:
                    drive(k, f"junction-{j}", 3 if b % 2 == 0 else 2)
                else:
                    drive(k, f"drive-{k - 1}", 1)
    sys.stdout.write("".join(out) + "\n" + rest)


if __name__ == "__main__":
    main()
