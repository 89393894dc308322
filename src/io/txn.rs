//! Transactional output directories: a run's files appear in `--out` all together, or not
//! at all.
//!
//! Atomic files alone ([`crate::io::atomic`]) keep each file whole, but a result is a *set*
//! of files that refer to each other (surface.obj names surface.mtl, which names
//! atlas.png; report.json describes facemaps.exr): a failure between two of them (a full
//! disk at surface.obj, a directory named `surface.obj` in the way, a signal) used to leave
//! a mixed or half set. [`OutputTxn`] makes the set the unit:
//!
//! 1. [`OutputTxn::begin`] checks `--out` (a regular file, a dangling symbolic link, an
//!    unwritable place, a directory where an output file goes are errors *before* any
//!    work) and creates a hidden **staging folder on the same file system**: inside `--out`
//!    when it exists (`--out/.surfsynth-staging-PID`), else beside it
//!    (`PARENT/.NAME.surfsynth-staging-PID`), creating missing parents (which are removed
//!    again if the run fails).
//! 2. Writers write the whole result into [`OutputTxn::dir`], each file atomically; the
//!    fsyncs run in the background (`crate::io::atomic::defer_syncs_in`) and the commit
//!    waits for them first.
//! 3. [`OutputTxn::commit`] moves them into place. A new `--out` is the staging folder
//!    renamed (one atomic step). An existing one is swapped file by file, with the previous
//!    files kept in the staging folder (hard links, so a reader never sees a file missing)
//!    until every new file is in place; outputs of an earlier run that this run does not
//!    write again (a stale displaced.glb) are retired with them. Any failure, or SIGINT /
//!    SIGTERM ([`crate::io::interrupt`]), before the end rolls every step back.
//! 4. Dropping an uncommitted transaction (an error anywhere, a panic unwinding) removes
//!    the staging folder and the parents it created: `--out` is exactly as before.
//!
//! Files in `--out` that are not outputs of the tool are never touched.

use crate::error::{Error, Result};
use crate::io::interrupt::{self, Registered};
use std::fs;
use std::io::ErrorKind;
use std::path::{Path, PathBuf};

/// Every file `synth` can write (a new run retires those it does not write again).
pub const SYNTH_OUTPUTS: &[&str] = &[
    "facemaps.exr",
    "geometry.exr",
    "facemaps.ptx",
    "surface.obj",
    "surface.mtl",
    "atlas.png",
    // The atlases of the usual maps of a material (any other `atlas_NAME.png` is written
    // too; these are also retired when a later run does not write them again).
    "atlas_normal.png",
    "atlas_roughness.png",
    "atlas_metallic.png",
    "atlas_height.png",
    "atlas_ao.png",
    "atlas_occlusion.png",
    "surface.glb",
    "displaced.glb",
    "report.json",
];

/// What `bake` writes.
pub const BAKE_OUTPUTS: &[&str] = &["geometry.exr"];

/// Name of the folder inside the staging folder that holds the previous files during a
/// commit.
const PREVIOUS: &str = ".previous";

/// An output directory being written (see the module docs).
#[derive(Debug)]
pub struct OutputTxn {
    target: PathBuf,
    staging: PathBuf,
    /// `--out` did not exist: the staging folder becomes it.
    fresh: bool,
    /// Outputs of the tool in `--out` that the commit may replace or retire.
    outputs: Vec<String>,
    /// Parents of `--out` this transaction created, deepest last.
    created: Vec<PathBuf>,
    _staging_reg: Option<Registered>,
    _created_reg: Vec<Registered>,
    done: bool,
}

fn is_dangling_symlink(p: &Path) -> Option<PathBuf> {
    let lm = fs::symlink_metadata(p).ok()?;
    if lm.file_type().is_symlink() && fs::metadata(p).is_err() {
        Some(fs::read_link(p).unwrap_or_default())
    } else {
        None
    }
}

/// The path with `staging` replaced by `target` in an error message (writers name the
/// staged file; users know the final one).
fn rename_in_message(e: Error, staging: &Path, target: &Path) -> Error {
    match e {
        Error::File { path, problem } => {
            let path = match path.strip_prefix(staging) {
                Ok(rest) => target.join(rest),
                Err(_) => path,
            };
            Error::File { path, problem }
        }
        Error::Invalid(m) => Error::Invalid(m.replace(
            &staging.display().to_string(),
            &target.display().to_string(),
        )),
        other => other,
    }
}

