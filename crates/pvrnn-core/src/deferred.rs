//! Results that may arrive later: how one code path serves a GPU whose read-backs block
//! (Vulkan, Metal, DX12: the device is polled until the copy lands) and one whose
//! read-backs resolve only when the browser's event loop runs (WebGPU).
//!
//! The arithmetic that waits on another device is written once, as `async` code over
//! [`Deferred`] results. Native callers run it to the end with [`now`]: every native
//! backend finishes its work before it returns a future, so the future is ready at its
//! first poll. The browser's worker awaits the same code instead
//! ([`crate::backend::LoadedModel::evaluate_async`],
//! [`crate::infer::OnlineInference::iterate_async`]).

use std::future::Future;
use std::pin::Pin;
use std::task::{Context, Poll, Waker};

/// A result computed elsewhere, borrowing whatever computes it for `'a`.
pub type Deferred<'a, R> = Pin<Box<dyn Future<Output = R> + 'a>>;

/// A result that is already here, as a [`Deferred`].
pub fn ready<'a, R: 'a>(value: R) -> Deferred<'a, R> {
    Box::pin(std::future::ready(value))
}

/// The result of a future that completes without waiting on an event loop (every native
/// backend's). A future that is still pending at its first poll is a WebGPU read-back
/// driven through a synchronous entry point; that is a caller's bug, and it stops here
/// with a message that names the asynchronous entry point to use instead.
pub fn now<F: Future>(future: F) -> F::Output {
    let mut future = std::pin::pin!(future);
    match future
        .as_mut()
        .poll(&mut Context::from_waker(Waker::noop()))
    {
        Poll::Ready(value) => value,
        Poll::Pending => panic!(
            "a GPU result can only arrive through the browser's event loop here: use the \
             asynchronous entry points (LoadedModel::evaluate_async, \
             OnlineInference::iterate_async / finish_step_async, free_energy_async)"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ready_future_gives_its_value_now() {
        assert_eq!(now(ready::<u32>(7)), 7);
        assert_eq!(now(async { 3 + 4 }), 7);
    }

    #[test]
    #[should_panic(expected = "asynchronous entry points")]
    fn a_pending_future_is_a_clear_error() {
        now(std::future::pending::<()>());
    }
}
