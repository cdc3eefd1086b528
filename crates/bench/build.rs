//! The shared data and display cfgs: see `crates/harness/build_cfg.rs`.

include!("../harness/build_cfg.rs");

fn main() {
    println!("cargo::rerun-if-changed=../harness/build_cfg.rs");
    shared_cfg();
}
