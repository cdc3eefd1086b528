//! The tokio runtime a remote reader owns, and how a loader thread waits on
//! it: each read runs as a task on the reader's runtime and the caller waits
//! on a channel (never a runtime thread), within a deadline, aborting when
//! its cancel token is cancelled.

use crate::{RemoteError, RemoteOptions};
use brickray_core::CancelToken;
use std::future::Future;
use std::time::Duration;

/// The runtime a reader owns: shut down in the background when the reader
/// goes (a drop never blocks, even inside another runtime).
pub(crate) struct Runtime(Option<tokio::runtime::Runtime>);

impl Drop for Runtime {
    fn drop(&mut self) {
        if let Some(rt) = self.0.take() {
            rt.shutdown_background();
        }
    }
}

/// Starts a reader's runtime.
pub(crate) fn start_runtime(url: &str, opts: &RemoteOptions) -> Result<Runtime, RemoteError> {
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(opts.worker_threads.max(1))
        .thread_name("brickray-remote")
        .enable_all()
        .build()
        .map(|rt| Runtime(Some(rt)))
        .map_err(|e| RemoteError::Runtime {
            url: url.to_owned(),
            reason: e.to_string(),
        })
}

/// Runs `f` on `runtime` and waits for it on this thread (a channel, never
/// a runtime thread), for at most `deadline`; errors name `url`.
pub(crate) fn run_on<T: Send + 'static>(
    runtime: &Runtime,
    url: &str,
    deadline: Duration,
    f: impl Future<Output = object_store::Result<T>> + Send + 'static,
) -> Result<T, RemoteError> {
    run_until(runtime, url, deadline, f, None)
}

/// How often a waiting caller looks at its cancel token.
const CANCEL_POLL: Duration = Duration::from_millis(2);

/// [`run_on`], aborted with [`RemoteError::Cancelled`] (the task and its
/// requests dropped) once `cancel` is cancelled.
pub(crate) fn run_until<T: Send + 'static>(
    runtime: &Runtime,
    url: &str,
    deadline: Duration,
    f: impl Future<Output = object_store::Result<T>> + Send + 'static,
    cancel: Option<&CancelToken>,
) -> Result<T, RemoteError> {
    let gone = |reason: &str| RemoteError::Runtime {
        url: url.to_owned(),
        reason: reason.to_owned(),
    };
    let rt = runtime.0.as_ref().ok_or_else(|| gone("shut down"))?;
    let (tx, rx) = std::sync::mpsc::sync_channel(1);
    let task = rt.spawn(async move {
        let r = tokio::time::timeout(deadline, f).await;
        // The caller may have stopped waiting; nothing to do then.
        let _ = tx.send(r);
    });
    let got = match cancel {
        None => rx.recv().map_err(|_| ()),
        Some(c) => loop {
            match rx.recv_timeout(CANCEL_POLL) {
                Ok(r) => break Ok(r),
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) if c.is_cancelled() => {
                    task.abort();
                    return Err(RemoteError::Cancelled {
                        url: url.to_owned(),
                    });
                }
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => break Err(()),
            }
        },
    };
    match got {
        Ok(Ok(r)) => r.map_err(|e| RemoteError::of(url, e)),
        Ok(Err(_elapsed)) => Err(RemoteError::Deadline {
            url: url.to_owned(),
            deadline,
        }),
        Err(_) => {
            task.abort();
            Err(gone("the read's task was dropped"))
        }
    }
}
