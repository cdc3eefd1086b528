//! Where a streamed volume's frames are planned: inline, on the render thread
//! inside `prepare`, or in the background, on a worker thread of the volume's
//! own that plans the next frame (refinement, placement, index encoding) while
//! the current one renders, so that `prepare` only applies the latest plan
//! (writes its uploads, tables and index) and sends the next request.
//!
//! Each plan is applied exactly once and in order (one request is in flight
//! at a time), so the planner's pool bookkeeping and the GPU atlas agree. A
//! frame is planned (inline) or a request sent (in the background) unless
//! the last plan converged and the views and the classification are those
//! it was made for and the configuration did not change since: the
//! planner's own convergence rule says that more frames of it (and their
//! feedback, which is then dropped) would change nothing, so a converged,
//! unchanged view plans nothing, draws the last plan and wants no redraw. Background
//! planning adds one frame of latency to a camera move (the frame after the
//! move is drawn with the plan of the view before); the first frame, and the
//! first after the pool was rebuilt, wait for their plan.

use brickray_cache::{Classification, StreamFrame, StreamPlan, Streamer, ViewFeedback};
use brickray_core::{FrameView, RenderMode, TransferFunction};
use brickray_index::{CutError, Splits};
use parking_lot::Mutex;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, TryRecvError};
use std::time::Instant;

/// What one plan gave: the plan, its index words, the planner's rows.
pub(crate) struct Reply {
    pub(crate) plan: StreamPlan,
    pub(crate) words: Result<Vec<u32>, CutError>,
    /// Rows of the slot table and usage counters the plan needs.
    pub(crate) slot_rows: u32,
    /// Milliseconds planning and encoding the index took (on the worker in
    /// the background).
    pub(crate) plan_ms: f64,
    pub(crate) encode_ms: f64,
    /// The pool epoch the plan was made for (a stale one is dropped).
    epoch: u64,
}

/// Plans one frame and encodes its index.
fn plan_now(
    streamer: &Mutex<Streamer>,
    splits: Splits,
    frame: &StreamFrame<'_>,
    epoch: u64,
) -> Reply {
    let t = Instant::now();
    let (plan, slot_rows) = {
        let mut s = streamer.lock();
        let plan = s.plan(frame);
        (plan, s.slot_rows())
    };
    let plan_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let words = brickray_index::encode_cut_with(&plan.cut, splits).map(|i| i.words().to_vec());
    Reply {
        plan,
        words,
        slot_rows,
        plan_ms,
        encode_ms: t.elapsed().as_secs_f64() * 1e3,
        epoch,
    }
}

/// A request to the worker: one frame, owned.
struct Request {
    views: Vec<FrameView>,
    mode: RenderMode,
    /// The transfer function when its generation changed since the last
    /// request (the worker keeps the last one).
    tf: Option<TransferFunction>,
    /// A multi-channel volume's styles, sent with the TF.
    channels: Vec<brickray_core::ChannelStyle>,
    tf_generation: u64,
    feedback: Vec<ViewFeedback>,
    time: Option<f64>,
    epoch: u64,
}

/// The background worker's ends.
struct Worker {
    tx: Sender<Request>,
    rx: Receiver<Reply>,
    /// A request was sent whose reply was not taken yet.
    outstanding: bool,
    /// The TF generation the worker holds.
    worker_tf: Option<u64>,
}

fn spawn(streamer: Arc<Mutex<Streamer>>, splits: Splits) -> std::io::Result<Worker> {
    let (tx, requests) = std::sync::mpsc::channel::<Request>();
    let (replies, rx) = std::sync::mpsc::channel::<Reply>();
    std::thread::Builder::new()
        .name("brickray-planner".into())
        .spawn(move || {
            let mut tf: Option<TransferFunction> = None;
            let mut channels = Vec::new();
            // Ends when the volume (the sender) is dropped.
            while let Ok(r) = requests.recv() {
                if let Some(t) = r.tf {
                    tf = Some(t);
                    channels = r.channels;
                }
                let Some(tf) = tf.as_ref() else { continue };
                let frame = StreamFrame {
                    views: &r.views,
                    classification: Classification {
                        mode: r.mode,
                        tf,
                        channels: &channels,
                        tf_generation: r.tf_generation,
                    },
                    feedback: &r.feedback,
                    time: r.time,
                };
                if replies
                    .send(plan_now(&streamer, splits, &frame, r.epoch))
                    .is_err()
                {
                    break;
                }
            }
        })?;
    Ok(Worker {
        tx,
        rx,
        outstanding: false,
        worker_tf: None,
    })
}

/// A streamed volume's planner (see the module documentation).
pub(crate) struct Planner {
    pub(crate) streamer: Arc<Mutex<Streamer>>,
    splits: Splits,
    worker: Option<Worker>,
    /// Bumped when the pool is rebuilt: plans made before are stale.
    epoch: u64,
    /// A plan of the current epoch was applied.
    applied: bool,
    /// The planner's frame counter as the render side knows it: requests
    /// made (read-backs copied in earlier frames were submitted).
    frame: u64,
    /// Feedback read back but not yet sent, per view.
    pending: Vec<ViewFeedback>,
    /// The last applied plan converged.
    converged: bool,
    /// What the last plan (inline) or request (in the background) was made
    /// for: views, mode, TF generation.
    last: Option<(Vec<FrameView>, RenderMode, u64)>,
}

