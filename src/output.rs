//! Every file raylab writes (images, reports, ray files, charts) goes through
//! [`write_atomic`]: a temporary file of an unpredictable name beside the
//! target, renamed over it once complete, so a reader never sees half a file
//! and a planted link is never followed. The `check_*` functions fail before
//! any work when an output could not be written.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};

/// Fails early, before any rendering, if `path` cannot be written: it must end in
/// `.png`, its folder must exist, and a file must be creatable there.
pub fn check_writable(path: &Path) -> Result<()> {
    if path.is_dir() {
        return Err(Error::usage(
            "-o",
            format!(
                "{} is a directory: give a file name ending in .png",
                path.display()
            ),
        ));
    }
    let is_png = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if !is_png {
        return Err(Error::usage(
            "-o",
            format!(
                "{}: only PNG output is supported (use a .png name)",
                path.display()
            ),
        ));
    }
    check_creatable(path, "-o")
}

/// Fails early if no file can be made at `path` (a folder, or a folder that
/// does not exist or cannot be written); `flag` names the flag in the error.
pub fn check_creatable(path: &Path, flag: &str) -> Result<()> {
    if path.is_dir() {
        return Err(Error::usage(
            flag,
            format!("{} is a directory: give a file name", path.display()),
        ));
    }
    // The same exclusive temporary file a write makes, removed at once.
    let (file, probe, _signal) = create_temp(path).map_err(|e| Error::io(path, e))?;
    drop(file);
    std::fs::remove_file(&probe).ok();
    Ok(())
}

/// A new file beside `path` for writing it: created exclusively (O_EXCL, so
/// a symbolic link or file planted under the name is never followed or
/// truncated) under a name no other process can predict, `NAME.tmp-` and 16
/// hex digits. The old name was `NAME.tmp-PID`, which a local user could
/// plant as a link to a file of the user's, truncated by the next render.
///
/// The guard returned removes the file if a signal ends raylab while it lives.
fn create_temp(
    path: &Path,
) -> std::io::Result<(std::fs::File, PathBuf, crate::os::RemoveOnSignal)> {
    let mut last = None;
    // A clash needs the same 64 random bits: the retries are for form's sake.
    for _ in 0..8 {
        let mut name = path.file_name().unwrap_or_default().to_os_string();
        name.push(format!(".tmp-{:016x}", unpredictable()));
        let tmp = path.with_file_name(name);
        match std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)
        {
            Ok(file) => {
                // Registered just after the create: a signal between the two
                // is the one moment the file can still be left.
                let guard = crate::os::RemoveOnSignal::new(&tmp);
                return Ok((file, tmp, guard));
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => return Err(e),
        }
    }
    Err(last.unwrap_or_else(|| std::io::Error::other("no free temporary name")))
}

/// 64 bits nobody else can predict: std's `RandomState` keys come from the
/// operating system's random source (getrandom), here mixed with a counter,
/// the process id and the time, so two calls never repeat. No crate needed.
fn unpredictable() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    use std::sync::atomic::{AtomicU64, Ordering};
    static CALLS: AtomicU64 = AtomicU64::new(0);
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u64(CALLS.fetch_add(1, Ordering::Relaxed));
    h.write_u32(std::process::id());
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    h.write_u128(now);
    h.finish()
}

/// Writes `path` through a temporary file beside it ([`create_temp`]) that
/// `fill` writes, flushed to disk and then renamed over `path`: a reader or a
/// failure never sees a partial file under the final name, and an existing
/// file survives any failure. On an error the temporary file is removed, and
/// on SIGINT, SIGTERM or SIGHUP too ([`crate::os::RemoveOnSignal`]); only
/// SIGKILL or a crash mid-write can leave it (`NAME.tmp-` and 16 hex digits,
/// never the final name).
pub fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<()>,
) -> Result<()> {
    let (file, tmp, _signal) = create_temp(path).map_err(|e| Error::io(path, e))?;
    let result = (|| {
        let mut w = std::io::BufWriter::new(file);
        fill(&mut w)?;
        w.flush()?;
        w.get_ref().sync_all()?;
        drop(w);
        std::fs::rename(&tmp, path)
    })();
    result.map_err(|e| {
        std::fs::remove_file(&tmp).ok();
        Error::io(path, e)
    })
}

/// Writes a report file (text) atomically, naming the file in the error.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}

/// Writes RGB8 pixels as a PNG, atomically ([`write_atomic`]).
pub fn write_png(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<()> {
    write_atomic(path, |w| {
        image::codecs::png::PngEncoder::new(w)
            .write_image(rgb8, width, height, image::ExtendedColorType::Rgb8)
            .map_err(std::io::Error::other)
    })
}

use image::ImageEncoder;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn png_round_trips_and_bad_paths_fail_early() {
        let dir = std::env::temp_dir().join(format!("raylab-png-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("x.png");
        check_writable(&path).unwrap();
        let px: Vec<u8> = (0..2 * 3 * 3).map(|i| i as u8 * 10).collect();
        write_png(&path, 2, 3, &px).unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.as_raw(), &px);
        assert!(
            std::fs::read_dir(&dir).unwrap().count() == 1,
            "no temp file left"
        );
        assert!(check_writable(&dir.join("x.jpg")).is_err());
        // A link planted under any name beside the output is never followed:
        // the target keeps its bytes, and the link stays a link.
        #[cfg(unix)]
        {
            let victim = dir.join("victim.txt");
            std::fs::write(&victim, "keep").unwrap();
            for pid in [std::process::id(), std::process::id() + 1] {
                let link = dir.join(format!("y.png.tmp-{pid}"));
                std::os::unix::fs::symlink(&victim, &link).unwrap();
            }
            write_png(&dir.join("y.png"), 2, 3, &px).unwrap();
            write_text(&dir.join("r.json"), "{}").unwrap();
            assert_eq!(std::fs::read_to_string(&victim).unwrap(), "keep");
            let names: Vec<String> = std::fs::read_dir(&dir)
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
                .collect();
            assert_eq!(names.len(), 6, "{names:?}");
        }
        // A failed write leaves no temporary file, and the old file as it was.
        let before: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        let e = write_atomic(&dir.join("x.png"), |_| Err(std::io::Error::other("full")));
        assert!(e.unwrap_err().to_string().contains("x.png"));
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), before.len());
        assert_eq!(image::open(&path).unwrap().to_rgb8().as_raw(), &px);
        assert!(check_writable(Path::new("/nonexistent-dir/x.png")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
