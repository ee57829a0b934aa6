//! `ecsync run`'s output files are checked before anything goes out: a `--summary` or
//! `--save-network` path that cannot be written fails before the interface is even opened
//! (here one that does not exist, which would be the error otherwise).

use std::process::Command;

#[test]
fn an_unwritable_summary_or_twin_fails_before_the_link() {
    let dir = std::env::temp_dir().join(format!("ecsync-run-out-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("a-file");
    std::fs::write(&file, b"not a folder").unwrap();
    for flag in ["--summary", "--save-network"] {
        let o = Command::new(env!("CARGO_BIN_EXE_ecsync"))
            .args(["run", "--iface", "ecsync-no-such-if0", flag])
            .arg(file.join("x.toml"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert!(err.contains(&format!("{flag}: cannot write")), "{err}");
        assert!(
            !err.contains("ecsync-no-such-if0"),
            "the link was not opened: {err}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
