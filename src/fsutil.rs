//! Safe file output.
//!
//! * Atomic files: write to a temporary sibling `.NAME.tmp-PID`, then rename into place. A
//!   failed or interrupted write never leaves a half-written file under the final name.
//! * Staged output directories ([`StagedDir`]): a run writes into `.NAME.tmp-PID` beside its
//!   output directory and swaps it into place at the end. It replaces only a directory that
//!   terratile wrote (it holds the [`MARKER`] file), an empty one, or none; never one that
//!   holds an input, the pipeline file, the pipeline's own directory or the current
//!   directory. A lock file `.NAME.lock` keeps two runs out of one directory. On Linux the
//!   swap is one `renameat2(RENAME_EXCHANGE)`, so a kill at any moment leaves either the old
//!   or the new output; elsewhere it is two renames.
//! * Cleanup: every temporary this process creates is registered, so that SIGINT/SIGTERM
//!   ([`clean_up_on_signals`]) removes exactly those, and a later run removes the staging
//!   that a dead process left ([`remove_stale_temps`]).

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard};

/// The file that marks a directory as terratile's output: a run may replace a directory that
/// holds it (with everything in it).
pub const MARKER: &str = ".terratile";

const MARKER_TEXT: &str = "This directory was written by terratile. The next run into it \
replaces it whole, with everything in it.\n";

/// Temporaries this process created and has not yet renamed into place or removed: what the
/// signal handler removes.
static CREATED: Mutex<Vec<PathBuf>> = Mutex::new(Vec::new());

fn created() -> MutexGuard<'static, Vec<PathBuf>> {
    CREATED.lock().unwrap_or_else(|p| p.into_inner())
}

pub(crate) fn register(path: &Path) {
    created().push(path.to_path_buf());
}

pub(crate) fn unregister(path: &Path) {
    created().retain(|p| p != path);
}

/// Set by the signal handler before it removes the temporaries: a thread that is about to
/// create a file from then on waits for the process to exit instead.
static STOPPING: AtomicBool = AtomicBool::new(false);

/// Threads between starting to create a file and finishing it (renamed into place, or a
/// brick's append done): the signal handler waits for them before it removes what they
/// write, so that no file is created after its last pass over the directories (a run
/// interrupted while shards were spilled left a `prepared-I.bin` behind that way).
static CREATING: AtomicUsize = AtomicUsize::new(0);

/// Held while a file this process may have to remove on a signal is created and written.
pub(crate) struct Creating(());

/// Marks the calling thread as creating a file until the guard drops. Once the signal
/// handler has started, it never returns: the handler exits the process.
pub(crate) fn creating() -> Creating {
    CREATING.fetch_add(1, Ordering::SeqCst);
    if STOPPING.load(Ordering::SeqCst) {
        CREATING.fetch_sub(1, Ordering::SeqCst);
        loop {
            std::thread::park();
        }
    }
    Creating(())
}

impl Drop for Creating {
    fn drop(&mut self) {
        CREATING.fetch_sub(1, Ordering::SeqCst);
    }
}

/// Stops new file creation and waits (at most `limit`) for the files being created to be
/// finished, so that the removal that follows sees all of them.
fn stop_creating(limit: std::time::Duration) {
    STOPPING.store(true, Ordering::SeqCst);
    let t = std::time::Instant::now();
    while CREATING.load(Ordering::SeqCst) > 0 && t.elapsed() < limit {
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
}

/// A working directory kept across runs (resumable), of which this process owns only the
/// files whose names `ours` accepts: what the signal handler removes of it.
type OwnedFiles = (PathBuf, fn(&str) -> bool);

static WORK_DIRS: Mutex<Vec<OwnedFiles>> = Mutex::new(Vec::new());

fn work_dirs() -> MutexGuard<'static, Vec<OwnedFiles>> {
    WORK_DIRS.lock().unwrap_or_else(|p| p.into_inner())
}

