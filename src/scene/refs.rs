//! The files a scene file refers to (glTF buffer URIs, OBJ `mtllib` names):
//! where they may be, and how they are opened.
//!
//! Why: a scene is often someone else's file (downloaded, or uploaded to a
//! service that renders it). Its references used to be joined to its folder
//! as written, so `../`, absolute paths and `%2e%2e%2f` read any file the user
//! could read, `/dev/zero` was read until memory ran out, a FIFO hung the
//! load, and error messages printed values read from such files. Now:
//!
//! - by default a reference must stay inside the scene's folder: no absolute
//!   path, no `..` that climbs out of it, and, with symbolic links resolved,
//!   a real path under the folder's real path (percent escapes are decoded by
//!   the caller before, so `%2e%2e%2f` is `../`); `--allow-outside-refs`
//!   ([`RefPolicy::allow_outside`]) lifts this rule and only this one;
//! - only regular files are opened (not devices, FIFOs, sockets, folders):
//!   checked before the open, so a device's open has no side effect, and
//!   again on the opened handle; the open is non-blocking, so a FIFO put in
//!   place between the two cannot hang it;
//! - at most the length the scene declares is read (a glTF buffer's
//!   `byteLength`), or a cap for files without one (an MTL).
//!
//! What is left: a local user who can rename files inside the scene's folder
//! while raylab loads it can still swap a checked folder for a symbolic link
//! between the check and the open (the last component is opened with
//! O_NOFOLLOW, the folders above it are not). Against a scene's author, who
//! controls only the files' contents and names, the rules hold.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

/// Where a scene's references may point.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RefPolicy {
    /// Also outside the scene's folder (`--allow-outside-refs`).
    pub allow_outside: bool,
}

/// Why a reference was not read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RefError {
    /// Against the rules above (outside the folder, not a regular file, too
    /// long): an error whatever the format.
    Refused(String),
    /// The file could not be read (missing, no permission): a format may
    /// take this as a warning (an OBJ's missing MTL).
    Unreadable(String),
}

impl std::fmt::Display for RefError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RefError::Refused(m) | RefError::Unreadable(m) => f.write_str(m),
        }
    }
}

type RefResult<T> = std::result::Result<T, RefError>;

fn io(e: std::io::Error) -> RefError {
    RefError::Unreadable(e.to_string())
}

/// The hint every refusal of an outside reference ends with.
const OUTSIDE_HINT: &str = "give --allow-outside-refs to read files outside the scene's folder";

/// The references of one scene file: resolves and reads them under a policy.
pub struct Refs {
    /// The scene file's folder, as given (what references are joined to).
    dir: PathBuf,
    /// The folder's real path (symbolic links resolved), when references must
    /// stay inside it; `None` with `--allow-outside-refs`.
    root: Option<std::result::Result<PathBuf, String>>,
}

impl Refs {
    /// The references of the scene file at `scene_path`.
    pub fn new(scene_path: &Path, policy: RefPolicy) -> Self {
        let dir = scene_path.parent().unwrap_or(Path::new("")).to_path_buf();
        Self::in_dir(&dir, policy)
    }

    /// References looked up in `dir` (for scenes read from a string).
    pub fn in_dir(dir: &Path, policy: RefPolicy) -> Self {
        let dir = if dir.as_os_str().is_empty() {
            PathBuf::from(".")
        } else {
            dir.to_path_buf()
        };
        let root = (!policy.allow_outside).then(|| {
            dir.canonicalize()
                .map_err(|e| format!("the scene's folder {}: {e}", dir.display()))
        });
        Refs { dir, root }
    }