impl OutputTxn {
    /// Checks `target` and creates the staging folder. `outputs` are the file names the
    /// tool may write there (e.g. [`SYNTH_OUTPUTS`]): one that exists as anything but a
    /// file (a directory named `surface.obj`) is an error now, before any work.
    pub fn begin(target: impl AsRef<Path>, outputs: &[&str]) -> Result<Self> {
        let target = target.as_ref().to_path_buf();
        if target.as_os_str().is_empty() {
            return Err(Error::invalid("the output directory (--out) is empty"));
        }
        if let Some(to) = is_dangling_symlink(&target) {
            return Err(Error::file(
                &target,
                format!(
                    "is a symbolic link to {}, which does not exist; create that directory or choose another --out",
                    to.display()
                ),
            ));
        }
        let fresh = match fs::metadata(&target) {
            Ok(m) if m.is_dir() => false,
            Ok(_) => {
                return Err(Error::file(
                    &target,
                    "is an existing file; the output path (--out) must be a directory",
                ))
            }
            Err(e) if e.kind() == ErrorKind::NotFound => true,
            Err(e) => return Err(Error::io(&target, "cannot access output directory", e)),
        };
        let mut txn = OutputTxn {
            target: target.clone(),
            staging: PathBuf::new(),
            fresh,
            outputs: outputs.iter().map(|s| s.to_string()).collect(),
            created: Vec::new(),
            _staging_reg: None,
            _created_reg: Vec::new(),
            done: false,
        };
        let pid = std::process::id();
        if fresh {
            let name = target
                .file_name()
                .ok_or_else(|| Error::file(&target, "output path has no directory name"))?
                .to_string_lossy()
                .into_owned();
            let parent = match target.parent() {
                Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
                _ => PathBuf::from("."),
            };
            txn.create_parents(&parent)?;
            txn.staging = parent.join(format!(".{name}.surfsynth-staging-{pid}"));
        } else {
            txn.check_in_the_way()?;
            txn.staging = target.join(format!(".surfsynth-staging-{pid}"));
        }
        // A leftover of a killed run with the same PID: ours to replace.
        let _ = fs::remove_dir_all(&txn.staging);
        txn._staging_reg = Some(interrupt::register_staging(&txn.staging, &target));
        if let Err(e) = fs::create_dir(&txn.staging) {
            let what = if fresh {
                "cannot create output directory"
            } else {
                "output directory is not writable"
            };
            return Err(Error::io(&target, what, e));
        }
        crate::io::atomic::defer_syncs_in(&txn.staging);
        Ok(txn)
    }

    /// Creates the missing ancestors of `dir` (and `dir`), remembering them for removal.
    fn create_parents(&mut self, dir: &Path) -> Result<()> {
        let mut missing = Vec::new();
        let mut p = dir.to_path_buf();
        loop {
            match fs::metadata(&p) {
                Ok(m) if m.is_dir() => break,
                Ok(_) => {
                    return Err(Error::io(
                        &self.target,
                        "cannot access output directory",
                        std::io::Error::from_raw_os_error(20), // ENOTDIR
                    ));
                }
                Err(e) if e.kind() == ErrorKind::NotFound => {
                    if let Some(to) = is_dangling_symlink(&p) {
                        return Err(Error::file(
                            &p,
                            format!(
                                "is a symbolic link to {}, which does not exist",
                                to.display()
                            ),
                        ));
                    }
                    missing.push(p.clone());
                    match p.parent() {
                        Some(q) if !q.as_os_str().is_empty() => p = q.to_path_buf(),
                        _ => break,
                    }
                }
                Err(e) => return Err(Error::io(&self.target, "cannot access output directory", e)),
            }
        }
        for d in missing.into_iter().rev() {
            self._created_reg.push(interrupt::register_empty_dir(&d));
            match fs::create_dir(&d) {
                Ok(()) => self.created.push(d),
                Err(e) if e.kind() == ErrorKind::AlreadyExists => {}
                Err(e) => return Err(Error::io(&self.target, "cannot create output directory", e)),
            }
        }
        Ok(())
    }

    /// An output name that exists in `--out` as something other than a file or a symbolic
    /// link (which a rename replaces) is in the way.
    fn check_in_the_way(&self) -> Result<()> {
        for name in &self.outputs {
            let p = self.target.join(name);
            if let Ok(m) = fs::symlink_metadata(&p) {
                if !(m.file_type().is_file() || m.file_type().is_symlink()) {
                    let kind = if m.is_dir() {
                        "a directory"
                    } else {
                        "not a regular file"
                    };
                    return Err(Error::file(
                        &p,
                        format!("is {kind}, in the way of the output file {name}; move it out of the output directory"),
                    ));
                }
            }
        }
        Ok(())
    }

    /// The folder to write the result into.
    pub fn dir(&self) -> &Path {
        &self.staging
    }

    /// The output directory.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// `e` with staged paths replaced by their final ones (for messages).
    pub fn explain(&self, e: Error) -> Error {
        rename_in_message(e, &self.staging, &self.target)
    }

