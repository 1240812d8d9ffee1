//! The compute pool: CPU work runs on a named rayon pool of its own, never on tokio's worker
//! threads, behind an admission limit.
//!
//! [`ComputePool::run`] takes a permit — one per job queued or running — or fails at once with
//! [`PoolError::Busy`], so past capacity the service answers "retry later" instead of letting
//! latency grow without bound. The job runs under `catch_unwind`: a panic fails that job
//! (`PoolError::Panicked`) and the process lives. A caller that stops waiting (its client went
//! away, its deadline passed) cancels the job: a queued job never starts, and a running one is
//! handed the [`Abandoned`] flag to look at between its stages.
//!
//! The pool also keeps the jobs it runs in view: one still running long after its caller gave
//! up ([`ComputePool::overrunning`]) means a stage that does not stop — a thread lost until it
//! ends — and the service reports itself not ready meanwhile, so a load balancer sends the
//! work elsewhere.

use std::collections::HashMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use thiserror::Error;
use tokio::sync::{oneshot, Semaphore};

#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum PoolError {
    #[error("all {max_jobs} compute slots are taken")]
    Busy { max_jobs: usize },
    #[error("the job panicked: {message}")]
    Panicked { message: String },
}

/// One job's state, shared by the waiting side and the thread running it.
struct JobState {
    cancelled: AtomicBool,
    /// When the waiting side went away, in microseconds after the pool's epoch (0: not).
    abandoned_at_us: AtomicU64,
}

/// Set once nobody waits for a job's result any more; a running job reads it between stages.
pub struct Abandoned(Arc<JobState>);

impl Abandoned {
    pub fn is_set(&self) -> bool {
        self.0.cancelled.load(Ordering::Relaxed)
    }
}

/// A rayon pool with an admission limit (see the module doc).
pub struct ComputePool {
    pool: rayon::ThreadPool,
    permits: Arc<Semaphore>,
    max_jobs: usize,
    epoch: Instant,
    next_id: AtomicU64,
    /// The jobs running now, by id.
    running: Arc<Mutex<HashMap<u64, Arc<JobState>>>>,
}

/// Marks the job abandoned when dropped before [`CancelOnDrop::disarm`]: the waiting side
/// went away.
struct CancelOnDrop {
    job: Arc<JobState>,
    epoch: Instant,
    armed: bool,
}

impl CancelOnDrop {
    fn disarm(&mut self) {
        self.armed = false;
    }
}

impl Drop for CancelOnDrop {
    fn drop(&mut self) {
        if self.armed {
            let at = self.epoch.elapsed().as_micros().max(1) as u64;
            self.job.abandoned_at_us.store(at, Ordering::Relaxed);
            self.job.cancelled.store(true, Ordering::Relaxed);
        }
    }
}

/// Takes a job out of the running set when it ends, however it ends.
struct Running {
    running: Arc<Mutex<HashMap<u64, Arc<JobState>>>>,
    id: u64,
}

impl Drop for Running {
    fn drop(&mut self) {
        if let Ok(mut running) = self.running.lock() {
            running.remove(&self.id);
        }
    }
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    payload
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "unknown panic".to_string())
}

impl ComputePool {
    /// `threads` compute threads (named `trinocular-compute-N`), at most `max_jobs` jobs queued
    /// or running at once.
    pub fn new(
        threads: usize,
        max_jobs: usize,
    ) -> Result<ComputePool, rayon::ThreadPoolBuildError> {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(|i| format!("trinocular-compute-{i}"))
            // Jobs catch their own panics; this catches a panic escaping rayon internals
            // (which would otherwise abort the process).
            .panic_handler(|payload| {
                tracing::error!(panic = %panic_message(payload.as_ref()), "compute pool");
            })
            .build()?;
        let max_jobs = max_jobs.max(1);
        Ok(ComputePool {
            pool,
            permits: Arc::new(Semaphore::new(max_jobs)),
            max_jobs,
            epoch: Instant::now(),
            next_id: AtomicU64::new(0),
            running: Arc::default(),
        })
    }

    /// Jobs still running more than `grace` after their caller went away (a deadline passed,
    /// a client left): each holds a compute thread that no one waits for.
    pub fn overrunning(&self, grace: Duration) -> usize {
        let now = self.epoch.elapsed().as_micros() as u64;
        let grace = grace.as_micros() as u64;
        self.running.lock().map_or(0, |running| {
            running
                .values()
                .filter(|job| {
                    let at = job.abandoned_at_us.load(Ordering::Relaxed);
                    at != 0 && now.saturating_sub(at) > grace
                })
                .count()
        })
    }

    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// Jobs queued or running now.
    pub fn in_flight(&self) -> usize {
        self.max_jobs - self.permits.available_permits()
    }

    pub fn max_jobs(&self) -> usize {
        self.max_jobs
    }

