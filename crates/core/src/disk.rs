//! Local disks as the writers meet them: which file system a path is on and how
//! much room it has (so that a write that fails for want of space says where and
//! how much: [`full_note`]), whether a process is still alive, and exclusive
//! locks that die with their holder ([`Lock`], `flock`), which tell a run that is
//! still writing from the leftovers of one that was killed.

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

/// Whether `e` says the disk (or the user's quota) is full.
pub fn is_full(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::StorageFull
        || matches!(e.raw_os_error(), Some(c) if c == libc::ENOSPC || c == libc::EDQUOT)
}

/// The nearest existing directory at or above `path`, absolute.
fn existing_dir(path: &Path) -> Option<PathBuf> {
    let abs = std::path::absolute(path).ok()?;
    abs.ancestors()
        .find(|a| a.is_dir())
        .and_then(|a| a.canonicalize().ok())
}

/// The mount point of the file system that holds `path` (or would hold it: the
/// nearest existing directory above it): the highest directory above it on the
/// same device.
pub fn mount_point(path: &Path) -> Option<PathBuf> {
    use std::os::unix::fs::MetadataExt;
    let dir = existing_dir(path)?;
    let dev = std::fs::metadata(&dir).ok()?.dev();
    let mut top = dir.clone();
    for a in dir.ancestors().skip(1) {
        match std::fs::metadata(a) {
            Ok(m) if m.dev() == dev => top = a.to_path_buf(),
            _ => break,
        }
    }
    Some(top)
}

/// The size of the file system holding `path` and the bytes free to this user:
/// `(total, free)`.
pub fn space(path: &Path) -> Option<(u64, u64)> {
    let dir = existing_dir(path)?;
    let c = std::ffi::CString::new(dir.as_os_str().as_encoded_bytes()).ok()?;
    // SAFETY: statvfs fills the struct it is given; `c` is a valid C string.
    let mut s: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: as above.
    if unsafe { libc::statvfs(c.as_ptr(), &mut s) } != 0 {
        return None;
    }
    let unit = s.f_frsize as u64;
    Some((s.f_blocks as u64 * unit, s.f_bavail as u64 * unit))
}

/// What is known about a full file system holding `path`: "the file system at
/// /mnt/x is full (12 KiB of 4.0 MiB free; about 9.5 MiB needed)". `needed`:
/// the bytes the write wanted in all, where the writer knows them.
pub fn full_note(path: &Path, needed: Option<u64>) -> String {
    let at = mount_point(path)
        .map(|m| crate::text::sanitize(&m.display().to_string()))
        .unwrap_or_else(|| "?".into());
    let mut s = format!("the file system at {at} is full");
    let room = space(path).map(|(total, free)| {
        format!(
            "{} of {} free",
            crate::text::bytes(free),
            crate::text::bytes(total)
        )
    });
    let need = needed.map(|n| format!("about {} needed", crate::text::bytes(n)));
    let facts: Vec<String> = room.into_iter().chain(need).collect();
    if !facts.is_empty() {
        s.push_str(&format!(" ({})", facts.join("; ")));
    }
    s
}

/// `e` with [`full_note`] added when it says the disk is full; else `e`.
pub fn with_full_note(e: io::Error, path: &Path, needed: Option<u64>) -> io::Error {
    if is_full(&e) {
        io::Error::new(e.kind(), format!("{e}: {}", full_note(path, needed)))
    } else {
        e
    }
}

/// Whether process `pid` of this machine is alive (or may be: one of another
/// user counts as alive).
pub fn pid_alive(pid: u32) -> bool {
    let Ok(p) = libc::pid_t::try_from(pid) else {
        return false;
    };
    if p <= 0 {
        return false;
    }
    // SAFETY: signal 0 only asks whether the process exists.
    let r = unsafe { libc::kill(p, 0) };
    r == 0 || io::Error::last_os_error().raw_os_error() == Some(libc::EPERM)
}

/// The process id a temporary name carries after `tag`: the digits that
/// follow it (`.x.pcimg-out-1234` with tag `pcimg-out-` gives 1234).
pub fn pid_after(name: &str, tag: &str) -> Option<u32> {
    let rest = &name[name.find(tag)? + tag.len()..];
    let digits: String = rest.chars().take_while(char::is_ascii_digit).collect();
    digits.parse().ok()
}

/// An exclusive lock on a file (`flock`), held until dropped; the kernel
/// releases it when the holder dies, however it dies, so a killed run never
/// leaves a lock that blocks the next. The file holds the holder's process id.
#[derive(Debug)]
pub struct Lock {
    path: PathBuf,
    /// Held open: closing it releases the lock.
    _file: File,
    /// Remove the file when dropped.
    remove: bool,
}

