//! Writing the commands' output files so that a failure never leaves a wrong one,
//! and never destroys an input.
//!
//! * [`write_atomic`] / [`write_atomic_with`]: the content goes to a temporary file
//!   in the destination's folder, is flushed and synced, and then renamed over the
//!   destination. A full disk, a missing or read-only folder leave the old file (or
//!   none) in place, and every error names the destination.
//! * [`prepare`] / [`prepare_folder`]: the checks a command runs on its `--out`
//!   before it starts working (the folder exists or can be created, and takes a
//!   file), so that a long calibration does not end in "cannot write".
//! * [`not_an_input`] / [`folder_spares_inputs`]: an output that is one of the
//!   command's inputs is refused, naming both (paths are compared canonicalised; a
//!   path that does not exist yet by its canonicalised folder and its name).

use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{anyhow, bail, Result};

/// Writes `bytes` to `path` atomically ([`write_atomic_with`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// Writes the file `path` atomically: `fill` writes into a temporary file in the
/// same folder (created if missing), which is flushed, synced to the disk and then
/// renamed to `path`. On any error the temporary file is removed, `path` keeps its
/// old content (or stays absent), and the error names `path`.
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    let dest = destination(path);
    let folder = prepare(&dest)?;
    let tmp = temp_path(&folder);
    let written = write_then_rename(&tmp, &dest, fill);
    if let Err(e) = written {
        let _ = fs::remove_file(&tmp);
        bail!("{}: cannot write: {e}", path.display());
    }
    // Makes the rename itself durable; not every platform can open a folder.
    if let Ok(dir) = File::open(&folder) {
        let _ = dir.sync_all();
    }
    Ok(())
}

/// Where the content of `path` goes: the file a symbolic link points to (the link
/// stays a link), else `path` itself.
fn destination(path: &Path) -> PathBuf {
    let is_link = fs::symlink_metadata(path).is_ok_and(|m| m.file_type().is_symlink());
    match is_link.then(|| path.canonicalize()) {
        Some(Ok(target)) => target,
        _ => path.to_path_buf(),
    }
}

/// Creates `tmp` (it must not exist), fills, flushes and syncs it, renames it to `path`.
fn write_then_rename(
    tmp: &Path,
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> io::Result<()> {
    let file = OpenOptions::new().write(true).create_new(true).open(tmp)?;
    let mut w = BufWriter::new(file);
    fill(&mut w)?;
    let file = w.into_inner().map_err(|e| e.into_error())?;
    file.sync_all()?;
    drop(file);
    fs::rename(tmp, path)
}

/// A fresh temporary name in `folder` (hidden, unique per process and call). It
/// does not carry the destination's name: a name that is valid as it is must not
/// become too long (255 bytes on most file systems) by the temporary's additions.
fn temp_path(folder: &Path) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    folder.join(format!(".fpi-{}-{n}.tmp", std::process::id()))
}

