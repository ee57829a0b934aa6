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

#[cfg(test)]
mod tests {
    use super::*;

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
