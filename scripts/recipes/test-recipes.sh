#!/usr/bin/env bash
# Runs the three recipes' mechanics with fake-ecsync.sh standing in for `ecsync sweep`: the shards
# of a 6-point grid, run as 4 parallel jobs, a 4-task Slurm array on a throwaway local cluster, and
# the Indexed Job's pods (emulated: its args with $(JOB_COMPLETION_INDEX) replaced as Kubernetes
# would, each index run here), must merge to every point exactly once; a failing shard must fail
# each recipe; a broken manifest must fail validation. Root (it may apt-get); about 40 s.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
export ECSYNC_BIN=$here/fake-ecsync.sh
args=(--preset paper-2024 --grid 'run.sync0_shift_pct=10,20,30' --grid 'methods.median-fit.gain=0.1,0.2' --quiet)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
chmod 755 "$work" # munged wants every folder above its socket open to all
export ECSYNC_SLURM_DIR=$work/cluster # the failing run keeps its logs there: removed with the rest
pass=0 fail=0
ok() { echo "ok: $*"; pass=$((pass + 1)); }
no() { echo "FAILED: $*"; fail=$((fail + 1)); }
all_points() { [ "$(sort -n "$1" | tr '\n' ' ')" = "0 1 2 3 4 5 " ]; }

t=$SECONDS
if "$here/sweep-parallel.sh" 4 "$work/par" "${args[@]}" && all_points "$work/par/merged.db"; then
    ok "GNU parallel: 4 shards merged to every point once ($((SECONDS - t)) s)"
else no "GNU parallel"; fi
if FAKE_ECSYNC_FAIL_SHARD=2 "$here/sweep-parallel.sh" 4 "$work/parfail" "${args[@]}" 2>/dev/null \
    || [ -e "$work/parfail/merged.db" ]; then no "GNU parallel: a failed shard did not fail the run"
else ok "GNU parallel: a failed shard fails the run, nothing merged"; fi

mkdir "$work/slurm" && cd "$work/slurm"
t=$SECONDS
if "$here/slurm-local.sh" --array=0-3 "$here/sweep-array.sbatch" "${args[@]}" \
    && "$ECSYNC_BIN" sweep merge --db merged.db shard-{0,1,2,3}.db && all_points merged.db; then
    ok "Slurm: a 4-task array on a local cluster merged to every point once ($((SECONDS - t)) s)"
else no "Slurm array"; fi
rm -f shard-*.db
# The arguments through ECSYNC_SWEEP_ARGS this time, with the quotes a user would type.
export ECSYNC_SWEEP_ARGS="--grid 'run.sync0_shift_pct=10,20,30' --grid 'methods.median-fit.gain=0.1,0.2'"
set +e
FAKE_ECSYNC_FAIL_SHARD=1 "$here/slurm-local.sh" --array=0-3 "$here/sweep-array.sbatch" 2>/dev/null
rc=$?
set -e
unset ECSYNC_SWEEP_ARGS
if [ "$rc" = 3 ] && [ -e shard-0.db ] && [ ! -e shard-1.db ]; then ok "Slurm: sbatch --wait exits 3 as the failed task did"
else no "Slurm: a failed task gave exit $rc"; fi
cd "$work"

if "$here/validate-k8s.sh" >/dev/null; then ok "Kubernetes: the manifest validates"; else no "Kubernetes: validation"; fi
sed 's/completions: 4/completions: 5/; s/  parallelism:/  paralelism:/' "$here/sweep-indexed-job.yaml" > broken.yaml
if "$here/validate-k8s.sh" broken.yaml >/dev/null 2>&1; then no "Kubernetes: a broken manifest validated"
else ok "Kubernetes: a broken manifest fails validation"; fi
# Emulation, not a cluster: each index's command line as the kubelet would make it, run here.
if "${ECSYNC_K8S_VENV:-/var/tmp/ecsync-k8s-venv}/bin/python" - "$here/sweep-indexed-job.yaml" "$work/k8s" <<'PY'
import os, subprocess, sys, yaml
job = next(d for d in yaml.safe_load_all(open(sys.argv[1])) if d["kind"] == "Job")
c = job["spec"]["template"]["spec"]["containers"][0]
results = sys.argv[2]
os.makedirs(results)
for i in range(job["spec"]["completions"]):
    argv = [a.replace("$(JOB_COMPLETION_INDEX)", str(i)).replace("/results/", results + "/") for a in c["args"]]
    subprocess.run([os.environ["ECSYNC_BIN"]] + argv, check=True)
PY
then
    "$ECSYNC_BIN" sweep merge --db k8s/merged.db k8s/shard-{0,1,2,3}.db
    if all_points k8s/merged.db; then ok "Kubernetes (emulated): 4 indices merged to every point once"
    else no "Kubernetes (emulated): merged points"; fi
else no "Kubernetes (emulated): a pod's command failed"; fi

echo "recipes: $pass passed, $fail failed"
[ "$fail" = 0 ]
