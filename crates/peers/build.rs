//! Links Embree 3 only when the `embree` feature is on, so the crate builds without it.

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    if std::env::var_os("CARGO_FEATURE_EMBREE").is_some() {
        println!("cargo:rustc-link-lib=embree3");
    }
}