    /// The folder references are joined to.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The real path `name` (a relative reference, percent escapes already
    /// decoded) stands for, or why it is refused. Refusals name no file
    /// outside the folder and never say whether one exists.
    pub fn resolve(&self, name: &str) -> RefResult<PathBuf> {
        let refuse = |m: String| Err(RefError::Refused(m));
        if name.is_empty() {
            return refuse("an empty file name".into());
        }
        if name.contains('\0') {
            return refuse("a file name with a NUL byte".into());
        }
        let rel = Path::new(name);
        let root = match &self.root {
            None => None,
            Some(Ok(root)) => Some(root),
            Some(Err(e)) => return Err(RefError::Unreadable(e.clone())),
        };
        if root.is_some() {
            // Judged on the name first, so that a reference to a file that
            // does not exist outside is refused like one that does.
            let mut depth = 0usize;
            for c in rel.components() {
                match c {
                    Component::Prefix(_) | Component::RootDir => {
                        return refuse(format!("an absolute path; {OUTSIDE_HINT}"))
                    }
                    Component::ParentDir if depth == 0 => {
                        return refuse(format!("climbs out of the scene's folder; {OUTSIDE_HINT}"))
                    }
                    Component::ParentDir => depth -= 1,
                    Component::CurDir => {}
                    Component::Normal(_) => depth += 1,
                }
            }
        }
        let joined = self.dir.join(rel);
        let through_link = || format!("a symbolic link out of the scene's folder; {OUTSIDE_HINT}");
        match joined.canonicalize() {
            Ok(real) => match root {
                Some(root) if !real.starts_with(root) => refuse(through_link()),
                _ => Ok(real),
            },
            Err(e) => {
                // A missing file behind a link that leads out: refused as
                // leaving, so the answer does not tell what exists out there.
                let leaves = root.is_some_and(|root| {
                    joined
                        .ancestors()
                        .skip(1)
                        .find_map(|a| a.canonicalize().ok())
                        .is_some_and(|a| !a.starts_with(root))
                });
                if leaves {
                    refuse(through_link())
                } else {
                    Err(io(e))
                }
            }
        }
    }

    /// The first `len` bytes of the file `name` refers to; an error when it
    /// is shorter (without its length, which could be a private file's).
    pub fn read_prefix(&self, name: &str, len: u64) -> RefResult<Vec<u8>> {
        let (file, size) = self.open(name)?;
        if size < len {
            return Err(RefError::Refused(format!(
                "shorter than the {len} bytes the scene declares"
            )));
        }
        read_at_most(file, len)
    }

    /// The whole file `name` refers to, refused when it is over `cap` bytes.
    pub fn read_whole(&self, name: &str, cap: u64) -> RefResult<Vec<u8>> {
        let too_long = || RefError::Refused(format!("over {cap} bytes: not read"));
        let (file, size) = self.open(name)?;
        if size > cap {
            return Err(too_long());
        }
        // The cap again: the file may grow between the stat and the read.
        let bytes = read_at_most(file, cap + 1)?;
        if bytes.len() as u64 > cap {
            return Err(too_long());
        }
        Ok(bytes)
    }

    /// Opens the regular file `name` refers to, with its size.
    fn open(&self, name: &str) -> RefResult<(std::fs::File, u64)> {
        let real = self.resolve(name)?;
        // Stat first: opening a device can act (a tape rewinds, a watchdog
        // arms), and a FIFO's open blocks until a writer comes.
        let meta = std::fs::metadata(&real).map_err(io)?;
        if !meta.is_file() {
            return Err(not_regular(&meta));
        }
        let file = open_no_wait(&real).map_err(io)?;
        // And the handle: what was opened is what is read.
        let meta = file.metadata().map_err(io)?;
        if !meta.is_file() {
            return Err(not_regular(&meta));
        }
        Ok((file, meta.len()))
    }
}