/// Registers `dir` as a working directory whose files named as `ours` accepts are this
/// process's: on SIGINT/SIGTERM those files are removed, then `dir` if nothing else is left
/// in it (a file someone else put there is never touched).
pub(crate) fn register_work_dir(dir: &Path, ours: fn(&str) -> bool) {
    work_dirs().push((dir.to_path_buf(), ours));
}

pub(crate) fn unregister_work_dir(dir: &Path) {
    work_dirs().retain(|(p, _)| p != dir);
}

/// Removes the files of `dir` that `ours` accepts, then `dir` if it is left empty. Like
/// [`remove_tree`], it goes over the directory again while other threads still writing
/// create files in it (a few passes; the next run removes the rest).
pub(crate) fn remove_owned_files(dir: &Path, ours: fn(&str) -> bool) {
    for _ in 0..8 {
        let Ok(rd) = std::fs::read_dir(dir) else {
            return;
        };
        let mut removed = false;
        for e in rd.flatten() {
            if ours(&e.file_name().to_string_lossy()) {
                removed |= std::fs::remove_file(e.path()).is_ok();
            }
        }
        if std::fs::remove_dir(dir).is_ok() || !removed {
            return;
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
}

/// Removes `path` (file or directory tree) and what was created in it meanwhile by other
/// threads still writing; gives up after a few tries (the next run removes the rest).
fn remove_tree(path: &Path) {
    for _ in 0..8 {
        match std::fs::symlink_metadata(path) {
            Err(_) => return,
            Ok(m) if m.is_dir() => {
                let _ = std::fs::remove_dir_all(path);
            }
            Ok(_) => {
                let _ = std::fs::remove_file(path);
            }
        }
    }
}

/// Removes every temporary this process has registered and not yet finished.
pub fn remove_created() {
    let mut list = created();
    for p in list.drain(..) {
        remove_tree(&p);
    }
    for (dir, ours) in work_dirs().drain(..) {
        remove_owned_files(&dir, ours);
    }
}

/// Installs handlers for SIGINT and SIGTERM that remove this process's temporaries (staging
/// directories, `.tmp-PID` files, its lock file: only what this process created) and exit
/// with the conventional 128 + signal (130, 143). For the command-line tool; a library user
/// keeps the default behaviour unless it calls this. A no-op where signals do not exist.
pub fn clean_up_on_signals() -> Result<()> {
    #[cfg(unix)]
    {
        use signal_hook::consts::{SIGINT, SIGTERM};
        let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM])
            .map_err(|e| Error::Internal(format!("installing signal handlers: {e}")))?;
        std::thread::Builder::new()
            .name("signals".into())
            .spawn(move || {
                if let Some(sig) = signals.forever().next() {
                    // A file being written is finished first (bounded: a thread stuck in
                    // a write must not keep the process from exiting).
                    stop_creating(std::time::Duration::from_secs(10));
                    remove_created();
                    let name = if sig == SIGINT { "SIGINT" } else { "SIGTERM" };
                    eprintln!("terratile: interrupted by {name}; its temporary files are removed");
                    std::process::exit(128 + sig);
                }
            })
            .map_err(|e| Error::Internal(format!("starting the signal thread: {e}")))?;
    }
    Ok(())
}

/// A temporary sibling of `path` (same directory, so the rename stays on one file system).
pub fn temp_sibling(path: &Path) -> PathBuf {
    sibling(path, "tmp", std::process::id())
}

fn file_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into())
}

/// `.NAME.KIND-PID` beside `path`.
fn sibling(path: &Path, kind: &str, pid: u32) -> PathBuf {
    path.with_file_name(format!(".{}.{kind}-{pid}", file_name(path)))
}

