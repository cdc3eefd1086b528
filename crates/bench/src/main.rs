//! brickray's benchmark binary.
//!
//! `cargo run --release -p brickray-bench -- <suite>` runs one suite, prints what
//! it measured, and ends with one line holding a JSON object of the figures.
//! Variants are interleaved within one run and compared as ratios, because this
//! machine's speed drifts.

mod accel;
mod build;
mod ooc;
mod soak;
mod u8;
mod visibility;

use std::process::ExitCode;

/// What a suite returns: its figures, printed as the last line.
type Figures = serde_json::Map<String, serde_json::Value>;

/// The value after `name` in `args`, parsed, or `default` when absent.
fn arg<T: std::str::FromStr>(args: &[String], name: &str, default: T) -> Result<T, String> {
    match args.iter().position(|a| a == name) {
        None => Ok(default),
        Some(i) => args
            .get(i + 1)
            .and_then(|s| s.parse().ok())
            .ok_or_else(|| format!("bad {name}")),
    }
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let suite = args.first().map(String::as_str).unwrap_or("");
    let rest = &args[args.len().min(1)..];
    let result: Result<Figures, String> = match suite {
        "accel" => accel::run(rest),
        "build" => build::run(rest),
        "ooc" => ooc::run(rest),
        "soak" => soak::run(rest),
        "u8" => u8::run(rest),
        "visibility" => visibility::run(rest),
        _ => {
            eprintln!("usage: brickray-bench <accel|build|ooc|soak|u8|visibility> [options]");
            return ExitCode::from(2);
        }
    };
    match result {
        Ok(fig) => {
            println!("{}", serde_json::Value::Object(fig));
            ExitCode::SUCCESS
        }
        Err(e) => {
            eprintln!("brickray-bench {suite}: {e}");
            ExitCode::FAILURE
        }
    }
}
