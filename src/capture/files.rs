//! Frame sources from files: one file re-emitted at a frame rate, or a directory of EXR/HDR frames
//! played in name order.

use super::{FrameSource, SourceError, pace};
use crate::envmap::{EnvMap, Projection};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One file, decoded once and re-emitted at `fps`.
pub struct FileSource {
    path: PathBuf,
    map: EnvMap,
    fps: f64,
    next: Instant,
}

impl FileSource {
    pub fn open(
        path: &Path,
        projection: Option<Projection>,
        max_pixels: u64,
        fps: f64,
    ) -> anyhow::Result<Self> {
        Ok(FileSource {
            path: path.to_owned(),
            map: EnvMap::open(path, projection, max_pixels)?,
            fps,
            next: Instant::now(),
        })
    }
}

impl FrameSource for FileSource {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError> {
        pace(&mut self.next, self.fps);
        out.clone_from(&self.map);
        Ok(true)
    }

    fn describe(&self) -> String {
        format!("file:{}", self.path.display())
    }

    fn nominal_fps(&self) -> f64 {
        self.fps
    }
}

/// A directory of `.exr`/`.hdr` frames sorted by name, played at `fps`, optionally looping.
/// A frame that fails to decode is reported and skipped; the list is re-read at each loop so
/// frames can be added while it runs.
pub struct DirectorySource {
    dir: PathBuf,
    files: Vec<PathBuf>,
    position: usize,
    looping: bool,
    projection: Option<Projection>,
    max_pixels: u64,
    fps: f64,
    next: Instant,
}

impl DirectorySource {
    pub fn open(
        dir: &Path,
        projection: Option<Projection>,
        max_pixels: u64,
        fps: f64,
        looping: bool,
    ) -> anyhow::Result<Self> {
        let files = list_frames(dir)?;
        if files.is_empty() {
            anyhow::bail!("{}: no .exr or .hdr frames", dir.display());
        }
        Ok(DirectorySource {
            dir: dir.to_owned(),
            files,
            position: 0,
            looping,
            projection,
            max_pixels,
            fps,
            next: Instant::now(),
        })
    }
}

/// The `.exr` and `.hdr` files of a directory, sorted by name.
pub fn list_frames(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| anyhow::anyhow!("cannot read directory {}: {e}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| e.eq_ignore_ascii_case("exr") || e.eq_ignore_ascii_case("hdr"))
        })
        .collect();
    files.sort();
    Ok(files)
}

impl FrameSource for DirectorySource {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError> {
        if self.position >= self.files.len() {
            if !self.looping {
                return Ok(false);
            }
            self.files = list_frames(&self.dir).map_err(|e| SourceError::Fatal(e.to_string()))?;
            if self.files.is_empty() {
                return Err(SourceError::Fatal(format!(
                    "{}: no frames left",
                    self.dir.display()
                )));
            }
            self.position = 0;
        }
        pace(&mut self.next, self.fps);
        let path = &self.files[self.position];
        self.position += 1;
        let bytes = std::fs::read(path)
            .map_err(|e| SourceError::BadFrame(format!("{}: {e}", path.display())))?;
        *out = EnvMap::decode(&bytes, self.projection, self.max_pixels)
            .map_err(|e| SourceError::BadFrame(format!("{}: {e}", path.display())))?;
        Ok(true)
    }

    fn describe(&self) -> String {
        format!("dir:{}", self.dir.display())
    }

    fn nominal_fps(&self) -> f64 {
        self.fps
    }
}