    /// Moves the staged files into place (see the module docs). Nothing in `--out` changes
    /// if this fails or the process is interrupted before it returns.
    pub fn commit(mut self) -> Result<()> {
        let _lock = interrupt::commit_lock();
        if let Some(sig) = interrupt::interrupted() {
            return Err(Error::invalid(format!("interrupted by signal {sig}")));
        }
        // Every staged file durable (their fsyncs ran in the background), and their names.
        crate::io::atomic::finish_syncs_in(&self.staging).map_err(|e| self.explain(e))?;
        sync_dir(&self.staging);
        let mut staged: Vec<String> = Vec::new();
        let rd = fs::read_dir(&self.staging)
            .map_err(|e| Error::io(&self.target, "cannot read the staged output", e))?;
        for e in rd {
            let e = e.map_err(|e| Error::io(&self.target, "cannot read the staged output", e))?;
            let name = e.file_name().to_string_lossy().into_owned();
            if !name.starts_with('.') {
                staged.push(name);
            }
        }
        staged.sort();
        if self.fresh {
            return self.commit_fresh();
        }
        self.check_in_the_way()?;
        let previous = self.staging.join(PREVIOUS);
        fs::create_dir(&previous)
            .map_err(|e| Error::io(&self.target, "cannot prepare the commit", e))?;
        // Steps done so far, undone in reverse on failure.
        enum Step {
            /// The old file is also at previous/name (hard link); the target may have been
            /// replaced by the new file.
            Linked(String, bool),
            /// The old file was moved to previous/name.
            Moved(String),
            /// A new file was moved into an empty place.
            Placed(String),
        }
        let mut steps: Vec<Step> = Vec::new();
        let result = (|| -> Result<()> {
            let check = || match interrupt::interrupted() {
                Some(sig) => Err(Error::invalid(format!("interrupted by signal {sig}"))),
                None => Ok(()),
            };
            for name in &staged {
                check()?;
                let (new, dst, old) = (
                    self.staging.join(name),
                    self.target.join(name),
                    previous.join(name),
                );
                if fs::symlink_metadata(&dst).is_ok() {
                    if fs::hard_link(&dst, &old).is_ok() {
                        steps.push(Step::Linked(name.clone(), false));
                        fs::rename(&new, &dst)
                            .map_err(|e| Error::io(&dst, "cannot move into place", e))?;
                        if let Some(Step::Linked(_, replaced)) = steps.last_mut() {
                            *replaced = true;
                        }
                    } else {
                        // No hard links on this file system: move the old one aside.
                        fs::rename(&dst, &old).map_err(|e| {
                            Error::io(&dst, "cannot move the previous file aside", e)
                        })?;
                        steps.push(Step::Moved(name.clone()));
                        fs::rename(&new, &dst)
                            .map_err(|e| Error::io(&dst, "cannot move into place", e))?;
                        steps.push(Step::Placed(name.clone()));
                    }
                } else {
                    fs::rename(&new, &dst)
                        .map_err(|e| Error::io(&dst, "cannot move into place", e))?;
                    steps.push(Step::Placed(name.clone()));
                }
            }
            // Outputs of an earlier run that this one did not write: retired with the rest.
            for name in &self.outputs {
                if staged.contains(name) {
                    continue;
                }
                check()?;
                let dst = self.target.join(name);
                if fs::symlink_metadata(&dst).is_ok() {
                    fs::rename(&dst, previous.join(name))
                        .map_err(|e| Error::io(&dst, "cannot retire the previous file", e))?;
                    steps.push(Step::Moved(name.clone()));
                }
            }
            check()?;
            sync_dir(&self.target);
            Ok(())
        })();
        if let Err(e) = result {
            // Undo, newest step first.
            for step in steps.into_iter().rev() {
                match step {
                    Step::Linked(name, replaced) => {
                        if replaced {
                            let _ = fs::rename(previous.join(&name), self.target.join(&name));
                        }
                    }
                    Step::Moved(name) => {
                        let _ = fs::rename(previous.join(&name), self.target.join(&name));
                    }
                    Step::Placed(name) => {
                        let _ = fs::remove_file(self.target.join(&name));
                    }
                }
            }
            sync_dir(&self.target);
            return Err(e);
        }
        // Point of no return: the new set is in place.
        self.done = true;
        let _ = fs::remove_dir_all(&self.staging);
        self._staging_reg = None;
        self._created_reg.clear();
        Ok(())
    }

