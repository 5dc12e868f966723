//! Whether a conversion may write its output path: its directory must exist, it
//! must not (or `--force` must be given), and even with `--force` it must not be the input,
//! hold the input or the working directory, or be a directory other than a
//! pcimg dataset: replacing an output removes it, so only what pcimg itself
//! wrote may be removed.

use anyhow::{Result, bail};
use std::path::{Component, Path, PathBuf};

/// Extensions an output is refused with: other image formats, point clouds and
/// common file types (a directory of parts would be made under such a name).
const NOT_A_DATASET: [&str; 27] = [
    "png", "jpg", "jpeg", "gif", "bmp", "webp", "jp2", "tga", "exr", "las", "laz", "xyz", "txt",
    "csv", "asc", "pts", "ply", "e57", "pcd", "xyzrgb", "xyzn", "obj", "zip", "gz", "json", "bin",
    "md",
];

/// The output path as a conversion uses it: its last component a name (not `.`,
/// `..` or a root), trailing slashes and `.` components dropped, and its
/// directory resolved when the path climbs with `..`, so that `X/.`, `X/` and
/// `X/../X` all mean `X` and no later step runs through the output itself.
pub fn resolve(output: &Path) -> Result<PathBuf> {
    let shown = output.display();
    let Some(name) = output.file_name() else {
        bail!("{shown}: name the output (a .tif file or a directory to create), not . or .. or /");
    };
    let ext = output
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if let Some(ext) = ext.filter(|e| NOT_A_DATASET.contains(&e.as_str())) {
        bail!(
            "{shown}: a dataset is a .tif file or a directory of parts, not .{ext}: \
             name it e.g. NAME.tif or NAME.pcimg"
        );
    }
    let Some(parent) = output.parent().filter(|p| !p.as_os_str().is_empty()) else {
        return Ok(PathBuf::from(name));
    };
    if parent.components().any(|c| c == Component::ParentDir) {
        let real = parent
            .canonicalize()
            .map_err(|e| anyhow::anyhow!("{shown}: cannot resolve {}: {e}", parent.display()))?;
        return Ok(real.join(name));
    }
    Ok(parent.join(name))
}

/// The lock of a conversion's output, `.<name>.pcimg-lock` beside it, held
/// while it runs (also by `pcimg index` on a dataset): a second run on the same
/// output is refused, naming the holder's process. The kernel lets go of it when
/// its holder dies, so a killed run never blocks the next.
pub fn lock(output: &Path) -> Result<crate::disk::Lock> {
    let shown = output.display();
    let parent = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let name = output
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let path = parent.join(format!(".{name}.pcimg-lock"));
    match crate::disk::Lock::try_take(&path, true) {
        Ok(Ok(lock)) => Ok(lock),
        Ok(Err(held)) => bail!(
            "{shown}: another pcimg run is writing it{} (lock {}); wait for it to finish, \
             or write another output",
            held.pid
                .map(|p| format!(" (process {p})"))
                .unwrap_or_default(),
            path.display()
        ),
        // (A directory that does not exist is said by the output check.)
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => bail!(
            "{shown}: the directory {} does not exist (create it first)",
            parent.display()
        ),
        Err(e) => bail!(
            "{shown}: cannot write in {} (its lock {}): {}",
            parent.display(),
            path.display(),
            crate::disk::with_full_note(e, &path, None)
        ),
    }
}

/// Removes what killed runs left for `output`: beside it, the staging and
/// spill directories and the single part's temporary file of conversions whose
/// process is gone; inside it (a dataset), the temporary overview and index of
/// `pcimg index` and the staging directories of cluster shards. Call it
/// holding [`lock`]. Returns what it removed.
pub fn remove_leftovers(output: &Path) -> Vec<PathBuf> {
    use super::spill::sweep;
    let parent = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let Some(name) = output.file_name().map(|n| n.to_string_lossy().into_owned()) else {
        return Vec::new();
    };
    let mine = format!(".{name}.");
    let mut gone = sweep(parent, &mine, "pcimg-out-", "");
    gone.extend(sweep(parent, &mine, "pcimg-spill-", ""));
    // The store's `.<name>.<pid>.tmp`.
    gone.extend(sweep(parent, ".", &format!("{name}."), ".tmp"));
    if output.is_dir() {
        gone.extend(crate::store::dataset::overview::remove_leftovers(output));
        gone.extend(super::cluster::remove_leftovers(output));
    }
    gone
}

/// Checks that converting `input` may write `output` (a `.tif` file when
/// `as_file`, else a directory of parts), replacing it only with `force`.
pub fn check(input: &Path, output: &Path, as_file: bool, force: bool) -> Result<()> {
    let shown = output.display();
    let parent = output
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !parent.exists() {
        bail!(
            "{shown}: the directory {} does not exist (create it first)",
            parent.display()
        );
    }
    if !parent.is_dir() {
        bail!("{shown}: {} is not a directory", parent.display());
    }
    let meta = match std::fs::symlink_metadata(output) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => bail!("{shown}: cannot inspect the output path: {e}"),
    };
    if !force {
        bail!("{shown}: already exists (use --force to replace it)");
    }
    if meta.file_type().is_symlink() {
        bail!("{shown}: is a symbolic link; refusing to replace it");
    }
    let out = output
        .canonicalize()
        .map_err(|e| anyhow::anyhow!("{shown}: cannot resolve the output path: {e}"))?;
    if let Ok(inp) = input.canonicalize() {
        if inp == out {
            bail!("{shown}: the output is the input file; choose another output");
        }
        if inp.starts_with(&out) {
            bail!("{shown}: holds the input file; refusing to replace it");
        }
    }
    if let Ok(cwd) = std::env::current_dir().and_then(|d| d.canonicalize())
        && cwd.starts_with(&out)
    {
        bail!("{shown}: is the working directory or holds it; refusing to replace it");
    }
    match (meta.is_dir(), as_file) {
        (true, true) => bail!(
            "{shown}: is a directory, and a .tif output is a single file; choose another output"
        ),
        (false, false) => bail!(
            "{shown}: is a file, and this output is a directory of parts (name a .tif file \
             for a single part); choose another output"
        ),
        (true, false) => check_dataset_dir(output),
        (false, true) => Ok(()),
    }
}