/// Creates `path` by running `write` on a buffered temporary file, then renaming it.
pub fn write_atomic(
    path: &Path,
    write: impl FnOnce(&mut BufWriter<File>) -> Result<()>,
) -> Result<()> {
    let _creating = creating();
    let tmp = temp_sibling(path);
    register(&tmp);
    let result = (|| {
        let file = File::create(&tmp).map_err(|e| Error::io(path, e))?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        write(&mut w)?;
        w.flush().map_err(|e| Error::io(path, e))?;
        drop(w);
        std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    unregister(&tmp);
    result
}

/// Writes `bytes` to `path` atomically.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic(path, |w| w.write_all(bytes).map_err(|e| Error::io(path, e)))
}

/// Refuses a single-file output (`convert`, `simplify`, `strips`, `generate`) that would
/// destroy a file terratile did not write: one of the command's `inputs` (by name or as the
/// same file), a symbolic link (the rename would replace the link), a directory or anything
/// else that is not a regular file, or a regular file without terratile's signature (see
/// [`written_by_terratile`]). A file terratile wrote is replaced atomically, so rerunning a
/// command into the same name works. The error is one line naming the output.
pub fn check_file_output(output: &Path, inputs: &[&Path]) -> Result<()> {
    let refuse = |why: String| Err(Error::Usage(format!("{}: {why}", output.display())));
    for input in inputs {
        let same = *input == output
            || matches!(
                (input.canonicalize(), output.canonicalize()),
                (Ok(a), Ok(b)) if a == b
            );
        if same {
            return refuse(format!(
                "the output is the input file {}; choose another name",
                input.display()
            ));
        }
    }
    let Ok(meta) = output.symlink_metadata() else {
        return Ok(());
    };
    if meta.file_type().is_symlink() {
        return refuse(
            "is a symbolic link; terratile does not replace it (name the file itself, or \
             another name)"
                .into(),
        );
    }
    if !meta.is_file() {
        return refuse(not_a_regular_file(output).unwrap_or_else(|| "is not a file".into()));
    }
    if !written_by_terratile(output) {
        return refuse(
            "already exists and terratile did not write it; remove it yourself or choose \
             another name"
                .into(),
        );
    }
    Ok(())
}

/// True when the file at `path` starts the way terratile writes its single-file outputs:
/// LAS with generating software `terratile …` (header bytes 58–89), OBJ whose first line is
/// `# terratile …`, PLY with the header comment `written by terratile`, a progressive-strips
/// stream (magic `TTPS`), binary glTF whose JSON names terratile as its generator, or text
/// whose first line is `# terratile` (generated XYZ). Only the first 64 KiB are read.
pub fn written_by_terratile(path: &Path) -> bool {
    let mut head = Vec::new();
    let Ok(file) = File::open(path) else {
        return false;
    };
    if file.take(1 << 16).read_to_end(&mut head).is_err() {
        return false;
    }
    let starts = |magic: &[u8]| head.starts_with(magic);
    if starts(b"LASF") {
        return head.get(58..67) == Some(b"terratile".as_slice());
    }
    if starts(b"ply") {
        let end = find(&head, b"end_header").unwrap_or(head.len());
        return find(&head[..end], b"\ncomment written by terratile").is_some();
    }
    if starts(b"glTF") {
        // The JSON chunk: its length at bytes 12–15, its text from byte 20.
        let len = head
            .get(12..16)
            .map_or(0, |b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize);
        let json = head.get(20..).unwrap_or_default();
        let json = &json[..json.len().min(len)];
        return find(json, b"\"generator\":\"terratile").is_some();
    }
    starts(b"TTPS") || starts(b"# terratile")
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// True unless `pid` is known to be gone. Where that cannot be told, every process counts as
/// alive, so nothing is removed.
fn alive(pid: u32) -> bool {
    #[cfg(unix)]
    {
        let Some(p) = i32::try_from(pid)
            .ok()
            .and_then(rustix::process::Pid::from_raw)
        else {
            return true;
        };
        !matches!(
            rustix::process::test_kill_process(p),
            Err(rustix::io::Errno::SRCH)
        )
    }
    #[cfg(not(unix))]
    {
        let _ = pid;
        true
    }
}

/// The PID of a name `.NAME.tmp-PID` or `.NAME.old-PID` (exactly our pattern for `target`),
/// else None.
fn temp_pid(entry: &str, target_name: &str) -> Option<u32> {
    let rest = entry.strip_prefix('.')?.strip_prefix(target_name)?;
    let digits = rest
        .strip_prefix(".tmp-")
        .or_else(|| rest.strip_prefix(".old-"))?;
    if digits.is_empty() || digits.len() > 10 || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    digits.parse().ok()
}

/// Removes the temporaries of `target` that dead processes left beside it: only entries
/// named exactly `.NAME.tmp-PID` or `.NAME.old-PID` (NAME = `target`'s file name) whose PID
/// is not a running process, files or directories, never symbolic links. Returns how many.
pub fn remove_stale_temps(target: &Path) -> usize {
    let Some(name) = target.file_name().and_then(|n| n.to_str()) else {
        return 0;
    };
    let parent = parent_of(target);
    let Ok(entries) = std::fs::read_dir(parent) else {
        return 0;
    };
    let me = std::process::id();
    let mut removed = 0;
    for e in entries.flatten() {
        let Some(pid) = e.file_name().to_str().and_then(|n| temp_pid(n, name)) else {
            continue;
        };
        if pid == me || alive(pid) {
            continue;
        }
        let Ok(t) = e.file_type() else { continue };
        let path = e.path();
        // A kill between the two renames of the fallback swap left the old output here and
        // none at the target: put it back rather than remove the only copy.
        if t.is_dir() && e.file_name().to_string_lossy().contains(".old-") && !target.exists() {
            removed += usize::from(std::fs::rename(&path, target).is_ok());
            continue;
        }
        let gone = if t.is_dir() {
            std::fs::remove_dir_all(&path).is_ok()
        } else if t.is_file() {
            std::fs::remove_file(&path).is_ok()
        } else {
            false
        };
        removed += usize::from(gone);
    }
    removed
}

/// `path` with `.` dropped and `name/..` folded, without touching the file system: for
/// showing paths (`pipes/../runs/out` is shown as `runs/out`). A leading `..` stays.
pub fn normalize_lexically(path: &Path) -> PathBuf {
    let mut out: Vec<Component> = Vec::new();
    for c in path.components() {
        match c {
            Component::CurDir => {}
            Component::ParentDir => match out.last() {
                Some(Component::Normal(_)) => {
                    out.pop();
                }
                Some(Component::RootDir | Component::Prefix(_)) => {}
                _ => out.push(c),
            },
            c => out.push(c),
        }
    }
    if out.is_empty() {
        return PathBuf::from(".");
    }
    out.iter().collect()
}

fn parent_of(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// `path` made absolute with every existing part resolved (symbolic links, `..`); the part
/// that does not exist yet is appended as written, with `.` and `..` folded (it holds no
/// links to follow).
fn resolve(path: &Path) -> std::io::Result<PathBuf> {
    let mut rest = Vec::new();
    let mut p = path;
    loop {
        if p.as_os_str().is_empty() {
            p = Path::new(".");
        }
        match std::fs::canonicalize(p) {
            Ok(mut abs) => {
                for c in rest.iter().rev() {
                    match c {
                        Component::ParentDir => {
                            abs.pop();
                        }
                        Component::Normal(n) => abs.push(n),
                        _ => {}
                    }
                }
                return Ok(abs);
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let Some(last) = p.components().next_back() else {
                    return Err(e);
                };
                rest.push(last);
                p = match p.parent() {
                    Some(parent) => parent,
                    None => return Err(e),
                };
            }
            Err(e) => return Err(e),
        }
    }
}

/// What must survive a run: paths that may not lie inside (or be) its output directory.
#[derive(Debug, Clone, Copy)]
pub struct Keep<'a> {
    /// What it is, for the message (`input file`, `pipeline file`, `asset input`).
    pub what: &'a str,
    /// The path.
    pub path: &'a Path,
}

/// An output directory built under a temporary name and swapped into place by
/// [`StagedDir::commit`]; dropped uncommitted, it is removed and the previous output stays.
#[derive(Debug)]
pub struct StagedDir {
    tmp: PathBuf,
    target: PathBuf,
    shown: PathBuf,
    lock: Option<OutputLock>,
    committed: bool,
}

/// What is at the output path now.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Existing {
    None,
    Empty,
    Marked,
}

fn refuse(shown: &Path, why: impl Into<String>) -> Error {
    Error::io(shown, std::io::Error::other(why.into()))
}

/// Whether terratile may replace `abs`, and what is there.
fn existing(abs: &Path, shown: &Path) -> Result<Existing> {
    let meta = match std::fs::symlink_metadata(abs) {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Existing::None),
        Err(e) => return Err(Error::io(shown, e)),
        Ok(m) => m,
    };
    if !meta.is_dir() {
        return Err(refuse(
            shown,
            "is a file, not a directory: the output directory cannot replace it",
        ));
    }
    let marker = std::fs::symlink_metadata(abs.join(MARKER)).is_ok_and(|m| m.is_file());
    if marker {
        return Ok(Existing::Marked);
    }
    let mut entries = std::fs::read_dir(abs).map_err(|e| Error::io(shown, e))?;
    if entries.next().is_none() {
        return Ok(Existing::Empty);
    }
    Err(refuse(
        shown,
        format!(
            "refusing to replace this directory: it holds files terratile did not write (no \
             {MARKER} marker); choose another output.dir, or empty or remove it yourself"
        ),
    ))
}

