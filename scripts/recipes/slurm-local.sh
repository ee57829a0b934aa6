#!/usr/bin/env bash
# A throwaway single-node Slurm cluster, to run the sbatch recipes on one machine (CI included):
# installs Debian's munge/slurmctld/slurmd if missing, starts the three daemons by hand (no systemd
# in a container) with their config, state and logs in ECSYNC_SLURM_DIR, runs `sbatch --wait ARGS`
# in the current folder, and stops the daemons whatever happens.
#   scripts/recipes/slurm-local.sh [sbatch options] JOB_SCRIPT [script args]
#   e.g. scripts/recipes/slurm-local.sh --array=0-3 scripts/recipes/sweep-array.sbatch --preset paper-2024 ...
# Exits with sbatch's status (for an array, the highest of its tasks'). Env: ECSYNC_SLURM_DIR
# (default /tmp/ecsync-slurm-local, emptied each run: one cluster at a time; munged refuses a
# folder whose parents not everyone may enter), ECSYNC_SLURM_PORT (slurmctld's, slurmd's is the
# next; default 16817, away from a real Slurm's 6817).
set -euo pipefail
[ $# -gt 0 ] || { sed -n '2,/^set /{/^#/p}' "$0"; exit 2; }
[ "$(id -u)" = 0 ] || { echo "slurm-local: run as root (apt-get; slurmd runs jobs as their submitter)" >&2; exit 2; }
dir=${ECSYNC_SLURM_DIR:-/tmp/ecsync-slurm-local}
port=${ECSYNC_SLURM_PORT:-16817}

if ! command -v munged >/dev/null || ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null \
    || ! command -v sbatch >/dev/null; then
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -q
    # Their postinst scripts try to start the system's services; without systemd that is refused
    # harmlessly, and with it they use /etc's config and the default ports, not ours.
    apt-get install -y -q --no-install-recommends munge slurmctld slurmd slurm-client
fi

ours() { # every process this cluster ran (daemons, job steps, jobs): they inherit the marker
    grep -lsz "^ECSYNC_SLURM_LOCAL=$dir\$" /proc/[0-9]*/environ | cut -d/ -f3 | grep -vx "$$" || true
}
stop() {
    local left pids
    unset ECSYNC_SLURM_LOCAL # or the commands below would find themselves
    if [ -n "${up:-}" ]; then # our slurmctld: let it end the jobs' steps, which ignore SIGTERM
        scancel --quiet --user="$(id -un)" 2>/dev/null || true
        for _ in $(seq 40); do [ -z "$(squeue -h 2>/dev/null)" ] && break; sleep 0.25; done
    fi
    mapfile -t pids < <(ours)
    [ ${#pids[@]} -eq 0 ] || kill "${pids[@]}" 2>/dev/null || true
    for _ in $(seq 20); do # a zombie (nobody reaps a daemon in a container) has no environ: gone
        mapfile -t left < <(ours)
        [ ${#left[@]} -eq 0 ] && return 0
        sleep 0.25
    done
    kill -9 "${left[@]}" 2>/dev/null || true
}
finish() {
    local rc=$?
    stop
    if [ "$rc" = 0 ]; then rm -rf "$dir"; else
        for f in "$dir"/log/*.log; do [ -f "$f" ] && { echo "--- $f"; tail -n 15 "$f"; }; done >&2
        echo "slurm-local: exit $rc, logs kept in $dir/log" >&2
    fi
    exit "$rc"
}

stop # what a previous run left if it was killed before its trap could run
rm -rf "$dir"
mkdir -p "$dir/state" "$dir/spool" "$dir/log"
chmod 755 "$dir" # munge's socket must be reachable by the jobs' user
trap finish EXIT
trap 'exit 143' TERM INT HUP # so that finish runs when the script is killed
t0=$(date +%s%N)
export ECSYNC_SLURM_LOCAL=$dir # the marker stop() finds the daemons and their jobs by

# munge with its own key and socket, so that it neither needs nor disturbs a system munge.
dd if=/dev/urandom of="$dir/munge.key" bs=1024 count=1 status=none
chmod 600 "$dir/munge.key"
munged --key-file="$dir/munge.key" --socket="$dir/munge.sock" --pid-file="$dir/munged.pid" \
    --seed-file="$dir/munge.seed" --log-file="$dir/log/munged.log"

host=$(hostname -s) # slurmd finds its node line by this name
cat > "$dir/slurm.conf" <<CONF
ClusterName=ecsync-local
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$port
SlurmdPort=$((port + 1))
SlurmUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$dir/munge.sock
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
# No cgroups: a container rarely lets slurmd manage them, and a throwaway cluster needs no fencing.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
# One core per task (sbatch's default), so an array runs as many tasks at once as there are cores.
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
ReturnToService=2
NodeName=$host NodeAddr=127.0.0.1 CPUs=$(nproc) State=UNKNOWN
PartitionName=local Nodes=$host Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$dir/slurm.conf # for sbatch and sinfo (and passed on into the jobs)
slurmctld -f "$SLURM_CONF"
up=1
slurmd -f "$SLURM_CONF"
for _ in $(seq 120); do
    [ "$(sinfo -h -o %T 2>/dev/null)" = idle ] && break
    sleep 0.25
done
[ "$(sinfo -h -o %T 2>/dev/null)" = idle ] || { echo "slurm-local: the node did not come up idle in 30 s" >&2; exit 1; }
echo "slurm-local: single-node cluster $host up in $(( ($(date +%s%N) - t0) / 1000000 )) ms ($(nproc) CPUs)" >&2

# In the background so that a signal to this script is handled at once, not when sbatch returns.
sbatch --wait "$@" &
wait $!
