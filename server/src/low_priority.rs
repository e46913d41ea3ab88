//! Threads of their own, at a lower CPU priority, for the web's heavy answers (a study's JSON and
//! page, the list of studies, the surfaces' pictures): however many readers ask, these take what
//! the dispatch of points and the pools' calls leave. Built on tokio's blocking threads, at the
//! same priority as everything else, eight readers of a 2,000-point study cut the points
//! dispatched per second 3 x on two cores (issue 48; docs/performance.md, "Under attack").
//!
//! A bounded queue: when it is full the answer is "busy" at once (503), not a wait that grows
//! with the readers; a job whose reader has gone is skipped.

use std::panic::AssertUnwindSafe;
use std::sync::mpsc::{SyncSender, TrySendError};

/// Nice value of the threads: a thread at nice 10 gets about a tenth of a core's share against
/// one at 0 when both want it, and all of it when nothing else runs.
const NICE: i32 = 10;
/// Jobs waiting at most.
const QUEUE: usize = 64;

type Job = Box<dyn FnOnce() + Send>;

/// The threads, and the queue that feeds them.
pub struct LowPriority {
    jobs: SyncSender<Job>,
}

/// Why a job gave no answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NotBuilt {
    /// every thread busy and the queue full
    Busy,
    /// the job panicked (logged)
    Failed,
}

impl LowPriority {
    /// Starts `threads` threads (at least one).
    pub fn start(threads: usize) -> std::io::Result<Self> {
        let (jobs, queue) = std::sync::mpsc::sync_channel::<Job>(QUEUE);
        let queue = std::sync::Arc::new(std::sync::Mutex::new(queue));
        for k in 0..threads.max(1) {
            let queue = queue.clone();
            std::thread::Builder::new().name(format!("web-{k}")).spawn(move || {
                lower_priority();
                loop {
                    // (the lock is held while waiting for a job only, not while running one)
                    let job = match queue.lock().unwrap_or_else(std::sync::PoisonError::into_inner).recv() {
                        Ok(job) => job,
                        Err(_) => return,
                    };
                    job();
                }
            })?;
        }
        Ok(Self { jobs })
    }

    /// As many threads as half the cores (one at least): the pages never take more than half.
    pub fn for_this_machine() -> std::io::Result<Self> {
        Self::start(std::thread::available_parallelism().map_or(1, |n| n.get() / 2))
    }

    /// Runs `f` on one of the threads and gives its answer; skipped if its caller has gone by
    /// the time a thread takes it.
    pub async fn run<T: Send + 'static>(&self, f: impl FnOnce() -> T + Send + 'static) -> Result<T, NotBuilt> {
        self.queue(f, false).await
    }

    /// [`Self::run`], run to its end even if its caller has gone (what it makes is kept for the
    /// next caller: a page's pictures).
    pub async fn run_to_end<T: Send + 'static>(&self, f: impl FnOnce() -> T + Send + 'static) -> Result<T, NotBuilt> {
        self.queue(f, true).await
    }

    async fn queue<T: Send + 'static>(
        &self,
        f: impl FnOnce() -> T + Send + 'static,
        to_end: bool,
    ) -> Result<T, NotBuilt> {
        let (tx, rx) = tokio::sync::oneshot::channel();
        let job: Job = Box::new(move || {
            if tx.is_closed() && !to_end {
                return;
            }
            match std::panic::catch_unwind(AssertUnwindSafe(f)) {
                Ok(v) => {
                    let _ = tx.send(Ok(v));
                }
                Err(_) => {
                    tracing::error!("a web answer's job panicked");
                    let _ = tx.send(Err(NotBuilt::Failed));
                }
            }
        });
        match self.jobs.try_send(job) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => return Err(NotBuilt::Busy),
            Err(TrySendError::Disconnected(_)) => return Err(NotBuilt::Failed),
        }
        rx.await.unwrap_or(Err(NotBuilt::Failed))
    }
}

/// Lowers the calling thread's priority (Linux: a thread's nice value is its own).
fn lower_priority() {
    // SAFETY: setpriority reads no memory of ours; `who` 0 is the calling thread.
    let r = unsafe { libc::setpriority(libc::PRIO_PROCESS, 0, NICE) };
    if r != 0 {
        tracing::warn!(error = %std::io::Error::last_os_error(), "could not lower the web threads' priority");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The threads run at nice 10, answer, survive a panic, and say busy when the queue is full.
    #[tokio::test]
    async fn jobs_run_at_a_lower_priority_and_a_full_queue_says_busy() {
        let pool = std::sync::Arc::new(LowPriority::start(1).unwrap());
        // SAFETY: getpriority reads no memory of ours.
        let nice = pool.run(|| unsafe { libc::getpriority(libc::PRIO_PROCESS, 0) }).await.unwrap();
        assert_eq!(nice, NICE);
        assert_eq!(pool.run(|| -> i32 { panic!("a job's bug") }).await, Err(NotBuilt::Failed));
        assert_eq!(pool.run(|| 7).await, Ok(7));
        // one job holds the thread; QUEUE more fill the queue; the next is refused at once
        let (release, held) = std::sync::mpsc::channel::<()>();
        let held = std::sync::Mutex::new(held);
        let p = pool.clone();
        let blocking = tokio::spawn(async move { p.run(move || held.lock().unwrap().recv().ok()).await });
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        let queued: Vec<_> = (0..QUEUE)
            .map(|_| {
                let p = pool.clone();
                tokio::spawn(async move { p.run(|| 1).await })
            })
            .collect();
        tokio::time::sleep(std::time::Duration::from_millis(50)).await;
        assert_eq!(pool.run(|| 2).await, Err(NotBuilt::Busy));
        release.send(()).unwrap();
        assert_eq!(blocking.await.unwrap(), Ok(Some(())));
        for q in queued {
            assert_eq!(q.await.unwrap(), Ok(1));
        }
    }
}