impl StagedDir {
    /// Starts staging `target`: refuses, before any work, a target that is not terratile's
    /// to replace (see the module documentation) or that contains any of `keep`, the
    /// current directory or `base` (the pipeline's directory); takes the lock; removes stale
    /// staging of dead runs; creates the staging directory with the marker in it.
    pub fn new(target: &Path, base: &Path, keep: &[Keep]) -> Result<StagedDir> {
        let shown = normalize_lexically(target);
        // A file in the way says more than the system's "File exists".
        if let Some(file) = target.ancestors().skip(1).find(|a| a.is_file()) {
            return Err(Error::io(
                file,
                std::io::Error::other(format!(
                    "is a file, so the output directory {} cannot be created",
                    shown.display()
                )),
            ));
        }
        let abs = resolve(target).map_err(|e| Error::io(&shown, e))?;
        if abs.parent().is_none() || abs.file_name().is_none() {
            return Err(refuse(
                &shown,
                "is the root directory: refusing to replace it",
            ));
        }
        let inside = |p: &Path| resolve(p).is_ok_and(|r| r.starts_with(&abs));
        if let Some(b) = resolve(base).ok().filter(|b| b.starts_with(&abs)) {
            let what = if b == abs {
                "is the pipeline file's own directory".to_string()
            } else {
                format!(
                    "contains the pipeline file's directory {}",
                    normalize_lexically(base).display()
                )
            };
            return Err(refuse(
                &shown,
                format!("{what}: refusing to replace it; name a subdirectory such as \"out\""),
            ));
        }
        if std::env::current_dir().is_ok_and(|cwd| inside(&cwd)) {
            return Err(refuse(
                &shown,
                "contains the current directory: refusing to replace it",
            ));
        }
        for k in keep {
            // Both the file as named (a link inside the output) and what it points to.
            let named = k
                .path
                .file_name()
                .and_then(|n| resolve(parent_of(k.path)).ok().map(|p| p.join(n)));
            if named.is_some_and(|n| n.starts_with(&abs)) || inside(k.path) {
                return Err(refuse(
                    &shown,
                    format!(
                        "holds the {} {}, which replacing it would delete: refusing; choose \
                         another output.dir",
                        k.what,
                        normalize_lexically(k.path).display()
                    ),
                ));
            }
        }
        let parent = parent_of(&abs).to_path_buf();
        std::fs::create_dir_all(&parent).map_err(|e| Error::io(&parent, e))?;
        let lock = OutputLock::take(&abs, &shown)?;
        existing(&abs, &shown)?;
        remove_stale_temps(&abs);
        let tmp = temp_sibling(&abs);
        let staged = StagedDir {
            tmp: tmp.clone(),
            target: abs,
            shown,
            lock: Some(lock),
            committed: false,
        };
        // Ours from an earlier process with the same PID (after a reboot): not a user's.
        remove_tree(&tmp);
        register(&tmp);
        std::fs::create_dir(&tmp).map_err(|e| Error::io(&staged.shown, e))?;
        std::fs::write(tmp.join(MARKER), MARKER_TEXT).map_err(|e| Error::io(&tmp, e))?;
        Ok(staged)
    }

