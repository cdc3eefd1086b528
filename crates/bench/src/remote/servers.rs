//! The `remote` suite's servers: the Range HTTP test server, moto's S3
//! server and the delaying proxies in front of them (python3), started for
//! the suite and stopped when dropped, and the files they serve.

use brickray_remote::RemoteOptions;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A test server (python3) started for the suite, stopped when dropped.
pub(super) struct Server {
    child: Child,
    pub(super) port: u16,
}

impl Server {
    pub(super) fn start(
        dir: &Path,
        name: &str,
        script: &Path,
        args: &[&str],
    ) -> Result<Server, String> {
        let port_file: PathBuf = dir.join(format!("{name}.port"));
        let child = Command::new("python3")
            .arg(script)
            .args(args)
            .arg("--port-file")
            .arg(&port_file)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .map_err(|e| format!("python3 {}: {e}", script.display()))?;
        let mut server = Server { child, port: 0 };
        let t = Instant::now();
        while t.elapsed() < Duration::from_secs(15) {
            if let Some(p) = std::fs::read_to_string(&port_file)
                .ok()
                .and_then(|s| s.trim().parse().ok())
            {
                server.port = p;
                return Ok(server);
            }
            if let Ok(Some(status)) = server.child.try_wait() {
                return Err(format!("{} exited: {status}", script.display()));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        Err(format!("{} did not start within 15 s", script.display()))
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// A delaying proxy (`fault_proxy.py --cycle ok --delay D`) in front of
/// `upstream` per delay of `delays`.
pub(super) fn start_proxies(
    dir: &Path,
    scripts: &Path,
    tag: &str,
    upstream: &str,
    delays: &[u32],
) -> Result<Vec<(u32, Server)>, String> {
    delays
        .iter()
        .map(|&d| {
            let delay = d.to_string();
            let args = ["--upstream", upstream, "--cycle", "ok", "--delay", &delay];
            let p = Server::start(
                dir,
                &format!("{tag}-proxy{d}"),
                &scripts.join("fault_proxy.py"),
                &args,
            )?;
            Ok((d, p))
        })
        .collect()
}

/// Options for the moto server at `endpoint` (its accepted test
/// credentials, plain HTTP).
pub(super) fn s3_options(endpoint: &str, gap_kib: u64) -> RemoteOptions {
    RemoteOptions {
        allow_http: true,
        endpoint: Some(endpoint.to_owned()),
        region: Some("us-east-1".into()),
        config: vec![
            ("aws_access_key_id".into(), "testing".into()),
            ("aws_secret_access_key".into(), "testing".into()),
        ],
        coalesce_gap: gap_kib << 10,
        ..RemoteOptions::default()
    }
}

/// moto's S3 server on a free loopback port, or `None` (said why) when moto
/// is not installed.
pub(super) fn start_moto() -> Result<Option<Server>, String> {
    let installed = Command::new("python3")
        .args(["-c", "import moto.server, flask"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !installed {
        println!("no S3 rows: moto is not installed (python3 -m pip install 'moto[server]')");
        return Ok(None);
    }
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map_err(|e| e.to_string())?
        .port();
    let child = Command::new("python3")
        .args([
            "-m",
            "moto.server",
            "-H",
            "127.0.0.1",
            "-p",
            &port.to_string(),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("moto: {e}"))?;
    let server = Server { child, port };
    let t = Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        if t.elapsed() > Duration::from_secs(30) {
            return Err("moto did not start within 30 s".into());
        }
        std::thread::sleep(Duration::from_millis(100));
    }
    Ok(Some(server))
}

/// Creates a bucket on the moto server at `port` (one unsigned `PUT`, which
/// moto accepts; object_store has no bucket API).
pub(super) fn create_bucket(port: u16, bucket: &str) -> Result<(), String> {
    use std::io::{Read, Write};
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).map_err(|e| e.to_string())?;
    s.set_read_timeout(Some(Duration::from_secs(10)))
        .map_err(|e| e.to_string())?;
    write!(
        s,
        "PUT /{bucket} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
    )
    .map_err(|e| e.to_string())?;
    let mut answer = String::new();
    let _ = s.read_to_string(&mut answer);
    if answer.starts_with("HTTP/1.1 200") {
        Ok(())
    } else {
        Err(format!("creating bucket {bucket}: {answer}"))
    }
}

/// Every file under `dir`.
pub(super) fn files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))? {
        let entry = entry.map_err(|e| e.to_string())?;
        if entry.file_type().map_err(|e| e.to_string())?.is_dir() {
            out.extend(files(&entry.path())?);
        } else {
            out.push(entry.path());
        }
    }
    Ok(out)
}

/// Copies a folder tree.
pub(super) fn copy_dir(from: &Path, to: &Path) -> Result<(), String> {
    std::fs::create_dir_all(to).map_err(|e| e.to_string())?;
    for entry in std::fs::read_dir(from).map_err(|e| format!("{}: {e}", from.display()))? {
        let entry = entry.map_err(|e| e.to_string())?;
        let target = to.join(entry.file_name());
        if entry.file_type().map_err(|e| e.to_string())?.is_dir() {
            copy_dir(&entry.path(), &target)?;
        } else {
            std::fs::copy(entry.path(), &target).map_err(|e| e.to_string())?;
        }
    }
    Ok(())
}
