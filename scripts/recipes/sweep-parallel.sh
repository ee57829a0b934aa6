#!/usr/bin/env bash
# `ecsync sweep` split into N shards run by GNU parallel (on this machine, or on others with
# parallel's own --sshlogin), then merged into one SQLite file:
#   scripts/recipes/sweep-parallel.sh N OUTDIR --preset paper-2024 --grid 'run.sync0_shift_pct=10,20,30'
#   (or the sweep arguments in ECSYNC_SWEEP_ARGS, shell-quoted; the binary in ECSYNC_BIN, else
#   ecsync on PATH; ECSYNC_JOBS shards at once, default N)
# Leaves OUTDIR/shard-I.db, OUTDIR/joblog and OUTDIR/merged.db; the same command again goes on
# with the shards' points not done. Installs parallel if missing.
set -euo pipefail
[ $# -ge 2 ] || { sed -n '2,/^set /{/^#/p}' "$0"; exit 2; }
n=$1 out=$2
shift 2
[ $# -gt 0 ] || eval "set -- ${ECSYNC_SWEEP_ARGS:?"give the sweep arguments as arguments or in ECSYNC_SWEEP_ARGS"}"
bin=${ECSYNC_BIN:-ecsync}
if ! command -v parallel >/dev/null; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q
    apt-get install -y -q --no-install-recommends parallel
fi
mkdir -p "$out"
# The shards are kept: run again after an interruption or a failed shard, each goes on where
# it stopped (its points done are not run again), and a shard database of another sweep is
# refused, naming what differs. Only the merge is made anew from them. (With another N, the
# shards 0..N-1 still hold points of this sweep only, each kept whole, and the merge takes them.)
rm -f "$out"/merged.db
# Shards are 0-based and parallel's job number {#} 1-based, so the shard is the input {} from
# seq 0..N-1. -q quotes every word as given (a grid value may hold shell characters); a failed
# shard stops the others (--halt now,fail=1) and fails the script before the merge.
# --tag prefixes each shard's output lines with its number, --joblog keeps each one's exit status.
parallel -q --halt now,fail=1 --jobs "${ECSYNC_JOBS:-$n}" --will-cite --tag --joblog "$out/joblog" \
    "$bin" sweep "$@" --shard "{}/$n" --db "$out/shard-{}.db" ::: $(seq 0 $((n - 1)))
shards=()
for ((i = 0; i < n; i++)); do shards+=("$out/shard-$i.db"); done
"$bin" sweep merge --db "$out/merged.db" "${shards[@]}"
echo "sweep-parallel: $n shards merged into $out/merged.db"