    /// Where to write files now.
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The final directory (absolute, resolved).
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Replaces `target` with the staged directory in one step where the platform allows it,
    /// then removes the old tree. Returns the final directory.
    pub fn commit(mut self) -> Result<PathBuf> {
        let old = {
            // Held through the swap: a signal arriving now waits, then removes what is at
            // the staging name, which is either the new tree (before) or the old (after).
            let mut list = created();
            let before = existing(&self.target, &self.shown)?;
            let old = swap(&self.tmp, &self.target, before != Existing::None)
                .map_err(|e| Error::io(&self.shown, e))?;
            self.committed = true;
            list.retain(|p| p != &self.tmp);
            if let Some(o) = &old {
                list.push(o.clone());
            }
            old
        };
        if let Some(o) = old {
            remove_tree(&o);
            unregister(&o);
        }
        self.lock.take();
        Ok(self.target.clone())
    }
}

/// Moves `tmp` to `target`. With `replace`, the old `target` ends up at the returned path
/// for the caller to remove.
fn swap(tmp: &Path, target: &Path, replace: bool) -> std::io::Result<Option<PathBuf>> {
    #[cfg(any(target_os = "linux", target_os = "android"))]
    {
        use rustix::fs::{renameat_with, RenameFlags, CWD};
        let flags = if replace {
            RenameFlags::EXCHANGE
        } else {
            RenameFlags::NOREPLACE
        };
        match renameat_with(CWD, tmp, CWD, target, flags) {
            // After the exchange the old tree sits at the staging name.
            Ok(()) => return Ok(replace.then(|| tmp.to_path_buf())),
            // A file system without renameat2 flags: the two renames below.
            Err(rustix::io::Errno::INVAL | rustix::io::Errno::NOSYS) => {}
            Err(e) => return Err(e.into()),
        }
    }
    // Elsewhere: two renames. A kill between them leaves the old output at `.NAME.old-PID`
    // (removed by the next run once this process is gone) and none at `target`.
    if !replace {
        std::fs::rename(tmp, target)?;
        return Ok(None);
    }
    let old = sibling(target, "old", std::process::id());
    std::fs::rename(target, &old)?;
    if let Err(e) = std::fs::rename(tmp, target) {
        let _ = std::fs::rename(&old, target);
        return Err(e);
    }
    Ok(Some(old))
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            remove_tree(&self.tmp);
            unregister(&self.tmp);
        }
    }
}

