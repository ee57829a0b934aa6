//! Issue 33, acceptance 4: the recipes for running a sweep beyond one process
//! (`scripts/recipes/`): 4 shards under GNU parallel, a 4-task Slurm job array on a throwaway
//! single-node cluster (slurmctld, slurmd and munged started by the script, no systemd), and the
//! Kubernetes Indexed Job, schema-checked offline and its pods' command lines run here. Each
//! merged database must equal the sweep run whole, table for table; a failing shard must fail
//! the parallel and Slurm recipes; a broken manifest must fail the schema check.

use std::path::Path;
use std::process::Command;

#[test]
#[ignore = "needs root, Slurm (slurm-wlm), GNU parallel and kubernetes-validate (.ci/run installs them)"]
fn slurm_parallel_and_kubernetes_recipes_merge_to_the_whole_sweep() {
    let script =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scripts/recipes/test-recipes.sh");
    let o = Command::new("bash")
        .arg(&script)
        .env("ECSYNC_BIN", env!("CARGO_BIN_EXE_ecsync"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    let err = String::from_utf8_lossy(&o.stderr);
    println!("{out}");
    assert!(o.status.success(), "{out}{err}");
    assert!(out.contains("recipes: 7 passed, 0 failed"), "{out}");
}
