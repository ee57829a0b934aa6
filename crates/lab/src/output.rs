//! Output files of a run (summaries, tables, reports): written atomically, so a reader — or
//! a run interrupted mid-write — never meets half a file.

use std::io;
use std::path::Path;

/// Writes `bytes` to `path` atomically: to a temporary file next to it, then renamed over it
/// (a rename within one directory replaces the file in one step).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let tmp = path.with_extension("tmp-ecsync");
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

/// Makes directory `dir` (and its parents) and checks that a file can be written into it, by
/// writing and removing one: checked before a run, so that a path that cannot take the results
/// (a file where a folder should be, a read-only or full file system, no permission) fails at
/// once instead of after the work.
pub fn ensure_writable_dir(dir: &Path) -> io::Result<()> {
    std::fs::create_dir_all(dir)?;
    let probe = dir.join(format!(".ecsync-write-check-{}", std::process::id()));
    std::fs::write(&probe, b"ecsync")?;
    std::fs::remove_file(&probe)
}

/// Checks that file `path` can be written (its folder made, a file written beside it and
/// removed), before a run whose result goes there.
pub fn ensure_writable_file(path: &Path) -> io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if path.is_dir() {
        return Err(io::Error::new(
            io::ErrorKind::IsADirectory,
            "it is a directory",
        ));
    }
    ensure_writable_dir(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folder_under_a_file_is_refused_and_a_fresh_one_accepted() {
        let dir = std::env::temp_dir().join(format!("ecsync-writable-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("plain-file");
        std::fs::write(&file, b"x").unwrap();
        // A file where a folder should be: refused, as it would be for root too.
        assert!(ensure_writable_dir(&file.join("out")).is_err());
        assert!(ensure_writable_file(&file.join("summary.json")).is_err());
        assert!(ensure_writable_file(&dir).is_err());
        // A new nested folder: made, and left empty.
        let fresh = dir.join("a/b");
        ensure_writable_dir(&fresh).unwrap();
        assert_eq!(std::fs::read_dir(&fresh).unwrap().count(), 0);
        ensure_writable_file(&dir.join("summary.json")).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn replaces_the_file_and_leaves_no_temporary() {
        let dir = std::env::temp_dir().join(format!("ecsync-output-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("summary.json");
        write_atomic(&p, b"old").unwrap();
        write_atomic(&p, b"new").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"new");
        assert!(!p.with_extension("tmp-ecsync").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
