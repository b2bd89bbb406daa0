//! Finds the system's Embree (4 first, then 3), generates FFI bindings for it with
//! bindgen, links it, and sets `cfg(embree4)` or `cfg(embree3)` so that one small
//! module (`src/accel/embree/api.rs`) absorbs the API difference.
//!
//! Search order: `EMBREE_DIR` (with `include/` and `lib/`), then pkg-config
//! (`embree4`, `embree3`), then the usual include folders. Bindings always come
//! from the header that is installed, never from a vendored copy: Embree 4.3 grew
//! `RTCHit`, and bindings from older headers make Embree write past the ray.

// Without the `embree` feature the search code is compiled but not called.
#![cfg_attr(not(feature = "embree"), allow(dead_code))]

use std::env;
use std::path::{Path, PathBuf};

struct Embree {
    major: u32,
    include_dir: PathBuf,
    lib_dir: Option<PathBuf>,
}

fn header_major(include_dir: &Path) -> Option<u32> {
    [4, 3].into_iter().find(|major| {
        include_dir
            .join(format!("embree{major}/rtcore.h"))
            .is_file()
    })
}

fn find_embree() -> Option<Embree> {
    if let Some(dir) = env::var_os("EMBREE_DIR") {
        let dir = PathBuf::from(dir);
        let include_dir = dir.join("include");
        return header_major(&include_dir).map(|major| Embree {
            major,
            include_dir,
            lib_dir: Some(dir.join("lib")),
        });
    }
    for (major, name) in [(4, "embree4"), (3, "embree3")] {
        if let Some(lib) = pkg_config_probe(name) {
            if let Some(include_dir) = lib
                .0
                .into_iter()
                .find(|d| d.join(format!("embree{major}/rtcore.h")).is_file())
            {
                return Some(Embree {
                    major,
                    include_dir,
                    lib_dir: lib.1,
                });
            }
        }
    }
    let mut dirs: Vec<PathBuf> = vec!["/usr/local/include".into(), "/usr/include".into()];
    if let Some(prefix) = env::var_os("CONDA_PREFIX") {
        dirs.insert(0, PathBuf::from(prefix).join("include"));
    }
    for dir in dirs {
        if let Some(major) = header_major(&dir) {
            return Some(Embree {
                major,
                include_dir: dir,
                lib_dir: None,
            });
        }
    }
    None
}

/// Include folders and library folder that `pkg-config` reports for `name`.
fn pkg_config_probe(name: &str) -> Option<(Vec<PathBuf>, Option<PathBuf>)> {
    let run = |arg: &str| {
        std::process::Command::new("pkg-config")
            .args([arg, name])
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).to_string())
    };
    let cflags = run("--cflags-only-I")?;
    let libs = run("--libs-only-L")?;
    let mut includes: Vec<PathBuf> = cflags
        .split_whitespace()
        .filter_map(|f| f.strip_prefix("-I"))
        .map(PathBuf::from)
        .collect();
    includes.push("/usr/include".into());
    let lib = libs
        .split_whitespace()
        .find_map(|f| f.strip_prefix("-L"))
        .map(PathBuf::from);
    Some((includes, lib))
}

fn main() {
    println!("cargo:rerun-if-env-changed=EMBREE_DIR");
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rustc-check-cfg=cfg(embree3)");
    println!("cargo:rustc-check-cfg=cfg(embree4)");
    #[cfg(feature = "embree")]
    embree_bindings();
}

#[cfg(feature = "embree")]
fn embree_bindings() {
    let Some(embree) = find_embree() else {
        eprintln!(
            "raylab: Embree not found: install it (Debian: `sudo apt-get install libembree-dev libclang-dev`, or `make deps`), \
             set EMBREE_DIR to a folder with include/ and lib/, or build without it: `cargo build --no-default-features`"
        );
        std::process::exit(1);
    };
    let major = embree.major;
    println!("cargo:rustc-cfg=embree{major}");
    if let Some(lib) = &embree.lib_dir {
        println!("cargo:rustc-link-search=native={}", lib.display());
        // A private Embree folder (EMBREE_DIR) is found at run time without LD_LIBRARY_PATH.
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    }
    println!("cargo:rustc-link-lib=dylib=embree{major}");

    let header = embree.include_dir.join(format!("embree{major}/rtcore.h"));
    println!("cargo:rerun-if-changed={}", header.display());
    let bindings = bindgen::Builder::default()
        .header(header.to_string_lossy())
        .clang_arg(format!("-I{}", embree.include_dir.display()))
        .allowlist_function("rtc.*")
        .allowlist_type("RTC.*")
        .allowlist_var("RTC.*")
        .derive_default(true)
        .layout_tests(true)
        .generate()
        .unwrap_or_else(|e| {
            eprintln!(
                "raylab: bindgen could not read {}: {e} (is libclang-dev installed?)",
                header.display()
            );
            std::process::exit(1);
        });
    let out = PathBuf::from(env::var("OUT_DIR").expect("OUT_DIR is set by cargo"))
        .join("embree_bindings.rs");
    bindings.write_to_file(&out).unwrap_or_else(|e| {
        eprintln!("raylab: cannot write {}: {e}", out.display());
        std::process::exit(1);
    });
    println!("cargo:rustc-env=RAYLAB_EMBREE_HEADER={}", header.display());
}
