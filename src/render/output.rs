//! From linear radiance to an 8-bit PNG: clamp to [0, 1], encode with the sRGB
//! transfer curve, hash the bytes, write the file atomically.

use std::io::Write;
use std::path::{Path, PathBuf};

use super::Frame;
use crate::error::{Error, Result};

/// The sRGB transfer function applied to a clamped linear value (NaN as 0).
#[inline]
pub fn linear_to_srgb(x: f32) -> f32 {
    let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, 1.0) };
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// [`linear_to_srgb`] rounded to 8 bits.
#[inline]
pub fn linear_to_srgb8(x: f32) -> u8 {
    (linear_to_srgb(x) * 255.0 + 0.5) as u8
}

/// The frame as 8-bit sRGB, RGB interleaved, row 0 at the top.
pub fn to_srgb8(frame: &Frame) -> Vec<u8> {
    frame
        .pixels
        .iter()
        .flat_map(|p| [p.x, p.y, p.z].map(linear_to_srgb8))
        .collect()
}

/// FNV-1a 64 of the 8-bit pixels, as 16 hex digits: equal hashes mean equal images.
pub fn image_hash(rgb8: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in rgb8 {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

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
    let probe = temp_path(path);
    std::fs::File::create(&probe).map_err(|e| Error::io(path, e))?;
    std::fs::remove_file(&probe).ok();
    Ok(())
}

fn temp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

/// Writes a text report file, naming the file in the error.
pub fn write_text(path: &Path, text: &str) -> Result<()> {
    std::fs::write(path, text).map_err(|e| Error::io(path, e))
}

/// Writes RGB8 pixels as a PNG: to a temporary file beside `path`, then renamed,
/// so a failure never leaves a partial image under the final name.
pub fn write_png(path: &Path, width: u32, height: u32, rgb8: &[u8]) -> Result<()> {
    let tmp = temp_path(path);
    let result = (|| {
        let file = std::fs::File::create(&tmp)?;
        let mut w = std::io::BufWriter::new(file);
        image::codecs::png::PngEncoder::new(&mut w)
            .write_image(rgb8, width, height, image::ExtendedColorType::Rgb8)
            .map_err(std::io::Error::other)?;
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

use image::ImageEncoder;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints_and_midtone() {
        assert_eq!(linear_to_srgb8(0.0), 0);
        assert_eq!(linear_to_srgb8(1.0), 255);
        assert_eq!(linear_to_srgb8(7.0), 255);
        assert_eq!(linear_to_srgb8(-1.0), 0);
        assert_eq!(linear_to_srgb8(f32::NAN), 0);
        assert_eq!(linear_to_srgb8(0.2159), 128); // sRGB 0.5 is linear 0.214; 128/255 is 0.2159
    }

    #[test]
    fn hash_changes_with_any_byte() {
        let a = vec![0u8; 30];
        let mut b = a.clone();
        b[17] = 1;
        assert_ne!(image_hash(&a), image_hash(&b));
        assert_eq!(image_hash(&a), image_hash(&a.clone()));
    }

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
        assert!(check_writable(Path::new("/nonexistent-dir/x.png")).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
