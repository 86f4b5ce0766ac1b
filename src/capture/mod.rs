//! Frame sources: the first stage of the daemon (DESIGN.md, "The pipeline").
//!
//! A [`FrameSource`] yields environment-map frames at its own pace: [`synthetic`], the built-in
//! dynamic sky ([`crate::sky`]) `vemlight serve` uses by default so the daemon runs with no camera and no data; a
//! file or a directory of frames ([`files`]); raw frames on stdin ([`stdin`]). The daemon's
//! pipeline ([`crate::daemon`]) takes the frames from here.

pub mod files;
pub mod stdin;
pub mod synthetic;

use crate::envmap::{EnvMap, InputError};

/// Why a source could not deliver a frame.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// This frame is bad (corrupt file, wrong size); later frames may be fine.
    #[error("bad frame: {0}")]
    BadFrame(String),
    /// The source cannot go on (directory gone, pipe broken).
    #[error("source failed: {0}")]
    Fatal(String),
}

impl From<InputError> for SourceError {
    fn from(e: InputError) -> Self {
        SourceError::BadFrame(e.to_string())
    }
}

/// Something that yields environment-map frames, pacing itself (at its frame rate, or at the pace
/// its producer writes).
pub trait FrameSource: Send {
    /// Blocks until the next frame is due and writes it into `out` (reusing its buffer where it can).
    /// `Ok(false)`: the source has ended normally (end of a non-looping sequence, stdin closed).
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError>;

    /// As [`next_frame`](Self::next_frame), but calls `rows(out, range)` as soon as those rows of
    /// `out` are final (in order, together covering the frame, with `out`'s size set and its
    /// pixel buffer full-sized), so that work on a frame can start while the rest of it arrives.
    /// The daemon resamples each batch as it lands, and a frame counts as captured when its last
    /// rows are in. The default hands over the whole frame at once.
    fn next_frame_by_rows(
        &mut self,
        out: &mut EnvMap,
        rows: &mut dyn FnMut(&EnvMap, std::ops::Range<usize>),
    ) -> Result<bool, SourceError> {
        let got = self.next_frame(out)?;
        if got {
            rows(out, 0..out.height);
        }
        Ok(got)
    }

    /// A short description for `/healthz` and the LightSet's `source` field.
    fn describe(&self) -> String;

    /// Nominal frames per second (0 when the producer sets the pace).
    fn nominal_fps(&self) -> f64;
}

/// Sleeps until `next` (a deadline on a fixed frame clock) and advances it by one period; if the
/// caller fell more than a frame behind, the clock restarts from now instead of bursting.
pub fn pace(next: &mut std::time::Instant, fps: f64) {
    if fps <= 0.0 {
        return;
    }
    let period = std::time::Duration::from_secs_f64(1.0 / fps);
    let now = std::time::Instant::now();
    if *next > now {
        std::thread::sleep(*next - now);
        *next += period;
    } else if now - *next > period {
        *next = now + period;
    } else {
        *next += period;
    }
}