    /// Runs `job` on the pool (its own `par_iter`s included) and awaits its result. The job
    /// may stop early once its [`Abandoned`] flag is set: its result goes nowhere.
    pub async fn run<T, F>(&self, job: F) -> Result<T, PoolError>
    where
        T: Send + 'static,
        F: FnOnce(&Abandoned) -> T + Send + 'static,
    {
        let permit =
            Arc::clone(&self.permits)
                .try_acquire_owned()
                .map_err(|_| PoolError::Busy {
                    max_jobs: self.max_jobs,
                })?;
        let state = Arc::new(JobState {
            cancelled: AtomicBool::new(false),
            abandoned_at_us: AtomicU64::new(0),
        });
        let mut guard = CancelOnDrop {
            job: Arc::clone(&state),
            epoch: self.epoch,
            armed: true,
        };
        let (tx, rx) = oneshot::channel();
        let running = Arc::clone(&self.running);
        let id = self.next_id.fetch_add(1, Ordering::Relaxed);
        self.pool.spawn(move || {
            let abandoned = Abandoned(state);
            if abandoned.is_set() {
                return; // the permit goes with the closure
            }
            if let Ok(mut jobs) = running.lock() {
                jobs.insert(id, Arc::clone(&abandoned.0));
            }
            let _running = Running { running, id };
            let result = catch_unwind(AssertUnwindSafe(|| job(&abandoned))).map_err(|p| {
                PoolError::Panicked {
                    message: panic_message(p.as_ref()),
                }
            });
            // Free the slot before answering, so a caller that got its answer sees it free.
            drop(permit);
            let _ = tx.send(result);
        });
        let result = rx.await.unwrap_or_else(|_| {
            Err(PoolError::Panicked {
                message: "the job was dropped".to_string(),
            })
        });
        guard.disarm();
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    fn runtime() -> tokio::runtime::Runtime {
        tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap()
    }

    #[test]
    fn runs_jobs_on_named_threads() {
        let pool = ComputePool::new(2, 4).unwrap();
        let name = runtime()
            .block_on(pool.run(|_| std::thread::current().name().map(str::to_string)))
            .unwrap();
        assert!(name.unwrap().starts_with("trinocular-compute-"));
        assert_eq!(pool.threads(), 2);
    }

    #[test]
    fn past_capacity_answers_busy_at_once() {
        let pool = ComputePool::new(1, 1).unwrap();
        let rt = runtime();
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        rt.block_on(async {
            let first = pool.run(move |_| release_rx.recv().is_ok());
            let second = async {
                // The first job holds the only slot while it waits.
                tokio::time::sleep(Duration::from_millis(20)).await;
                let busy = pool.run(|_| 0).await;
                release_tx.send(()).unwrap();
                busy
            };
            let (first, second) = tokio::join!(first, second);
            assert_eq!(first, Ok(true));
            assert_eq!(second, Err(PoolError::Busy { max_jobs: 1 }));
        });
        assert_eq!(pool.in_flight(), 0, "slots come back");
    }

    #[test]
    fn a_panic_fails_its_job_and_the_pool_lives() {
        let pool = ComputePool::new(1, 2).unwrap();
        let rt = runtime();
        let err = rt
            .block_on(pool.run(|_| -> u32 { panic!("boom") }))
            .unwrap_err();
        assert_eq!(
            err,
            PoolError::Panicked {
                message: "boom".to_string()
            }
        );
        assert_eq!(rt.block_on(pool.run(|_| 7)), Ok(7));
    }

    #[test]
    fn a_job_whose_caller_went_away_does_not_start() {
        let pool = ComputePool::new(1, 4).unwrap();
        let rt = runtime();
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        let started = Arc::new(AtomicBool::new(false));
        rt.block_on(async {
            // Occupy the only thread, then queue a job and stop waiting for it.
            let blocker = pool.run(move |_| release_rx.recv().is_ok());
            let queued = {
                let started = Arc::clone(&started);
                pool.run(move |_| started.store(true, Ordering::Relaxed))
            };
            let abandon = async {
                tokio::time::timeout(Duration::from_millis(20), queued)
                    .await
                    .ok();
                release_tx.send(()).unwrap();
            };
            let (b, _) = tokio::join!(blocker, abandon);
            assert_eq!(b, Ok(true));
        });
        // Let the pool drain: the cancelled job returns without running.
        for _ in 0..100 {
            if pool.in_flight() == 0 {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(pool.in_flight(), 0);
        assert!(!started.load(Ordering::Relaxed));
    }

    #[test]
    fn a_running_job_sees_that_its_caller_went_away() {
        let pool = ComputePool::new(1, 4).unwrap();
        let rt = runtime();
        let (saw_tx, saw_rx) = std::sync::mpsc::channel::<bool>();
        rt.block_on(async {
            let (started_tx, started_rx) = tokio::sync::oneshot::channel::<()>();
            let job = pool.run(move |abandoned| {
                let _ = started_tx.send(());
                // A long job that looks at the flag between its "stages".
                for _ in 0..2000 {
                    if abandoned.is_set() {
                        let _ = saw_tx.send(true);
                        return;
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
                let _ = saw_tx.send(false);
            });
            let abandon = async {
                started_rx.await.unwrap();
                // Dropping the future while the job runs is what a gone client does.
            };
            tokio::select! {
                _ = job => panic!("the job should not finish first"),
                _ = abandon => {}
            }
        });
        let saw = saw_rx
            .recv_timeout(Duration::from_secs(5))
            .expect("job ended");
        assert!(
            saw,
            "the running job stopped early because its caller went away"
        );
    }

    #[test]
    fn a_job_running_on_long_after_its_caller_left_is_overrunning() {
        let pool = ComputePool::new(1, 2).unwrap();
        let rt = runtime();
        let (release_tx, release_rx) = std::sync::mpsc::channel::<()>();
        rt.block_on(async {
            // A job that ignores its flag, abandoned by its caller after 10 ms.
            let stubborn = pool.run(move |_| release_rx.recv().is_ok());
            assert!(tokio::time::timeout(Duration::from_millis(10), stubborn)
                .await
                .is_err());
        });
        assert_eq!(pool.overrunning(Duration::from_secs(60)), 0, "within grace");
        std::thread::sleep(Duration::from_millis(30));
        assert_eq!(pool.overrunning(Duration::from_millis(10)), 1);
        release_tx.send(()).unwrap();
        for _ in 0..200 {
            if pool.overrunning(Duration::ZERO) == 0 {
                break;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        assert_eq!(pool.overrunning(Duration::ZERO), 0, "an ended job is not");
    }
}