/// The lock file `.NAME.lock` beside an output directory, locked (`flock` on Unix) while a
/// run writes it; removed when released (closing the file releases the lock).
#[derive(Debug)]
struct OutputLock {
    path: PathBuf,
    /// Held open for the lock: closing it releases the lock.
    _file: File,
}

impl OutputLock {
    fn take(target: &Path, shown: &Path) -> Result<OutputLock> {
        let path = target.with_file_name(format!(".{}.lock", file_name(target)));
        for _ in 0..16 {
            let mut file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(|e| Error::io(&path, e))?;
            match try_lock(&file) {
                Ok(true) => {}
                Ok(false) => {
                    let mut pid = String::new();
                    let _ = file.read_to_string(&mut pid);
                    let pid = pid.trim();
                    let who = if pid.is_empty() {
                        String::new()
                    } else {
                        format!(" (pid {pid})")
                    };
                    return Err(refuse(
                        shown,
                        format!(
                            "another terratile run{who} is writing this output directory; \
                             try again when it has finished"
                        ),
                    ));
                }
                Err(e) => return Err(Error::io(&path, e)),
            }
            // The holder before us may have removed the file after we opened it: then our
            // lock is on a deleted file, so start over with the file now at the path.
            if !same_file(&file, &path) {
                continue;
            }
            register(&path);
            let _ = file.set_len(0);
            let _ = write!(file, "{}", std::process::id());
            return Ok(OutputLock { path, _file: file });
        }
        Err(refuse(
            shown,
            "its lock file keeps changing: another terratile run is starting; try again",
        ))
    }
}

