//! What the smoke runs of the benchmark suites share (`smoke.rs`,
//! `smoke_planning.rs`): running the bench binary and reading its JSON line.
#![allow(dead_code)] // each test binary uses a part

use std::process::Command;

/// A suite's JSON line.
pub(crate) type Fig = serde_json::Map<String, serde_json::Value>;

/// Runs the bench with `args`; returns the JSON object of its last line.
pub(crate) fn run(args: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let out = Command::new(env!("CARGO_BIN_EXE_brickray-bench"))
        .args(args)
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "{args:?}: {:?}\n{stdout}\n{stderr}",
        out.status
    );
    let last = stdout.lines().last().unwrap_or_default();
    match serde_json::from_str(last) {
        Ok(serde_json::Value::Object(m)) => m,
        other => panic!("{args:?}: the last line is not a JSON object: {last:?} ({other:?})"),
    }
}

/// The rows of the array `key` of a suite's JSON object.
pub(crate) fn rows<'a>(fig: &'a Fig, key: &str) -> &'a Vec<serde_json::Value> {
    fig.get(key)
        .and_then(|v| v.as_array())
        .unwrap_or_else(|| panic!("no array {key} in {fig:?}"))
}

/// The row of the array `key` whose `field` is `value`.
pub(crate) fn row<'a>(fig: &'a Fig, key: &str, field: &str, value: &str) -> &'a serde_json::Value {
    rows(fig, key)
        .iter()
        .find(|r| r[field] == value)
        .unwrap_or_else(|| panic!("no {key} row with {field} {value} in {fig:?}"))
}

/// Checks that every row of `key` has `fields`.
pub(crate) fn has_fields(fig: &Fig, key: &str, fields: &[&str]) {
    for r in rows(fig, key) {
        for f in fields {
            assert!(r.get(*f).is_some(), "{key}: no {f} in {r:?}");
        }
    }
}

/// Runs a suite with `args` and checks that its JSON object has `keys`
/// (documented in docs/benchmarks.md; a value may be null where a smoke
/// run measures nothing) and some finite numbers (anywhere in it, rows
/// included).
pub(crate) fn smoke(args: &[&str], keys: &[&str]) -> serde_json::Map<String, serde_json::Value> {
    let fig = run(args);
    for key in keys {
        assert!(fig.contains_key(*key), "{args:?}: no {key} in {fig:?}");
    }
    fn finite(v: &serde_json::Value) -> usize {
        match v {
            serde_json::Value::Number(n) => usize::from(n.as_f64().is_some_and(f64::is_finite)),
            serde_json::Value::Array(a) => a.iter().map(finite).sum(),
            serde_json::Value::Object(m) => m.values().map(finite).sum(),
            _ => 0,
        }
    }
    let numbers: usize = fig.values().map(finite).sum();
    assert!(
        numbers >= 3,
        "{args:?}: {numbers} finite numbers in {fig:?}"
    );
    fig
}

/// A fresh temporary directory for a suite's charts and files.
pub(crate) fn tmp() -> tempfile::TempDir {
    tempfile::tempdir().unwrap()
}

/// The path of `name` in `dir`, as an argument.
pub(crate) fn at(dir: &tempfile::TempDir, name: &str) -> String {
    dir.path().join(name).to_string_lossy().into_owned()
}