/// A directory `--force` may replace: empty, or holding pcimg parts only.
fn check_dataset_dir(dir: &Path) -> Result<()> {
    let shown = dir.display();
    let refuse = |what: String| -> Result<()> {
        bail!(
            "{shown}: is not a pcimg dataset ({what}); refusing to replace it: choose \
             another output, or remove it yourself"
        )
    };
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        let path = entry.path();
        let name = crate::text::sanitize(&entry.file_name().to_string_lossy());
        let ours = entry.file_name() == crate::store::dataset::index::INDEX_FILE
            || (entry.file_name() == crate::store::dataset::index::OVERVIEW_DIR
                && entry.file_type()?.is_dir()
                && std::fs::read_dir(&path)?
                    .all(|e| e.is_ok_and(|e| crate::store::Part::open(&e.path()).is_ok())));
        if ours {
            continue;
        }
        if !entry.file_type()?.is_file() {
            return refuse(format!("it holds {name}, which is not a file"));
        }
        if crate::store::Part::open(&path).is_err() {
            return refuse(format!("it holds {name}, which is not a pcimg part"));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn refused(input: &Path, output: &Path, as_file: bool) -> String {
        check(input, output, as_file, true).unwrap_err().to_string()
    }

    #[test]
    fn force_never_replaces_the_input_or_what_pcimg_did_not_write() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let input = d.join("in.xyz");
        std::fs::write(&input, "1 2 3\n").unwrap();
        // Absent: fine, with or without --force; but not in a missing directory.
        check(&input, &d.join("new.pcimg"), false, false).unwrap();
        let e = check(&input, &d.join("no/new.tif"), true, false)
            .unwrap_err()
            .to_string();
        assert!(e.contains("does not exist"), "{e}");
        // Present without --force.
        let e = check(&input, &input, false, false).unwrap_err().to_string();
        assert!(e.contains("--force"), "{e}");
        // The input itself, as a file or a directory output.
        assert!(refused(&input, &input, false).contains("is the input"));
        assert!(refused(&input, &input, true).contains("is the input"));
        // A directory that holds the input.
        assert!(refused(&input, d, false).contains("holds the input"));
        // A directory of other things.
        let docs = d.join("docs");
        std::fs::create_dir(&docs).unwrap();
        std::fs::write(docs.join("notes.txt"), "keep").unwrap();
        let e = refused(&input, &docs, false);
        assert!(
            e.contains("not a pcimg dataset") && e.contains("notes.txt"),
            "{e}"
        );
        std::fs::remove_file(docs.join("notes.txt")).unwrap();
        std::fs::create_dir(docs.join("sub")).unwrap();
        assert!(refused(&input, &docs, false).contains("sub, which is not a file"));
        std::fs::remove_dir(docs.join("sub")).unwrap();
        // An empty directory may be replaced, but not by a single .tif.
        check(&input, &docs, false, true).unwrap();
        assert!(refused(&input, &docs, true).contains("is a directory"));
        // A file where a directory of parts would go.
        let file = d.join("x.pcimg");
        std::fs::write(&file, "x").unwrap();
        assert!(refused(&input, &file, false).contains("is a file"));
        // Paths that name the output through itself mean the output.
        let docs_str = docs.display().to_string();
        for spelled in [
            format!("{docs_str}/."),
            format!("{docs_str}/"),
            format!("{docs_str}/../docs"),
        ] {
            assert_eq!(
                resolve(Path::new(&spelled)).unwrap().file_name(),
                docs.file_name()
            );
            assert!(
                resolve(Path::new(&spelled))
                    .unwrap()
                    .parent()
                    .unwrap()
                    .canonicalize()
                    .unwrap()
                    == d.canonicalize().unwrap()
            );
        }
        for bad in [".", "..", "/", "x/.."] {
            assert!(
                resolve(Path::new(bad))
                    .unwrap_err()
                    .to_string()
                    .contains("name the output"),
                "{bad}"
            );
        }
        assert_eq!(
            resolve(Path::new("out.pcimg")).unwrap(),
            Path::new("out.pcimg")
        );
        for bad in ["frame.png", "d/scan.LAZ", "x.xyz"] {
            let e = resolve(Path::new(bad)).unwrap_err().to_string();
            assert!(e.contains("not .") && e.contains("NAME.tif"), "{bad}: {e}");
        }
        // A .tif file may be replaced.
        let tif = d.join("a.tif");
        std::fs::write(&tif, "x").unwrap();
        check(&input, &tif, true, true).unwrap();
    }
}
