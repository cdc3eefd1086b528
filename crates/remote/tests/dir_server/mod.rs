//! An HTTP server for the OME-Zarr tests: serves the files under a folder
//! on loopback with ranges, counts every request, and answers each GET as a
//! plan says (serve, a status, a reset, a truncated or a stalled body).
#![allow(dead_code)] // each test file uses part of it

use crate::common::*;
use std::io::{BufReader, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// What the server does with the n-th GET.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Act {
    Serve,
    Status(u16),
    Reset,
    Truncate,
    /// Served after this many milliseconds.
    Stall(u64),
}

/// One request the server saw: method, path, Range header.
pub(crate) type Seen = (String, String, Option<String>);

/// Serves the files under a folder on loopback, with ranges; a missing file
/// is 404, or 403 (as S3 answers without list permission).
pub(crate) struct DirServer {
    port: u16,
    seen: Arc<Mutex<Vec<Seen>>>,
    stop: Arc<AtomicBool>,
}

impl Drop for DirServer {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        let _ = TcpStream::connect(("127.0.0.1", self.port));
    }
}

impl DirServer {
    pub(crate) fn url(&self, name: &str) -> String {
        format!("http://127.0.0.1:{}/{name}", self.port)
    }

    pub(crate) fn seen(&self) -> Vec<Seen> {
        self.seen.lock().unwrap().clone()
    }

    pub(crate) fn count(&self) -> usize {
        self.seen.lock().unwrap().len()
    }
}

pub(crate) fn serve_dir(
    root: &Path,
    missing: u16,
    plan: impl Fn(usize, &str) -> Act + Send + Sync + 'static,
) -> DirServer {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let stop = Arc::new(AtomicBool::new(false));
    let gets = Arc::new(AtomicUsize::new(0));
    let (sn, st, root) = (seen.clone(), stop.clone(), root.to_owned());
    let plan = Arc::new(plan);
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            if st.load(Ordering::SeqCst) {
                break;
            }
            let Ok(conn) = conn else { continue };
            let (sn, root, plan, gets) = (sn.clone(), root.clone(), plan.clone(), gets.clone());
            std::thread::spawn(move || {
                let _ = handle(conn, &root, missing, &*plan, &gets, &sn);
            });
        }
    });
    DirServer { port, seen, stop }
}

fn handle(
    conn: TcpStream,
    root: &Path,
    missing: u16,
    plan: &(dyn Fn(usize, &str) -> Act + Send + Sync),
    gets: &AtomicUsize,
    seen: &Mutex<Vec<Seen>>,
) -> std::io::Result<()> {
    let mut reader = BufReader::new(conn.try_clone()?);
    let mut out = conn;
    loop {
        let Some(Request {
            method,
            path,
            range,
        }) = read_request(&mut reader)?
        else {
            return Ok(());
        };
        seen.lock()
            .unwrap()
            .push((method.clone(), path.clone(), range.clone()));
        let rel = path.trim_start_matches('/');
        let file = root.join(rel);
        let bytes = if rel.split('/').any(|c| c == "..") {
            None
        } else {
            std::fs::read(&file).ok()
        };
        let Some(bytes) = bytes else {
            let reason = if missing == 403 {
                "Forbidden"
            } else {
                "Not Found"
            };
            write!(
                out,
                "HTTP/1.1 {missing} {reason}\r\nContent-Length: 0\r\n\r\n"
            )?;
            continue;
        };
        let len = bytes.len();
        let common = "Accept-Ranges: bytes\r\nETag: \"v1\"\r\nLast-Modified: Thu, 01 Jan 2026 00:00:00 GMT\r\n";
        if method == "HEAD" {
            write!(
                out,
                "HTTP/1.1 200 OK\r\n{common}Content-Length: {len}\r\n\r\n"
            )?;
            continue;
        }
        let act = plan(gets.fetch_add(1, Ordering::SeqCst), &path);
        let (start, end, partial) = match range.as_deref().and_then(|r| r.strip_prefix("bytes=")) {
            Some(r) => {
                let (a, b) = r.split_once('-').unwrap_or(("", ""));
                let (s, e) = match (a.parse::<usize>(), b.parse::<usize>()) {
                    (Ok(a), Ok(b)) => (a, (b + 1).min(len)),
                    (Ok(a), Err(_)) => (a, len),
                    (Err(_), Ok(n)) => (len.saturating_sub(n), len),
                    _ => (0, len),
                };
                (s, e, true)
            }
            None => (0, len, false),
        };
        if start >= end {
            write!(
                out,
                "HTTP/1.1 416 Range Not Satisfiable\r\nContent-Range: bytes */{len}\r\nContent-Length: 0\r\n\r\n"
            )?;
            continue;
        }
        let body = &bytes[start..end];
        let head = |out: &mut TcpStream| {
            if partial {
                write!(
                    out,
                    "HTTP/1.1 206 Partial Content\r\n{common}Content-Range: bytes {start}-{}/{len}\r\nContent-Length: {}\r\n\r\n",
                    end - 1,
                    body.len()
                )
            } else {
                write!(
                    out,
                    "HTTP/1.1 200 OK\r\n{common}Content-Length: {}\r\n\r\n",
                    body.len()
                )
            }
        };
        match act {
            Act::Serve => {
                head(&mut out)?;
                out.write_all(body)?;
            }
            Act::Stall(ms) => {
                std::thread::sleep(Duration::from_millis(ms));
                head(&mut out)?;
                out.write_all(body)?;
            }
            Act::Status(code) => {
                write!(
                    out,
                    "HTTP/1.1 {code} Busy\r\nRetry-After: 0\r\nContent-Length: 0\r\nConnection: close\r\n\r\n"
                )?;
                return Ok(());
            }
            Act::Reset => return out.shutdown(std::net::Shutdown::Both),
            Act::Truncate => {
                head(&mut out)?;
                out.write_all(&body[..body.len() / 2])?;
                out.flush()?;
                return out.shutdown(std::net::Shutdown::Both);
            }
        }
        out.flush()?;
    }
}