fn read_at_most(file: std::fs::File, len: u64) -> RefResult<Vec<u8>> {
    let mut bytes = Vec::new();
    file.take(len).read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Why a file that is not a regular file is refused, by its kind.
fn not_regular(meta: &std::fs::Metadata) -> RefError {
    let kind = if meta.is_dir() {
        "a folder"
    } else {
        special_kind(meta)
    };
    RefError::Refused(format!("{kind}, not a regular file"))
}

#[cfg(unix)]
fn special_kind(meta: &std::fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() || t.is_block_device() {
        "a device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn special_kind(_meta: &std::fs::Metadata) -> &'static str {
    "a special file"
}

/// Opens `path` for reading without blocking on a FIFO, without following a
/// symbolic link in its last component (the path is already resolved, so one
/// there was put in place since) and without making a terminal the process's
/// controlling terminal.
#[cfg(unix)]
fn open_no_wait(path: &Path) -> std::io::Result<std::fs::File> {
    use std::os::unix::fs::OpenOptionsExt;
    std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK | libc::O_NOFOLLOW | libc::O_NOCTTY)
        .open(path)
}

#[cfg(not(unix))]
fn open_no_wait(path: &Path) -> std::io::Result<std::fs::File> {
    std::fs::File::open(path)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A folder `scene/` with `inside.bin` and `sub/deeper.bin`, beside
    /// `secret.bin` outside it.
    fn fixture(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("raylab-refs-{tag}-{}", std::process::id()));
        std::fs::create_dir_all(d.join("scene/sub")).unwrap();
        std::fs::write(d.join("scene/inside.bin"), b"inside").unwrap();
        std::fs::write(d.join("scene/sub/deeper.bin"), b"deeper").unwrap();
        std::fs::write(d.join("secret.bin"), b"secret").unwrap();
        d
    }

    #[test]
    fn references_inside_the_folder_are_read() {
        let d = fixture("inside");
        let refs = Refs::new(&d.join("scene/a.gltf"), RefPolicy::default());
        assert_eq!(refs.read_prefix("inside.bin", 6).unwrap(), b"inside");
        assert_eq!(refs.read_prefix("inside.bin", 3).unwrap(), b"ins");
        assert_eq!(refs.read_whole("sub/deeper.bin", 100).unwrap(), b"deeper");
        assert_eq!(
            refs.read_whole("./sub/../inside.bin", 100).unwrap(),
            b"inside"
        );
        let e = refs.read_prefix("inside.bin", 7).unwrap_err().to_string();
        assert!(e.contains("shorter than the 7 bytes"), "{e}");
        assert!(!e.contains('6'), "the file's own length is not told: {e}");
        assert!(refs
            .read_whole("inside.bin", 5)
            .unwrap_err()
            .to_string()
            .contains("over"));
        assert!(matches!(
            refs.read_whole("gone.bin", 5),
            Err(RefError::Unreadable(_))
        ));
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn references_out_of_the_folder_are_refused_unless_allowed() {
        let d = fixture("outside");
        let scene = d.join("scene/a.obj");
        let refs = Refs::new(&scene, RefPolicy::default());
        let secret = d.join("secret.bin");
        let secret = secret.to_str().unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink(d.join("secret.bin"), d.join("scene/link.bin")).unwrap();
        #[cfg(unix)]
        std::os::unix::fs::symlink(&d, d.join("scene/up")).unwrap();
        for name in [
            "../secret.bin",
            "sub/../../secret.bin",
            "../nothing-there.bin",
            secret,
            "/etc/passwd",
            #[cfg(unix)]
            "link.bin",
            #[cfg(unix)]
            "up/secret.bin",
            #[cfg(unix)]
            "up/nothing-there.bin",
        ] {
            let e = refs.read_whole(name, 100).unwrap_err().to_string();
            assert!(e.contains("--allow-outside-refs"), "{name}: {e}");
            assert!(
                !e.contains("secret") && !e.contains("passwd"),
                "{name}: {e}"
            );
        }
        let allowed = Refs::new(
            &scene,
            RefPolicy {
                allow_outside: true,
            },
        );
        assert_eq!(allowed.read_whole("../secret.bin", 100).unwrap(), b"secret");
        assert_eq!(allowed.read_whole(secret, 100).unwrap(), b"secret");
        #[cfg(unix)]
        assert_eq!(allowed.read_whole("link.bin", 100).unwrap(), b"secret");
        std::fs::remove_dir_all(&d).ok();
    }

    #[test]
    fn only_regular_files_are_opened() {
        let d = fixture("special");
        let allowed = Refs::new(
            &d.join("scene/a.obj"),
            RefPolicy {
                allow_outside: true,
            },
        );
        let e = allowed.read_whole("sub", 100).unwrap_err().to_string();
        assert!(e.contains("a folder, not a regular file"), "{e}");
        #[cfg(unix)]
        {
            let e = allowed
                .read_prefix("/dev/zero", 16)
                .unwrap_err()
                .to_string();
            assert!(e.contains("a device, not a regular file"), "{e}");
            let fifo = d.join("scene/pipe.bin");
            let made = std::process::Command::new("mkfifo").arg(&fifo).status();
            if made.is_ok_and(|s| s.success()) {
                // Would block forever if it were opened for reading.
                let e = Refs::new(&d.join("scene/a.obj"), RefPolicy::default())
                    .read_whole("pipe.bin", 100)
                    .unwrap_err()
                    .to_string();
                assert!(e.contains("a FIFO, not a regular file"), "{e}");
            }
        }
        assert!(allowed
            .read_whole("", 100)
            .unwrap_err()
            .to_string()
            .contains("empty"));
        std::fs::remove_dir_all(&d).ok();
    }
}