/// Takes an exclusive `flock` on `file` without waiting: false when another process holds it.
/// (std's `File::try_lock` needs Rust 1.89, past this crate's minimum version.)
#[cfg(unix)]
fn try_lock(file: &File) -> std::io::Result<bool> {
    use rustix::fs::{flock, FlockOperation};
    match flock(file, FlockOperation::NonBlockingLockExclusive) {
        Ok(()) => Ok(true),
        Err(rustix::io::Errno::WOULDBLOCK) => Ok(false),
        Err(e) => Err(e.into()),
    }
}

/// No lock where `flock` does not exist: concurrent runs are not kept apart there.
#[cfg(not(unix))]
fn try_lock(_file: &File) -> std::io::Result<bool> {
    Ok(true)
}

#[cfg(unix)]
fn same_file(file: &File, path: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (file.metadata(), std::fs::metadata(path)) {
        (Ok(a), Ok(b)) => a.dev() == b.dev() && a.ino() == b.ino(),
        _ => false,
    }
}

#[cfg(not(unix))]
fn same_file(_file: &File, path: &Path) -> bool {
    path.exists()
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, then unlocked: a waiter that opened the old file sees
        // that it changed (same_file) and starts over.
        // (The lock itself goes when `file` is closed, just after.)
        let _ = std::fs::remove_file(&self.path);
        unregister(&self.path);
    }
}

/// Why `path` cannot be read as a file ("does not exist", "is a directory", "is a FIFO
/// …"), or `None` for a regular file (symbolic links followed). Reading a FIFO or a device
/// would block or never end, and mapping one fails with an obscure system error.
pub fn not_a_regular_file(path: &Path) -> Option<String> {
    let meta = match std::fs::metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Some("does not exist".into()),
        Err(e) => return Some(format!("cannot be read: {e}")),
    };
    let t = meta.file_type();
    if t.is_file() {
        return None;
    }
    let kind = if t.is_dir() {
        "a directory"
    } else {
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if t.is_fifo() {
                "a FIFO (named pipe)"
            } else if t.is_char_device() || t.is_block_device() {
                "a device"
            } else if t.is_socket() {
                "a socket"
            } else {
                "something other than a file"
            }
        }
        #[cfg(not(unix))]
        {
            "something other than a file"
        }
    };
    Some(format!("is {kind}, not a regular file"))
}