/// Who holds a lock another run asked for: the process id its file names.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Held {
    pub pid: Option<u32>,
}

fn flock(file: &File, how: libc::c_int) -> io::Result<bool> {
    use std::os::fd::AsRawFd;
    loop {
        // SAFETY: flock on a descriptor this process owns.
        if unsafe { libc::flock(file.as_raw_fd(), how | libc::LOCK_NB) } == 0 {
            return Ok(true);
        }
        let e = io::Error::last_os_error();
        match e.raw_os_error() {
            Some(libc::EWOULDBLOCK) => return Ok(false),
            Some(libc::EINTR) => continue,
            _ => return Err(e),
        }
    }
}

impl Lock {
    /// Takes the lock at `path` (creating the file) without waiting: `Err(Held)`
    /// inside `Ok` when a live process holds it. The file is removed when the
    /// lock is dropped, where `remove`.
    pub fn try_take(path: &Path, remove: bool) -> io::Result<Result<Lock, Held>> {
        use std::io::{Seek, Write};
        use std::os::unix::fs::MetadataExt;
        loop {
            let mut file = File::options()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(path)?;
            if !flock(&file, libc::LOCK_EX)? {
                let text = std::fs::read_to_string(path).unwrap_or_default();
                return Ok(Err(Held {
                    pid: text.trim().parse().ok(),
                }));
            }
            // A holder that let go removed the file it locked: ours must be the
            // file now at the path, else try again with that one.
            let mine = file.metadata()?;
            match std::fs::metadata(path) {
                Ok(now) if now.ino() == mine.ino() && now.dev() == mine.dev() => {}
                _ => continue,
            }
            file.set_len(0)?;
            file.rewind()?;
            writeln!(file, "{}", std::process::id())?;
            return Ok(Ok(Lock {
                path: path.to_path_buf(),
                _file: file,
                remove,
            }));
        }
    }

    /// Where the lock's file is.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Lock {
    fn drop(&mut self) {
        // (Removed while still held: a run that opened it meanwhile finds the
        // path no longer names its file and opens the new one. Closing the
        // file then releases the lock.)
        if self.remove {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// Whether a live process holds the lock on the file at `path` (false when
/// there is no such file).
pub fn is_locked(path: &Path) -> bool {
    let Ok(file) = File::open(path) else {
        return false;
    };
    // A shared lock is refused while someone holds the exclusive one.
    matches!(flock(&file, libc::LOCK_SH), Ok(false))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_lock_excludes_until_dropped_and_names_its_holder() {
        let dir = std::env::temp_dir().join(format!("pcimg-core-lock-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.lock");
        let a = Lock::try_take(&path, true).unwrap().unwrap();
        assert!(is_locked(&path));
        // (flock locks belong to the open file: a second open is refused even
        // in the same process.)
        let held = Lock::try_take(&path, true).unwrap().unwrap_err();
        assert_eq!(held.pid, Some(std::process::id()));
        drop(a);
        assert!(!path.exists());
        assert!(!is_locked(&path));
        let b = Lock::try_take(&path, false).unwrap().unwrap();
        drop(b);
        assert!(path.exists() && !is_locked(&path));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn pids_and_mount_points() {
        assert!(pid_alive(std::process::id()));
        assert!(!pid_alive(0));
        assert_eq!(pid_after(".a.pcimg-out-123", "pcimg-out-"), Some(123));
        assert_eq!(pid_after(".a.b.77.tmp", "b."), Some(77));
        assert_eq!(pid_after(".a.pcimg-out-x", "pcimg-out-"), None);
        let m = mount_point(Path::new("/proc/self")).unwrap();
        assert_eq!(m, Path::new("/proc"));
        let (total, free) = space(&std::env::temp_dir()).unwrap();
        assert!(total >= free);
        let full = io::Error::from_raw_os_error(libc::ENOSPC);
        assert!(is_full(&full));
        let e = with_full_note(full, Path::new("/proc/self/x"), Some(5 << 20));
        assert!(
            e.to_string().contains("the file system at /proc is full"),
            "{e}"
        );
        assert!(e.to_string().contains("about 5.0 MiB needed"), "{e}");
        let other = with_full_note(
            io::Error::from_raw_os_error(libc::EACCES),
            Path::new("/"),
            None,
        );
        assert!(!other.to_string().contains("full"), "{other}");
    }
}
