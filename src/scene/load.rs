//! Which reader a scene file goes to: by its content where that is certain
//! (PLY's and GLB's magic, UTF-16 byte-order marks, binary data), else by its
//! extension. Formats raylab does not read get one line naming the format and
//! what raylab reads, never "no faces".

use std::path::Path;

use super::refs::RefPolicy;
use super::{is_scene_file, obj, ply, Scene, READS};
use crate::error::{Error, Result};

/// Extensions of 3D formats raylab does not read, with their names.
const OTHER_FORMATS: &[(&str, &str)] = &[
    ("stl", "STL"),
    ("fbx", "FBX"),
    ("off", "OFF"),
    ("3ds", "3DS"),
    ("dae", "COLLADA"),
    ("blend", "Blender"),
    ("abc", "Alembic"),
    ("usd", "USD"),
    ("usda", "USD"),
    ("usdc", "USD"),
    ("usdz", "USD"),
    ("x3d", "X3D"),
    ("wrl", "VRML"),
    ("3mf", "3MF"),
    ("step", "STEP"),
    ("stp", "STEP"),
    ("iges", "IGES"),
    ("igs", "IGES"),
    ("lwo", "LightWave"),
    ("ma", "Maya"),
    ("mb", "Maya"),
    ("max", "3ds Max"),
    ("c4d", "Cinema 4D"),
];

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    Obj,
    Ply,
    Gltf,
}

/// Loads a scene file in any format raylab reads; the files it refers to
/// must be in its folder.
pub fn load_file(path: &Path) -> Result<Scene> {
    load_file_with(path, RefPolicy::default())
}

/// [`load_file`], the files it refers to read where `policy` allows.
pub fn load_file_with(path: &Path, policy: RefPolicy) -> Result<Scene> {
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    match detect(path, &bytes)? {
        Format::Ply => ply::load_ply_bytes(&bytes, path),
        Format::Gltf => super::gltf_motion::load_still(&bytes, path, policy),
        Format::Obj => {
            let text = String::from_utf8_lossy(&bytes);
            // A UTF-8 byte-order mark would make the first record unknown.
            let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
            let dir = path.parent().unwrap_or(Path::new(""));
            obj::load_obj_str_with(text, path, dir, policy)
        }
    }
}

/// Loads `spec`: a scene file (an existing file, a path, or a name with a scene
/// extension), or else a built-in scene name.
pub fn load_scene(spec: &str) -> Result<Scene> {
    load_scene_with(spec, RefPolicy::default())
}

/// [`load_scene`], a scene file's references read where `policy` allows.
pub fn load_scene_with(spec: &str, policy: RefPolicy) -> Result<Scene> {
    if is_scene_file(spec) {
        load_file_with(Path::new(spec), policy)
    } else {
        super::builtin::builtin(spec)
    }
}

/// The reader for `bytes` read from `path`, or an error naming what it is.
pub fn detect(path: &Path, bytes: &[u8]) -> Result<Format> {
    let fail = |msg: String| Error::Parse {
        path: path.to_path_buf(),
        line: 0,
        msg,
    };
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        return Ok(Format::Ply);
    }
    if bytes.starts_with(b"glTF") {
        return Ok(Format::Gltf);
    }
    if bytes.starts_with(&[0xFF, 0xFE]) || bytes.starts_with(&[0xFE, 0xFF]) {
        return Err(fail(
            "UTF-16 text: save it as UTF-8 (raylab reads OBJ, PLY headers and glTF JSON as UTF-8 or ASCII)".into(),
        ));
    }
    if let Some((_, name)) = OTHER_FORMATS.iter().find(|(e, _)| *e == ext) {
        return Err(fail(format!("{name} files are not read: {READS}")));
    }
    if bytes.starts_with(b"Kaydara FBX Binary") {
        return Err(fail(format!("an FBX file: {READS}")));
    }
    match ext.as_str() {
        "ply" => return Err(fail("not a PLY file (it must start with 'ply')".into())),
        "glb" => return Err(fail("not a GLB file (it must start with 'glTF')".into())),
        "gltf" => return Ok(Format::Gltf),
        _ => {}
    }
    let head = &bytes[..bytes.len().min(1 << 16)];
    if head.contains(&0) {
        return Err(fail(format!("a binary file, not a scene: {READS}")));
    }
    let text_start = String::from_utf8_lossy(&head[..head.len().min(256)]);
    let first = text_start.trim_start_matches('\u{feff}').trim_start();
    if ext != "obj" {
        if first.starts_with('{') {
            return Ok(Format::Gltf);
        }
        if first.starts_with("solid") {
            return Err(fail(format!("an ASCII STL file: {READS}")));
        }
        if first.starts_with("OFF") {
            return Err(fail(format!("an OFF file: {READS}")));
        }
    }
    Ok(Format::Obj)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn what(name: &str, bytes: &[u8]) -> std::result::Result<Format, String> {
        detect(Path::new(name), bytes).map_err(|e| e.to_string())
    }

    #[test]
    fn formats_are_told_by_content_first() {
        assert_eq!(what("a.ply", b"ply\nformat ascii 1.0\n"), Ok(Format::Ply));
        assert_eq!(what("scan", b"ply\r\nformat ascii 1.0\n"), Ok(Format::Ply));
        assert_eq!(what("a.bin", b"glTF\x02\0\0\0"), Ok(Format::Gltf));
        assert_eq!(what("a.gltf", b"{\"asset\":{}}"), Ok(Format::Gltf));
        assert_eq!(what("noext", b"  {\"asset\":{}}"), Ok(Format::Gltf));
        assert_eq!(what("a.obj", b"v 0 0 0\n"), Ok(Format::Obj));
        assert_eq!(what("a.txt", b"v 0 0 0\n"), Ok(Format::Obj));
    }

    #[test]
    fn other_formats_and_binaries_say_what_they_are() {
        for (name, bytes, needle) in [
            ("m.stl", &b"solid x\n"[..], "STL files are not read"),
            ("m", &b"solid cube\nfacet normal"[..], "ASCII STL"),
            ("m.fbx", &b"Kaydara FBX Binary  \0"[..], "FBX files"),
            ("m.bin", &b"Kaydara FBX Binary  \0"[..], "FBX file"),
            ("m.off", &b"OFF\n3 1 0\n"[..], "OFF files"),
            ("m.dat", &b"OFF\n3 1 0\n"[..], "OFF file"),
            ("m.obj", &[0x7f, b'E', b'L', b'F', 0, 0][..], "binary file"),
            ("m.obj", &[0xFF, 0xFE, b'v', 0][..], "UTF-16"),
            ("m.ply", &b"v 0 0 0\n"[..], "not a PLY file"),
            ("m.glb", &b"v 0 0 0\n"[..], "not a GLB file"),
        ] {
            let e = what(name, bytes).unwrap_err();
            assert!(e.starts_with(name), "{name}: {e}");
            assert!(e.contains(needle), "{name}: {e}");
            assert_eq!(e.lines().count(), 1);
        }
        assert!(what("m.stl", b"solid").unwrap_err().contains(READS));
    }
}