impl Planner {
    pub(crate) fn new(
        streamer: Streamer,
        splits: Splits,
        background: bool,
    ) -> std::io::Result<Planner> {
        let streamer = Arc::new(Mutex::new(streamer));
        let worker = if background {
            Some(spawn(streamer.clone(), splits)?)
        } else {
            None
        };
        Ok(Planner {
            streamer,
            splits,
            worker,
            epoch: 0,
            applied: false,
            frame: 0,
            pending: Vec::new(),
            converged: false,
            last: None,
        })
    }

    /// The frame number read-backs are polled against (see
    /// `Streamer::next_frame`).
    pub(crate) fn next_frame(&self) -> u64 {
        self.frame + 1
    }

    /// Keeps feedback read back for view `i` until it is sent.
    pub(crate) fn add_feedback(&mut self, i: usize, f: ViewFeedback) {
        if self.pending.len() <= i {
            self.pending.resize_with(i + 1, ViewFeedback::default);
        }
        let p = &mut self.pending[i];
        p.usage.extend(f.usage);
        p.queries.extend(f.queries);
    }

    /// The pool was rebuilt: plans in flight are stale, and the next frame
    /// waits for a plan of the new pool.
    pub(crate) fn pool_rebuilt(&mut self) {
        self.epoch += 1;
        self.applied = false;
    }

    /// The configuration changed without a pool rebuild (a budget, the LOD
    /// rule, visibility): the views are planned again, and the image has
    /// not converged until a plan made after the change is applied.
    pub(crate) fn reconfigured(&mut self) {
        self.converged = false;
        self.last = None;
    }

    /// True when another frame of the same views would change the image.
    pub(crate) fn wants_redraw(&self) -> bool {
        !self.converged || self.worker.as_ref().is_some_and(|w| w.outstanding)
    }

    /// The plan to apply this frame, if any: inline, this frame's; in the
    /// background, the latest the worker finished (the first frame of an
    /// epoch waits for it), and the next request is sent.
    pub(crate) fn plan(&mut self, frame: &StreamFrame<'_>) -> Option<Reply> {
        let feedback = std::mem::take(&mut self.pending);
        let c = frame.classification;
        let same = self.last.as_ref().is_some_and(|(v, m, g)| {
            v.as_slice() == frame.views && *m == c.mode && *g == c.tf_generation
        });
        let Some(w) = self.worker.as_mut() else {
            // A converged plan of the same views stands: another would
            // change nothing (the views draw it again).
            if same && self.converged && self.applied {
                return None;
            }
            self.last = Some((frame.views.to_vec(), c.mode, c.tf_generation));
            self.frame += 1;
            let f = StreamFrame {
                feedback: &feedback,
                ..*frame
            };
            let reply = plan_now(&self.streamer, self.splits, &f, self.epoch);
            self.applied = true;
            self.converged = reply.plan.stats.converged;
            return Some(reply);
        };
        let mut got = None;
        if w.outstanding {
            let r = if self.applied {
                match w.rx.try_recv() {
                    Ok(r) => Some(r),
                    Err(TryRecvError::Empty) => None,
                    Err(TryRecvError::Disconnected) => None,
                }
            } else {
                w.rx.recv().ok()
            };
            if let Some(r) = r {
                w.outstanding = false;
                if r.epoch == self.epoch {
                    got = Some(r);
                }
            }
        }
        let settled = got
            .as_ref()
            .map_or(self.converged, |r| r.plan.stats.converged);
        let steady = same && settled && self.applied;
        if !w.outstanding && !steady {
            let changed = w.worker_tf != Some(c.tf_generation);
            let tf = changed.then(|| c.tf.clone());
            let channels = if changed {
                c.channels.to_vec()
            } else {
                Vec::new()
            };
            w.worker_tf = Some(c.tf_generation);
            self.last = Some((frame.views.to_vec(), c.mode, c.tf_generation));
            let sent = w.tx.send(Request {
                views: frame.views.to_vec(),
                mode: c.mode,
                tf,
                channels,
                tf_generation: c.tf_generation,
                feedback,
                time: frame.time,
                epoch: self.epoch,
            });
            if sent.is_ok() {
                w.outstanding = true;
                self.frame += 1;
            }
            if !self.applied && got.is_none() && w.outstanding {
                // The first frame of an epoch waits for its plan.
                if let Ok(r) = w.rx.recv() {
                    w.outstanding = false;
                    if r.epoch == self.epoch {
                        got = Some(r);
                    }
                }
            }
        } else if w.outstanding {
            // Not sent while a plan is in flight: kept for the next request.
            self.pending = feedback;
        }
        if let Some(r) = &got {
            self.applied = true;
            self.converged = r.plan.stats.converged;
        }
        got
    }
}
