#!/usr/bin/env bash
# Measures ecsync run on this machine's kernel against ecsync serve, over a veth pair between two
# network namespaces: every method at 1 ms and at 250 us. Prints a Markdown table (the README's
# "what a non-RT kernel gives") and leaves the JSON summaries in $OUT.
# Needs root (namespaces, raw sockets). Usage: scripts/realnet-measure.sh [seconds per run]
set -euo pipefail
cd "$(dirname "$0")/.."
SECS=${1:-20}
OUT=${OUT:-out/realnet}
mkdir -p "$OUT"
cargo build --release -q -p ecsync
B=$PWD/target/release/ecsync
A=ecsm-a; Bn=ecsm-b
cleanup() { pkill -f "ecsync serve --iface ecsmA" 2>/dev/null || true; ip netns del $A 2>/dev/null || true; ip netns del $Bn 2>/dev/null || true; }
trap cleanup EXIT
cleanup
ip netns add $A; ip netns add $Bn
ip link add ecsmA type veth peer name ecsmB
ip link set ecsmA netns $A; ip link set ecsmB netns $Bn
ip -n $A link set ecsmA up; ip -n $Bn link set ecsmB up
ip netns exec $A "$B" serve --iface ecsmA --quiet 2>"$OUT/serve.log" &
sleep 1
echo "kernel $(uname -r), $(nproc) CPUs, PREEMPT_RT: $(cat /sys/kernel/realtime 2>/dev/null || echo 0); $SECS s per run"
echo
echo "| cycle | method | wake-up p50 / p99 / p99.9 / max (us) | M-rS mean / std / max / min (us) | rS-IS max (ns) | skipped | lost | late |"
echo "|---|---|---|---|---|---|---|---|"
for cyc in 1000 250; do
  for m in median pi-m2s bus-shift snap soem-pi; do
    f="$OUT/run-$cyc-$m.json"
    ip netns exec $Bn "$B" run --iface ecsmB --method "$m" --cycle-us $cyc --duration "$SECS" --json > "$f" 2>/dev/null || true
    python3 - "$f" "$cyc" "$m" <<'PY'
import json, sys
f, cyc, m = sys.argv[1:]
try:
    d = json.load(open(f))
except Exception as e:
    print(f"| {cyc} us | {m} | run failed ({e}) | | | | | |"); sys.exit()
w, r, s = d["wake_latency"], d["m_rs"], d["rs_is"]
us = lambda x: x / 1e3
print(f"| {cyc} us | {m} | {w['p50_us']:.1f} / {w['p99_us']:.1f} / {w['p999_us']:.1f} / {w['max_us']:.0f} "
      f"| {us(r['mean']):.2f} / {us(r['std']):.2f} / {us(r['max']):.1f} / {us(r['min']):.1f} "
      f"| {s['max']:.0f} | {d['skipped_cycles']} | {d['lost_frames']} | {d['late_replies']} |")
PY
  done
done