/// The folder a path's file goes in (`.` for a bare file name).
fn folder_of(path: &Path) -> PathBuf {
    match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// Checks that the file `path` can be written before a command does its work:
/// `path` is not a folder nor a device, pipe or socket (which an atomic write would
/// replace, e.g. `/dev/full`), its folder exists (it is created if missing) and
/// takes a new file. Returns the folder. Errors name `path`.
pub fn prepare(path: &Path) -> Result<PathBuf> {
    if path.file_name().is_none() {
        bail!("{}: not a file name", path.display());
    }
    if let Ok(meta) = fs::metadata(path) {
        if meta.is_dir() {
            bail!("{}: is a folder, not a file", path.display());
        }
        if !meta.is_file() {
            bail!(
                "{}: not a regular file (a device, a pipe or a socket): refusing to write \
                 an output there",
                path.display()
            );
        }
    }
    let folder = folder_of(path);
    if let Some(file) = folder.ancestors().find(|a| a.is_file()) {
        bail!(
            "{}: cannot create its folder {}: {} is a file",
            path.display(),
            folder.display(),
            file.display()
        );
    }
    fs::create_dir_all(&folder).map_err(|e| {
        anyhow!(
            "{}: cannot create its folder {}: {e}",
            path.display(),
            folder.display()
        )
    })?;
    probe(&folder).map_err(|e| {
        anyhow!(
            "{}: its folder {} does not take a new file: {e}",
            path.display(),
            folder.display()
        )
    })?;
    Ok(folder)
}

/// The checks a command that writes files after it has worked (measured a
/// board, fitted a model) runs on its outputs before it starts: each output
/// (with the option that gave it, e.g. `--out`) is no input of the command and
/// no other output, and takes a file ([`prepare`]; nothing is left behind).
/// Errors name the option and the path.
pub fn check_outputs(outputs: &[(&str, &Path)], inputs: &[(&str, &Path)]) -> Result<()> {
    for (k, (option, out)) in outputs.iter().enumerate() {
        not_an_input(option, out, inputs)?;
        if let Some((other, _)) = outputs[..k].iter().find(|(_, o)| same_file(o, out)) {
            bail!(
                "{option} {} is also {other}: give each output its own file",
                out.display()
            );
        }
        prepare(out).map_err(|e| anyhow!("{option} {e:#}"))?;
    }
    Ok(())
}

/// Checks that the folder `dir` exists (it is created if missing) and takes new
/// files. Errors name `dir`.
pub fn prepare_folder(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        bail!("{}: not a folder (a file is in the way)", dir.display());
    }
    fs::create_dir_all(dir)
        .map_err(|e| anyhow!("{}: cannot create the folder: {e}", dir.display()))?;
    if !dir.is_dir() {
        bail!("{}: not a folder", dir.display());
    }
    probe(dir).map_err(|e| {
        anyhow!(
            "{}: the folder does not take a new file: {e}",
            dir.display()
        )
    })
}

/// Creates and removes a temporary file in `folder`.
fn probe(folder: &Path) -> io::Result<()> {
    let tmp = temp_path(folder);
    OpenOptions::new().write(true).create_new(true).open(&tmp)?;
    fs::remove_file(&tmp)
}

/// What a path refers to, for comparing: canonicalised if it exists, else its
/// canonicalised folder joined with its name (`None` if neither exists).
fn identity(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    let name = path.file_name()?;
    folder_of(path).canonicalize().ok().map(|d| d.join(name))
}