/// A read-only memory map of `path` (the one place terratile uses `unsafe`).
pub fn map_file(path: &Path) -> Result<memmap2::Mmap> {
    // A missing file keeps the system's own message; anything else that is not a regular
    // file is refused before it is opened (opening a FIFO blocks).
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        if let Some(why) = not_a_regular_file(path) {
            return Err(Error::Usage(format!("{}: {why}", path.display())));
        }
    }
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    if len == 0 {
        return Err(Error::format(path, 0, "empty file"));
    }
    #[allow(unsafe_code)]
    // SAFETY: the map is read-only and private to this process. If another process truncates
    // the file while we read it, accesses past the new end raise SIGBUS; that is the accepted
    // contract of every memory-mapped reader (PDAL, LAStools) and documented in the README.
    let map = unsafe { memmap2::MmapOptions::new().map(&file) }.map_err(|e| Error::io(path, e))?;
    #[cfg(unix)]
    let _ = map.advise(memmap2::Advice::Sequential);
    Ok(map)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normalizes_lexically() {
        let n = |s: &str| normalize_lexically(Path::new(s));
        assert_eq!(n("pipes/../runs/out"), PathBuf::from("runs/out"));
        assert_eq!(n("./a/./b/"), PathBuf::from("a/b"));
        assert_eq!(n("../a/../../b"), PathBuf::from("../../b"));
        assert_eq!(n("/../a"), PathBuf::from("/a"));
        assert_eq!(n("a/.."), PathBuf::from("."));
    }

    #[test]
    fn temp_names_match_only_our_pattern() {
        assert_eq!(temp_pid(".out.tmp-123", "out"), Some(123));
        assert_eq!(temp_pid(".out.old-7", "out"), Some(7));
        for other in [
            ".out.tmp-",
            ".out.tmp-12a",
            ".out.tmp-123.bak",
            "out.tmp-123",
            ".outer.tmp-123",
            ".out.lock",
            ".out.tmp-99999999999",
        ] {
            assert_eq!(temp_pid(other, "out"), None, "{other}");
        }
    }

    #[test]
    fn swap_exchanges_in_one_step_on_linux() {
        let d = tempfile::tempdir().unwrap();
        let (tmp, target) = (d.path().join(".out.tmp-1"), d.path().join("out"));
        std::fs::create_dir(&tmp).unwrap();
        std::fs::write(tmp.join("f"), "new").unwrap();
        std::fs::create_dir(&target).unwrap();
        std::fs::write(target.join("f"), "old").unwrap();
        let old = swap(&tmp, &target, true).unwrap().unwrap();
        assert_eq!(std::fs::read_to_string(target.join("f")).unwrap(), "new");
        assert_eq!(std::fs::read_to_string(old.join("f")).unwrap(), "old");
        // RENAME_EXCHANGE leaves the old tree at the staging name; the two-rename fallback
        // would have moved it to `.out.old-PID`, with a moment of no `out` between.
        #[cfg(target_os = "linux")]
        assert_eq!(old, tmp);
        // Without a previous output: NOREPLACE, and no old tree.
        let fresh = d.path().join("fresh");
        std::fs::create_dir(d.path().join(".fresh.tmp-1")).unwrap();
        assert_eq!(
            swap(&d.path().join(".fresh.tmp-1"), &fresh, false).unwrap(),
            None
        );
        assert!(fresh.is_dir());
    }

    #[cfg(unix)]
    #[test]
    fn old_output_of_a_run_killed_between_two_renames_is_put_back() {
        let mut c = std::process::Command::new("true").spawn().unwrap();
        let dead = c.id();
        c.wait().unwrap();
        let d = tempfile::tempdir().unwrap();
        let target = d.path().join("out");
        let old = d.path().join(format!(".out.old-{dead}"));
        std::fs::create_dir(&old).unwrap();
        std::fs::write(old.join(MARKER), MARKER_TEXT).unwrap();
        assert_eq!(remove_stale_temps(&target), 1);
        assert!(target.join(MARKER).is_file() && !old.exists());
        // With an output in place, a stale old tree is removed instead.
        std::fs::create_dir(&old).unwrap();
        assert_eq!(remove_stale_temps(&target), 1);
        assert!(target.join(MARKER).is_file() && !old.exists());
    }

    #[test]
    fn resolve_folds_the_missing_part() {
        let d = tempfile::tempdir().unwrap();
        let real = std::fs::canonicalize(d.path()).unwrap();
        assert_eq!(resolve(&d.path().join("x/../y")).unwrap(), real.join("y"));
        assert_eq!(resolve(&d.path().join(".")).unwrap(), real);
        assert_eq!(resolve(&d.path().join("")).unwrap(), real);
    }
}
