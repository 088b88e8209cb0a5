//! The terminal's progress bars for the pipelines' progress callbacks (`reconstruct`, `study`,
//! `render-dataset`): [`bar`] makes one, a [`BarSlot`] holds the one being drawn while the library reports
//! into it from any thread.
use indicatif::{ProgressBar, ProgressStyle};
use std::sync::Mutex;

/// A bar of `n` steps drawn with `template` (indicatif's syntax), labelled `what`.
pub fn bar(n: u64, template: &str, what: &str) -> ProgressBar {
    let pb = ProgressBar::new(n);
    pb.set_style(ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar()));
    pb.set_message(what.to_string());
    pb
}

/// The bar being drawn, if any (a poisoned lock is taken over: a bar is only drawn).
#[derive(Default)]
pub struct BarSlot(Mutex<Option<ProgressBar>>);

impl BarSlot {
    /// Draw `pb` from now on.
    pub fn show(&self, pb: ProgressBar) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(pb);
    }

    /// `f` on the bar being drawn; `None` when there is none.
    pub fn with<R>(&self, f: impl FnOnce(&ProgressBar) -> R) -> Option<R> {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).as_ref().map(f)
    }

    /// Stop drawing the bar (it is cleared from the terminal).
    pub fn clear(&self) {
        if let Some(pb) = self.0.lock().unwrap_or_else(|e| e.into_inner()).take() {
            pb.finish_and_clear();
        }
    }
}
