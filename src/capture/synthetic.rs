//! The synthetic sky as a frame source: the default source of `vemlight serve`, so the daemon runs,
//! and its lights move, with no data and no camera (DESIGN.md, "Processes and endpoints").
//!
//! The sky itself (sun, clouds, ground, lamp, exact ground truth) is [`crate::sky`]; this wrapper
//! only paces it: frames at a fixed rate, sky time following the wall clock, each frame handed on
//! by rows as it renders.

use std::ops::Range;

use crate::envmap::EnvMap;
use crate::sky::{SyntheticConfig, SyntheticSky};

/// The synthetic sky as a [`FrameSource`](super::FrameSource): frames at `fps`, sky time following
/// the wall clock, so the sun moves at its configured speed whatever the frame rate.
pub struct SyntheticSource {
    sky: SyntheticSky,
    fps: f64,
    start: std::time::Instant,
    next: std::time::Instant,
}

impl SyntheticSource {
    pub fn new(cfg: SyntheticConfig, fps: f64) -> Self {
        let now = std::time::Instant::now();
        SyntheticSource {
            sky: SyntheticSky::new(cfg),
            fps,
            start: now,
            next: now,
        }
    }
}

impl super::FrameSource for SyntheticSource {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, super::SourceError> {
        self.next_frame_by_rows(out, &mut |_, _| {})
    }

    fn next_frame_by_rows(
        &mut self,
        out: &mut EnvMap,
        rows: &mut dyn FnMut(&EnvMap, Range<usize>),
    ) -> Result<bool, super::SourceError> {
        super::pace(&mut self.next, self.fps);
        self.sky
            .render_by_rows(self.start.elapsed().as_secs_f64(), out, rows);
        Ok(true)
    }

    fn describe(&self) -> String {
        let c = self.sky.config();
        format!("synthetic:{}x{}", c.width, c.height)
    }

    fn nominal_fps(&self) -> f64 {
        self.fps
    }
}
