#!/usr/bin/env bash
# Offline check of the Kubernetes recipe (no cluster, no network past PyPI for the first install):
# kubernetes-validate ships the API's JSON schemas. Strict, so a misspelt field fails instead of
# being dropped; against 1.25 (the oldest it ships; Indexed Jobs are stable since 1.24) and its
# newest. The schemas hold no enums and know nothing of the shard arithmetic, so a few lines of
# Python check what they cannot. Exits non-zero on an invalid file.
#   scripts/recipes/validate-k8s.sh [FILE.yaml...]   (default: sweep-indexed-job.yaml beside it)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
[ $# -gt 0 ] || set -- "$here/sweep-indexed-job.yaml"
venv=${ECSYNC_K8S_VENV:-/var/tmp/ecsync-k8s-venv}
base=python3
[ -x /usr/bin/python3 ] && base=/usr/bin/python3
if ! "$venv/bin/kubernetes-validate" --version >/dev/null 2>&1; then
    if ! "$base" -m venv "$venv" >/dev/null 2>&1; then
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -q
        apt-get install -y -q --no-install-recommends python3-venv
        "$base" -m venv "$venv"
    fi
    # Pinned: its newest schema version moves with the package.
    "$venv/bin/pip" install -q kubernetes-validate==1.37.0
fi
for k in 1.25.0 1.37.0; do
    "$venv/bin/kubernetes-validate" --strict --kubernetes-version "$k" "$@"
done
"$venv/bin/python" - "$@" <<'PY'
import sys, yaml
bad = []
for path in sys.argv[1:]:
    for doc in yaml.safe_load_all(open(path)):
        if not doc or doc.get("kind") != "Job":
            continue
        spec = doc["spec"]
        name = f"{path}: job/{doc['metadata']['name']}"
        n = spec.get("completions")
        if spec.get("completionMode") != "Indexed":
            bad.append(f"{name}: completionMode is {spec.get('completionMode')!r}, not 'Indexed'")
        for c in spec["template"]["spec"]["containers"]:
            args = c.get("args", [])
            opt = lambda o: args[args.index(o) + 1] if o in args[:-1] else None
            if opt("--shard") != f"$(JOB_COMPLETION_INDEX)/{n}":
                bad.append(f"{name}: --shard is {opt('--shard')!r}, not '$(JOB_COMPLETION_INDEX)/{n}' (completions {n})")
            if "$(JOB_COMPLETION_INDEX)" not in (opt("--db") or ""):
                bad.append(f"{name}: --db {opt('--db')!r} is the same file for every shard")
print("\n".join(bad) or "recipe checks passed: Indexed, --shard $(JOB_COMPLETION_INDEX)/completions, one --db per index")
sys.exit(1 if bad else 0)
PY