    fn commit_fresh(&mut self) -> Result<()> {
        // rename(2) onto a path that appeared meanwhile as an empty directory replaces it;
        // onto anything else it fails, and the staging folder is removed on drop.
        fs::rename(&self.staging, &self.target)
            .map_err(|e| Error::io(&self.target, "cannot move the result into place", e))?;
        self.done = true;
        if let Some(parent) = self.target.parent() {
            sync_dir(if parent.as_os_str().is_empty() {
                Path::new(".")
            } else {
                parent
            });
        }
        self._staging_reg = None;
        self._created_reg.clear();
        Ok(())
    }
}

impl Drop for OutputTxn {
    fn drop(&mut self) {
        if !self.staging.as_os_str().is_empty() {
            crate::io::atomic::stop_deferring(&self.staging);
        }
        if self.done {
            return;
        }
        if !self.staging.as_os_str().is_empty() {
            let _ = fs::remove_dir_all(&self.staging);
        }
        for d in self.created.iter().rev() {
            let _ = fs::remove_dir(d);
        }
    }
}

/// Persists directory entries (best effort: not every file system can sync a directory).
fn sync_dir(dir: &Path) {
    if let Ok(d) = fs::File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .map(|rd| {
                rd.map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                    .collect()
            })
            .unwrap_or_default();
        v.sort();
        v
    }

    #[test]
    fn fresh_directory_appears_whole_or_not_at_all() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path().join("a/b/out");
        let t = OutputTxn::begin(&out, SYNTH_OUTPUTS).unwrap();
        fs::write(t.dir().join("report.json"), b"{}").unwrap();
        assert!(!out.exists());
        drop(t);
        assert!(names(d.path()).is_empty(), "created parents removed too");
        let t = OutputTxn::begin(&out, SYNTH_OUTPUTS).unwrap();
        fs::write(t.dir().join("report.json"), b"{}").unwrap();
        t.commit().unwrap();
        assert_eq!(names(&out), vec!["report.json"]);
    }

    #[test]
    fn existing_directory_is_swapped_and_foreign_files_kept() {
        let d = tempfile::tempdir().unwrap();
        let out = d.path();
        fs::write(out.join("notes.txt"), b"mine").unwrap();
        fs::write(out.join("report.json"), b"old").unwrap();
        fs::write(out.join("displaced.glb"), b"stale").unwrap();
        let t = OutputTxn::begin(out, SYNTH_OUTPUTS).unwrap();
        fs::write(t.dir().join("report.json"), b"new").unwrap();
        fs::write(t.dir().join("facemaps.exr"), b"new").unwrap();
        // Not committed: nothing changes.
        drop(t);
        assert_eq!(
            names(out),
            vec!["displaced.glb", "notes.txt", "report.json"]
        );
        assert_eq!(fs::read(out.join("report.json")).unwrap(), b"old");
        let t = OutputTxn::begin(out, SYNTH_OUTPUTS).unwrap();
        fs::write(t.dir().join("report.json"), b"new").unwrap();
        fs::write(t.dir().join("facemaps.exr"), b"new").unwrap();
        t.commit().unwrap();
        assert_eq!(names(out), vec!["facemaps.exr", "notes.txt", "report.json"]);
        assert_eq!(fs::read(out.join("report.json")).unwrap(), b"new");
        assert_eq!(fs::read(out.join("notes.txt")).unwrap(), b"mine");
    }

    #[test]
    fn in_the_way_and_bad_targets_are_refused_before_anything() {
        let d = tempfile::tempdir().unwrap();
        fs::create_dir(d.path().join("surface.obj")).unwrap();
        let e = OutputTxn::begin(d.path(), SYNTH_OUTPUTS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("surface.obj: is a directory, in the way"), "{e}");
        assert_eq!(names(d.path()), vec!["surface.obj"]);
        let link = d.path().join("link");
        std::os::unix::fs::symlink(d.path().join("nowhere/x"), &link).unwrap();
        let e = OutputTxn::begin(&link, SYNTH_OUTPUTS)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("symbolic link") && e.contains("does not exist"),
            "{e}"
        );
        let file = d.path().join("f");
        fs::write(&file, b"").unwrap();
        let e = OutputTxn::begin(&file, SYNTH_OUTPUTS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("must be a directory"), "{e}");
        let e = OutputTxn::begin(file.join("below"), SYNTH_OUTPUTS)
            .unwrap_err()
            .to_string();
        assert!(e.contains("Not a directory"), "{e}");
    }

    #[test]
    fn messages_name_the_final_path() {
        let d = tempfile::tempdir().unwrap();
        let t = OutputTxn::begin(d.path().join("o"), SYNTH_OUTPUTS).unwrap();
        let e = t.explain(Error::file(
            t.dir().join("surface.obj"),
            "cannot write: full",
        ));
        assert_eq!(
            e.to_string(),
            format!(
                "{}: cannot write: full",
                d.path().join("o/surface.obj").display()
            )
        );
    }
}
