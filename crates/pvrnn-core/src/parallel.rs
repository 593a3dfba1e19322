//! Parallelism that disappears on wasm: rayon natively, a plain loop in the browser.
//!
//! Work is always split into the same pieces whatever the thread count, and partial results
//! are combined in piece order, so results do not depend on how many threads ran them.

/// `(0..n).map(f)`, in parallel where threads exist; results in index order.
pub(crate) fn map<R: Send>(n: usize, f: impl Fn(usize) -> R + Sync + Send) -> Vec<R> {
    map_if(true, n, f)
}

/// Like [`map`], but sequential unless `worth_it`: waking an idle worker costs tens of
/// microseconds, more than small pieces of work save.
pub(crate) fn map_if<R: Send>(
    worth_it: bool,
    n: usize,
    f: impl Fn(usize) -> R + Sync + Send,
) -> Vec<R> {
    #[cfg(not(target_arch = "wasm32"))]
    {
        use rayon::prelude::*;
        if worth_it && n > 1 {
            return (0..n).into_par_iter().map(f).collect();
        }
    }
    let _ = worth_it;
    (0..n).map(f).collect()
}

/// Multiply-adds below which a split into parallel tasks does not pay (~0.2 ms of work;
/// measured: the 16x16 inference condition, 4.6 M per iteration, runs faster on one thread).
pub(crate) const PARALLEL_MIN_MACS: usize = 10_000_000;

/// How to parallelise one faer product of about `flops` floating-point operations when not
/// already inside a parallel task.
pub(crate) fn gemm_par(flops: usize) -> faer::Par {
    #[cfg(not(target_arch = "wasm32"))]
    {
        if flops > 4_000_000 && rayon::current_num_threads() > 1 {
            return faer::Par::rayon(0);
        }
    }
    let _ = flops;
    faer::Par::Seq
}

/// Runs `f` on a worker thread of the pool, so the parallel sections inside it start from a
/// worker instead of each paying a hand-off from a foreign thread.
pub(crate) fn in_pool<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    #[cfg(not(target_arch = "wasm32"))]
    {
        rayon::scope(|_| f())
    }
    #[cfg(target_arch = "wasm32")]
    {
        f()
    }
}

/// `(wait(), work())`, with `work` handed to another worker of the pool while this thread
/// waits (for a device, say): host work hidden behind the device's. With one thread, or on
/// wasm, `work` runs after `wait`.
pub(crate) fn while_waiting<A, B: Send>(
    wait: impl FnOnce() -> A,
    work: impl FnOnce() -> B + Send,
) -> (A, B) {
    #[cfg(not(target_arch = "wasm32"))]
    {
        let mut done = None;
        // `in_place_scope` keeps `wait` on this thread (it need not be `Send`) and returns
        // only once the spawned `work` has run, so `done` is set by then.
        let waited = rayon::in_place_scope(|scope| {
            scope.spawn(|_| done = Some(work()));
            wait()
        });
        match done {
            Some(worked) => (waited, worked),
            None => unreachable!("rayon's scope returned before its spawned work ran"),
        }
    }
    #[cfg(target_arch = "wasm32")]
    {
        let waited = wait();
        (waited, work())
    }
}

/// Elements below which an element-wise pass stays on one thread.
#[cfg(not(target_arch = "wasm32"))]
const ELEMENTWISE_MIN: usize = 1 << 16;

/// `f` on matching chunks of four equally long slices (an element-wise update of a
/// parameter, its two optimiser moments and its gradient), in parallel for long slices.
/// Element-wise work gives the same result whatever the split.
pub(crate) fn for_each_chunk4<T: Send + Sync>(
    a: &mut [T],
    b: &mut [T],
    c: &mut [T],
    d: &[T],
    f: impl Fn(&mut [T], &mut [T], &mut [T], &[T]) + Sync + Send,
) {
    #[cfg(not(target_arch = "wasm32"))]
    {
        use rayon::prelude::*;
        if a.len() >= 2 * ELEMENTWISE_MIN && rayon::current_num_threads() > 1 {
            a.par_chunks_mut(ELEMENTWISE_MIN)
                .zip(b.par_chunks_mut(ELEMENTWISE_MIN))
                .zip(c.par_chunks_mut(ELEMENTWISE_MIN))
                .zip(d.par_chunks(ELEMENTWISE_MIN))
                .for_each(|(((a, b), c), d)| f(a, b, c, d));
            return;
        }
    }
    f(a, b, c, d);
}

#[cfg(all(test, not(target_arch = "wasm32")))]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    #[test]
    fn work_runs_on_another_thread_while_this_one_waits() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let (sender, receiver) = mpsc::channel();
        // `wait` can only receive if `work` runs meanwhile, on the pool's other thread.
        let (received, sent) = pool.install(move || {
            while_waiting(
                || receiver.recv_timeout(Duration::from_secs(10)),
                move || sender.send(7).is_ok(),
            )
        });
        assert_eq!(received, Ok(7));
        assert!(sent);
        // With one thread the work runs after the wait, and both results come back.
        let single = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        assert_eq!(single.install(|| while_waiting(|| 1, || 2)), (1, 2));
    }
}
