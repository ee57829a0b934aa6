#!/usr/bin/env bash
# Stand-in for `ecsync sweep` while the real subcommand is written: same arguments, no simulation.
# `sweep ... --grid K=a,b,c ... --shard I/N --db F` writes to F (plain text, not SQLite) the indices
# of the grid's points that shard I owns (index % N == I, 0-based); `sweep merge --db OUT IN...`
# concatenates them. test-recipes.sh checks that the shards together own every point exactly once.
set -euo pipefail
[ "${1:-}" = sweep ] || { echo "fake-ecsync: only 'sweep' is faked" >&2; exit 2; }
shift
if [ "${1:-}" = merge ]; then
    shift
    [ "${1:-}" = --db ] || { echo "fake-ecsync: sweep merge --db OUT IN..." >&2; exit 2; }
    out=$2; shift 2
    cat "$@" > "$out"
    exit 0
fi
points=1 shard='' db=''
while [ $# -gt 0 ]; do
    case $1 in
        --grid) vals=${2#*=}; IFS=, read -ra v <<<"$vals"; points=$((points * ${#v[@]})); shift 2 ;;
        --shard) shard=$2; shift 2 ;;
        --db) db=$2; shift 2 ;;
        --preset) shift 2 ;;
        --quiet) shift ;;
        *) echo "fake-ecsync: unknown argument $1" >&2; exit 2 ;;
    esac
done
i=${shard%/*} n=${shard#*/}
if [ -z "$db" ] || [ -z "$shard" ] || [ "$i" -lt 0 ] || [ "$i" -ge "$n" ]; then
    echo "fake-ecsync: need --shard I/N with 0 <= I < N and --db F (got '$shard', '$db')" >&2
    exit 2
fi
# Fail on demand so the recipes' failure paths can be tested.
[ "${FAKE_ECSYNC_FAIL_SHARD:-}" != "$i" ] || { echo "fake-ecsync: shard $i fails on purpose" >&2; exit 3; }
: > "$db"
for ((p = i; p < points; p += n)); do echo "$p" >> "$db"; done