/// Whether two paths name the same file (or the same place for one that does not
/// exist yet).
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (identity(a), identity(b)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// Refuses an output `out` (given as option `what`, e.g. `--out`) that is one of
/// the command's `inputs` (each with the option that gave it, e.g. `--model`).
pub fn not_an_input(what: &str, out: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    for (option, input) in inputs {
        if same_file(out, input) {
            bail!(
                "{what} {} is the input {option} {}: refusing to overwrite an input",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Refuses an output folder `dir` (option `what`) that is an input, or that holds
/// an input which the command would overwrite (`writes(name)` says whether it
/// writes a file of that name in `dir`).
pub fn folder_spares_inputs(
    what: &str,
    dir: &Path,
    inputs: &[(&str, &Path)],
    writes: impl Fn(&str) -> bool,
) -> Result<()> {
    not_an_input(what, dir, inputs)?;
    let Some(dir_id) = identity(dir) else {
        return Ok(());
    };
    for (option, input) in inputs {
        let name = input.file_name().map(|n| n.to_string_lossy().to_string());
        let folder = identity(input).and_then(|p| p.parent().map(Path::to_path_buf));
        if let (Some(name), Some(folder)) = (name, folder) {
            if folder == dir_id && writes(&name) {
                bail!(
                    "{what} {} would overwrite the input {option} {}: choose another folder",
                    dir.display(),
                    input.display()
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("fpi-output-{}-{name}", std::process::id()));
        fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn an_atomic_write_replaces_the_file_and_leaves_no_temporary() {
        let d = dir("atomic");
        let p = d.join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(fs::read_to_string(&p).unwrap(), "two");
        let names: Vec<_> = fs::read_dir(&d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("a.txt")]);
    }

    #[test]
    fn a_failed_write_keeps_the_old_file_and_names_the_path() {
        let d = dir("failed");
        let p = d.join("keep.txt");
        write_atomic(&p, b"old").unwrap();
        let e = write_atomic_with(&p, |w| {
            w.write_all(b"partial")?;
            Err(io::Error::other("disk full"))
        })
        .unwrap_err()
        .to_string();
        assert!(e.contains("keep.txt") && e.contains("disk full"), "{e}");
        assert_eq!(fs::read_to_string(&p).unwrap(), "old");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1);
        // A folder that cannot exist (its parent is a file).
        let e = write_atomic(&p.join("x.txt"), b"x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("keep.txt/x.txt"), "{e}");
        // A folder in the way.
        let e = write_atomic(&d, b"x").unwrap_err().to_string();
        assert!(e.contains("is a folder"), "{e}");
    }

    #[test]
    fn a_device_is_refused_and_a_link_is_written_through() {
        let null = Path::new("/dev/null");
        if null.exists() {
            let e = write_atomic(null, b"x").unwrap_err().to_string();
            assert!(e.contains("/dev/null: not a regular file"), "{e}");
            assert!(!fs::metadata(null).unwrap().is_file(), "/dev/null replaced");
        }
        #[cfg(unix)]
        {
            let d = dir("link");
            let target = d.join("target.csv");
            let link = d.join("link.csv");
            fs::write(&target, "old").unwrap();
            let _ = fs::remove_file(&link);
            std::os::unix::fs::symlink(&target, &link).unwrap();
            write_atomic(&link, b"new").unwrap();
            assert!(fs::symlink_metadata(&link)
                .unwrap()
                .file_type()
                .is_symlink());
            assert_eq!(fs::read_to_string(&target).unwrap(), "new");
        }
    }

    #[test]
    fn the_longest_valid_name_is_written() {
        let d = dir("long-name");
        let name = format!("{}.csv", "n".repeat(251)); // 255 bytes, most systems' limit
        write_atomic(&d.join(&name), b"x").unwrap();
        assert_eq!(fs::read_to_string(d.join(&name)).unwrap(), "x");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1, "no temporary left");
    }

    #[test]
    fn an_output_that_is_an_input_is_refused_by_both_names() {
        let d = dir("inputs");
        let input = d.join("in.csv");
        fs::write(&input, "x").unwrap();
        let alias = d.join(".").join("in.csv");
        let e = not_an_input("--out", &alias, &[("--drive", &input)])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--out") && e.contains("--drive") && e.contains("in.csv"),
            "{e}"
        );
        assert!(not_an_input("--out", &d.join("new.csv"), &[("--drive", &input)]).is_ok());
        let e = folder_spares_inputs("--out", &d, &[("--runs", &input)], |n| n.ends_with(".csv"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("--runs"), "{e}");
    }

    #[test]
    fn outputs_are_checked_by_option_and_leave_nothing_behind() {
        let d = dir("check-outputs");
        let file = d.join("a-file");
        fs::write(&file, "x").unwrap();
        let under = file.join("model.toml");
        let e = check_outputs(&[("--out", &under)], &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("--out ") && e.contains("a-file/model.toml") && e.contains("is a file"),
            "{e}"
        );
        let e = check_outputs(&[("--out", &d)], &[])
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("--out ") && e.contains("is a folder"), "{e}");
        let out = d.join("out.csv");
        let e = check_outputs(&[("--out", &out), ("--frf-out", &out)], &[])
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("--frf-out") && e.contains("is also --out"),
            "{e}"
        );
        let e = check_outputs(&[("--out", &file)], &[("the model", &file)])
            .unwrap_err()
            .to_string();
        assert!(e.contains("the model"), "{e}");
        check_outputs(&[("--out", &out)], &[("the model", &file)]).unwrap();
        assert!(!out.exists(), "the check leaves no file");
        assert_eq!(fs::read_dir(&d).unwrap().count(), 1, "no temporary left");
    }
}
