//! One `ecsync serve` an interface: two on one interface would both answer every frame, and a
//! master there would see two segments' replies. Each serve holds an exclusive lock (flock) on
//! a file named after the interface and its network namespace while it serves; a second is
//! refused naming the first's pid. The kernel drops the lock when its holder ends, however it
//! ends: the file of a serve that was killed (SIGKILL) stays, unlocked, and the next serve on
//! the interface takes it over. Its file is removed when it ends cleanly, and a serve that
//! takes a lock removes the folder's other unlocked lock files (a killed serve's in a network
//! namespace that is gone, whose name no serve takes again); a lock taken on a file removed
//! meanwhile is taken again on the new one, and a lock held only while its file is removed
//! is waited for a moment, not reported as a serve.

use anyhow::{Result, anyhow};
use std::fs::File;
use std::io::{Read, Seek, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// A lock held as long as this lives; its file removed when it ends.
pub struct IfaceLock {
    held: Option<(File, PathBuf)>,
}

impl Drop for IfaceLock {
    fn drop(&mut self) {
        // Removed while still locked: a serve that opened it meanwhile finds, once it has the
        // lock, that the path no longer names its file, and takes the lock again.
        if let Some((_, path)) = &self.held {
            let _ = std::fs::remove_file(path);
        }
    }
}

/// Whether `path` still names `file` (not removed, nor made anew, since it was opened).
fn still_names(path: &Path, file: &File) -> bool {
    match (std::fs::metadata(path), file.metadata()) {
        (Ok(p), Ok(f)) => p.ino() == f.ino() && p.dev() == f.dev(),
        _ => false,
    }
}

/// The folders a lock file may live in, the first that takes it: /run for root, the user's
/// runtime folder, else the temporary folder (a serve sees the locks of the same user).
fn lock_dirs() -> Vec<PathBuf> {
    let mut dirs = vec![PathBuf::from("/run/ecsync")];
    if let Some(d) = std::env::var_os("XDG_RUNTIME_DIR") {
        dirs.push(Path::new(&d).join("ecsync"));
    }
    dirs.push(std::env::temp_dir().join("ecsync-serve-locks"));
    dirs
}

/// The lock file's name: the interface within its network namespace (two namespaces may each
/// have an `ecsync0`, as every sandbox does; its inode tells the namespaces apart).
fn lock_name(iface: &str) -> String {
    let netns = std::fs::metadata("/proc/self/ns/net").map_or(0, |m| m.ino());
    format!("serve-net{netns}-{iface}.lock")
}

/// How long a lock held by another process is tried again before that process is named as a
/// serve: a serve removing its file as it ends, or another sweeping a stale one, holds it for
/// microseconds.
const HELD_RETRIES: u32 = 20;
const HELD_RETRY_MS: u64 = 5;

/// Whether `name` is a lock file's name (see [`lock_name`]).
fn is_lock_name(name: &str) -> bool {
    name.starts_with("serve-net") && name.ends_with(".lock")
}

/// Removes the unlocked lock files in `dir` but `keep`: their serves ended without removing
/// them (SIGKILL). Each is removed while locked, as a serve's own file is when it ends, so that
/// a serve that opened it meanwhile takes its lock again on a new file.
fn sweep_stale(dir: &Path, keep: &Path) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let path = e.path();
        if path == keep || !e.file_name().to_str().is_some_and(is_lock_name) {
            continue;
        }
        let Ok(file) = File::open(&path) else {
            continue;
        };
        if ecsync_net::sys::try_lock_exclusive(&file).unwrap_or(false) && still_names(&path, &file)
        {
            let _ = std::fs::remove_file(&path);
        }
    }
}

/// Takes the lock of `iface` (`flag` names the option that gave it), or says which serve holds
/// it and what to do.
pub fn take(iface: &str, flag: &str) -> Result<IfaceLock> {
    let name = lock_name(iface);
    let mut refused = Vec::new();
    let mut dirs = lock_dirs().into_iter();
    let (mut retries, mut held_retries) = (0, 0);
    let mut dir = dirs.next();
    while let Some(d) = dir.take() {
        let path = d.join(&name);
        let opened = std::fs::create_dir_all(&d).and_then(|()| {
            std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
        });
        let mut file = match opened {
            Ok(f) => f,
            Err(e) => {
                refused.push(format!("{}: {e}", path.display()));
                dir = dirs.next();
                continue;
            }
        };
        if ecsync_net::sys::try_lock_exclusive(&file)? {
            if !still_names(&path, &file) && retries < 10 {
                // The serve that held it ended and removed it between our open and our lock.
                retries += 1;
                dir = Some(d);
                continue;
            }
            // The holder's pid, for the error of a second serve.
            file.set_len(0)?;
            file.rewind()?;
            write!(file, "{}", std::process::id())?;
            sweep_stale(&d, &path);
            return Ok(IfaceLock {
                held: Some((file, path)),
            });
        }
        if held_retries < HELD_RETRIES {
            held_retries += 1;
            std::thread::sleep(std::time::Duration::from_millis(HELD_RETRY_MS));
            dir = Some(d);
            continue;
        }
        let mut pid = String::new();
        let _ = file.read_to_string(&mut pid);
        let pid = pid.trim();
        let who = if pid.is_empty() {
            "another ecsync serve".to_string()
        } else {
            format!("another ecsync serve (pid {pid})")
        };
        let kill = if pid.is_empty() {
            String::new()
        } else {
            format!(" (kill {pid})")
        };
        return Err(anyhow!(
            "{flag} {iface}: {who} serves this interface already (its lock: {}); two would both answer every frame, and a master would see two segments' replies; fix: stop that serve{kill}, or serve on another interface",
            path.display()
        ));
    }
    // Nowhere to keep a lock: serve anyway (a second serve cannot be told of, as before).
    eprintln!(
        "ecsync serve: warning: no folder takes the lock of {iface} ({}); a second serve on it would not be refused",
        refused.join("; ")
    );
    Ok(IfaceLock { held: None })
}
