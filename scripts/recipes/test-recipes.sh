#!/usr/bin/env bash
# Runs the three recipes with the real `ecsync sweep` (ECSYNC_BIN) on a 6-point grid of short
# comparisons: 4 shards under GNU parallel, a 4-task Slurm array on a throwaway local cluster,
# and the Indexed Job's pods (emulated: its args with $(JOB_COMPLETION_INDEX) filled in as
# Kubernetes does, each index run here). Each merged database must equal the sweep run whole,
# table for table; a failing shard must fail each recipe; a broken manifest must fail
# validation. Root (it may apt-get); about a minute. crates/cli/tests/recipes.rs runs it.
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
real=${ECSYNC_BIN:?"give the ecsync binary in ECSYNC_BIN"}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
chmod 755 "$work" # munged wants every folder above its socket open to all
export ECSYNC_SLURM_DIR=$work/cluster # the failing run keeps its logs there: removed with the rest
# The binary the recipes call: the real one, failing on purpose for shard FAIL_SHARD (the
# failure paths), and leaving its own threads to one core (the shards share the machine).
cat > "$work/ecsync" <<SH
#!/usr/bin/env bash
if [ -n "\${FAIL_SHARD:-}" ]; then
    for a in "\$@"; do
        case \$a in "\$FAIL_SHARD"/[0-9]*) echo "shard \$a fails on purpose" >&2; exit 3 ;; esac
    done
fi
[ "\${2:-}" = merge ] && exec "$real" "\$@"
exec "$real" "\$@" --threads 1
SH
chmod 755 "$work/ecsync"
export ECSYNC_BIN=$work/ecsync
# shellcheck disable=SC2054 # the commas are inside grid values
args=(--preset paper-2024 --grid 'run.sync0_shift_pct=10,20,30' --grid 'methods.median-fit.gain=0.01,0.02'
      --runs 1 --cycles 2000 --warmup-s 10 --methods median-fit,soem-pi --quiet)
"$real" sweep "${args[@]}" --db "$work/whole.db" >/dev/null
pass=0 fail=0
ok() { echo "ok: $*"; pass=$((pass + 1)); }
no() { echo "FAILED: $*"; fail=$((fail + 1)); }
# The merged database holds what the whole run does, row for row (the log table aside).
same_as_whole() {
    python3 - "$work/whole.db" "$1" <<'PY'
import sqlite3, sys
def rows(p):
    c = sqlite3.connect(p)
    return [r for t, k in (("sweep", "key"), ("points", "point"), ("results", "point, method"))
            for r in c.execute(f"select * from {t} order by {k}")]
a, b = rows(sys.argv[1]), rows(sys.argv[2])
sys.exit(0 if a == b and len(a) > 12 else 1)
PY
}

t=$SECONDS
if "$here/sweep-parallel.sh" 4 "$work/par" "${args[@]}" >/dev/null && same_as_whole "$work/par/merged.db"; then
    ok "GNU parallel: 4 shards merged equal the whole sweep ($((SECONDS - t)) s)"
else no "GNU parallel"; fi
if FAIL_SHARD=2 "$here/sweep-parallel.sh" 4 "$work/parfail" "${args[@]}" >/dev/null 2>&1 \
    || [ -e "$work/parfail/merged.db" ]; then no "GNU parallel: a failed shard did not fail the run"
else ok "GNU parallel: a failed shard fails the run, nothing merged"; fi

mkdir "$work/slurm" && cd "$work/slurm"
t=$SECONDS
if "$here/slurm-local.sh" --array=0-3 "$here/sweep-array.sbatch" "${args[@]}" \
    && "$real" sweep merge --db merged.db shard-{0,1,2,3}.db >/dev/null 2>&1 && same_as_whole merged.db; then
    ok "Slurm: a 4-task array on a local cluster merged equals the whole sweep ($((SECONDS - t)) s)"
else no "Slurm array"; fi
rm -f shard-*.db
# The arguments through ECSYNC_SWEEP_ARGS this time, with the quotes a user would type.
export ECSYNC_SWEEP_ARGS="--preset paper-2024 --grid 'run.sync0_shift_pct=10,20,30' --grid 'methods.median-fit.gain=0.01,0.02' --runs 1 --cycles 2000 --warmup-s 10 --methods median-fit,soem-pi --quiet"
set +e
FAIL_SHARD=1 "$here/slurm-local.sh" --array=0-3 "$here/sweep-array.sbatch" 2>/dev/null
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
# Emulation, not a cluster: each index's command line as the kubelet would make it, run here
# (the manifest's grid with the short comparison of this test appended).
if "${ECSYNC_K8S_VENV:-/var/tmp/ecsync-k8s-venv}/bin/python" - "$here/sweep-indexed-job.yaml" "$work/k8s" "${args[@]}" <<'PY'
import os, subprocess, sys, yaml
job = next(d for d in yaml.safe_load_all(open(sys.argv[1])) if d["kind"] == "Job")
c = job["spec"]["template"]["spec"]["containers"][0]
results, grid = sys.argv[2], sys.argv[3:]
os.makedirs(results)
for i in range(job["spec"]["completions"]):
    argv = [a.replace("$(JOB_COMPLETION_INDEX)", str(i)).replace("/results/", results + "/") for a in c["args"]]
    # The manifest's own shard and database, this test's points.
    shard = argv[argv.index("--shard") : argv.index("--shard") + 2]
    db = argv[argv.index("--db") : argv.index("--db") + 2]
    subprocess.run([os.environ["ECSYNC_BIN"], "sweep", *grid, *shard, *db], check=True)
PY
then
    "$real" sweep merge --db k8s/merged.db k8s/shard-{0,1,2,3}.db >/dev/null 2>&1
    if same_as_whole k8s/merged.db; then ok "Kubernetes (emulated): 4 indices merged equal the whole sweep"
    else no "Kubernetes (emulated): merged points"; fi
else no "Kubernetes (emulated): a pod's command failed"; fi

echo "recipes: $pass passed, $fail failed"
[ "$fail" = 0 ]
