//! The `brickray-bench` command line refuses options no suite can run with
//! (zero rounds or frames, an image side of 0 or past any device's target,
//! parts that name no part) with a usage error naming the option, before
//! any GPU work or data access, and never panics.
#![allow(missing_docs)]

use std::process::Command;
use std::time::{Duration, Instant};

/// Runs the bench with `args`; returns its stderr after checking that it
/// was refused as a usage error.
fn refused(args: &[&str]) -> String {
    let t = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_brickray-bench"))
        .args(args)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert_eq!(
        out.status.code(),
        Some(2),
        "{args:?}: not a usage error ({:?}):\n{stderr}",
        out.status
    );
    assert!(!stderr.contains("panicked"), "{args:?}:\n{stderr}");
    assert!(
        t.elapsed() < Duration::from_secs(10),
        "{args:?}: took {:?} (GPU work?)",
        t.elapsed()
    );
    stderr
}

#[test]
fn options_no_suite_can_run_with_are_usage_errors() {
    let cases: [(&[&str], &str); 9] = [
        (&["accel", "--rounds", "0", "--size", "32"], "--rounds"),
        (&["accel", "--size", "0"], "--size"),
        (&["accel", "--size", "1000000"], "--size"),
        (&["soak", "--frames", "0"], "--frames"),
        (&["soak", "--size", "0"], "--size"),
        (&["ooc", "--parts", "zz"], "--parts"),
        (&["ooc", "--parts", ""], "--parts"),
        (&["u8", "--rounds", "0"], "--rounds"),
        (&["raw", "--size", "99999999999"], "--size"),
    ];
    for (args, option) in cases {
        let stderr = refused(args);
        assert!(
            stderr.contains(option),
            "{args:?}: {option} not named:\n{stderr}"
        );
        eprintln!("{args:?}: {}", stderr.lines().next().unwrap_or(""));
    }
}
