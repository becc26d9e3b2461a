//! The listener's remote control: stop, abort, and the state its I/O loop publishes.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use super::stats::ListenStats;
use super::Listener;

/// Shared between [`run`](super::run()) and whoever controls it (the CLI's signal handler, a test).
#[derive(Debug, Default)]
pub struct Control {
    /// Stop: save and return (Ctrl-C).
    pub stop: Arc<AtomicBool>,
    /// Return at once without saving (as if killed; the capture has every byte received).
    pub abort: AtomicBool,
    /// The device is open.
    pub connected: AtomicBool,
    pub(super) sent: AtomicU64,
    snapshot: Mutex<Option<ListenStats>>,
}

impl Control {
    /// A fresh control.
    pub fn new() -> Arc<Control> {
        Arc::new(Control::default())
    }

    /// The listener's counters after its last read.
    pub fn stats(&self) -> Option<ListenStats> {
        self.snapshot.lock().ok().and_then(|s| s.clone())
    }

    pub(super) fn publish(&self, l: &Listener) {
        if let Ok(mut s) = self.snapshot.lock() {
            *s = Some(l.stats().clone());
        }
    }

    pub(super) fn stopping(&self) -> bool {
        self.stop.load(Ordering::SeqCst) || self.abort.load(Ordering::SeqCst)
    }
}
