//! Progress bars for library stages (the libraries only report; the binary draws).

use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// One bar per stage, drawn on stderr when it is a terminal; also times each stage.
pub struct Bars {
    bar: Mutex<Option<(ProgressBar, String, Instant)>>,
    timings: Mutex<Vec<(String, f64)>>,
}

impl Bars {
    pub fn new() -> Self {
        Self {
            bar: Mutex::new(None),
            timings: Mutex::new(Vec::new()),
        }
    }

    /// Wall-clock seconds per finished stage, in order.
    pub fn timings(&self) -> Vec<(String, f64)> {
        self.timings.lock().map(|t| t.clone()).unwrap_or_default()
    }
}

impl svbrdf_core::progress::Progress for Bars {
    fn stage(&self, name: &str, total: u64) {
        crate::alloc::release_free_memory();
        let bar = ProgressBar::with_draw_target(Some(total), ProgressDrawTarget::stderr());
        let style = ProgressStyle::with_template(
            "{msg:>20} [{bar:30}] {pos}/{len} {elapsed_precise} eta {eta}",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
        bar.set_style(style);
        bar.set_message(name.to_string());
        bar.enable_steady_tick(Duration::from_millis(200));
        if let Ok(mut b) = self.bar.lock() {
            *b = Some((bar, name.to_string(), Instant::now()));
        }
    }

    fn advance(&self, n: u64) {
        if let Ok(b) = self.bar.lock() {
            if let Some((b, _, _)) = b.as_ref() {
                b.inc(n);
            }
        }
    }

    fn finish(&self) {
        if let Ok(mut b) = self.bar.lock() {
            if let Some((b, name, start)) = b.take() {
                b.finish_and_clear();
                if let Ok(mut t) = self.timings.lock() {
                    t.push((name, start.elapsed().as_secs_f64()));
                }
            }
        }
    }
}
