//! Points the linker at memory.x and checks that the frames exported by `m2smap firmware-frames` exist.
use std::path::PathBuf;

fn main() {
    let dir = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    println!("cargo:rustc-link-search={}", dir.display());
    println!("cargo:rerun-if-changed=memory.x");
    println!("cargo:rerun-if-env-changed=M2SMAP_FRAMES");
    let frames = std::env::var("M2SMAP_FRAMES").unwrap_or_else(|_| {
        panic!("set M2SMAP_FRAMES to the folder written by `m2smap firmware-frames` (make firmware does this)")
    });
    let path = PathBuf::from(&frames).join("frames.rs");
    assert!(path.is_file(), "{} is missing: run `m2smap firmware-frames`", path.display());
    println!("cargo:rerun-if-changed={}", path.display());
}
