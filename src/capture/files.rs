//! Frame sources from files: one file re-emitted at a frame rate, or a directory of EXR/HDR frames
//! played in name order.

use super::{FrameSource, SourceError, pace};
use crate::envmap::{EnvMap, Projection};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

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
    /// How long to wait before looking again at a looping directory found empty or unreadable.
    pub retry: Duration,
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
            retry: Duration::from_secs(1),
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
            // A looping directory that is empty or unreadable for a while (frames being rotated,
            // a share remounted) is retried, not given up on.
            match list_frames(&self.dir) {
                Ok(files) if !files.is_empty() => {
                    self.files = files;
                    self.position = 0;
                }
                listed => {
                    std::thread::sleep(self.retry);
                    self.next = Instant::now();
                    let why = match listed {
                        Ok(_) => format!("{}: no .exr or .hdr frames", self.dir.display()),
                        Err(e) => e.to_string(),
                    };
                    return Err(SourceError::BadFrame(format!(
                        "{why} (retrying every {:?})",
                        self.retry
                    )));
                }
            }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, value: f32) {
        exr::prelude::write_rgb_file(path, 8, 4, |_, _| (value, value, value)).unwrap();
    }

    #[test]
    fn directory_plays_in_name_order_skips_bad_frames_and_loops() {
        let dir = std::env::temp_dir().join(format!("vemlight-dir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        write(&dir.join("frame-002.exr"), 2.0);
        write(&dir.join("frame-001.exr"), 1.0);
        std::fs::write(dir.join("frame-003.exr"), b"not an exr").unwrap();
        write(&dir.join("frame-004.exr"), 4.0);
        std::fs::write(dir.join("notes.txt"), b"ignored").unwrap();

        let blank = || EnvMap::from_pixels(2, 1, vec![[0.0; 3]; 2], Projection::LatLong).unwrap();
        let mut out = blank();
        let mut src = DirectorySource::open(&dir, None, 1 << 20, 1000.0, false).unwrap();
        let mut seen = Vec::new();
        loop {
            match src.next_frame(&mut out) {
                Ok(true) => seen.push(out.pixels[0][0]),
                Ok(false) => break,
                Err(SourceError::BadFrame(e)) => {
                    assert!(e.contains("frame-003"), "{e}");
                    seen.push(-1.0);
                }
                Err(e) => panic!("{e}"),
            }
        }
        assert_eq!(seen, vec![1.0, 2.0, -1.0, 4.0]);

        let mut looping = DirectorySource::open(&dir, None, 1 << 20, 1000.0, true).unwrap();
        let values: Vec<f32> = (0..8)
            .filter_map(|_| match looping.next_frame(&mut out) {
                Ok(true) => Some(out.pixels[0][0]),
                _ => None,
            })
            .collect();
        assert_eq!(values, vec![1.0, 2.0, 4.0, 1.0, 2.0, 4.0]);

        // Emptied, it is a bad frame (counted, retried), not the end; refilled, it plays on.
        looping.retry = Duration::from_millis(10);
        for f in [
            "frame-001.exr",
            "frame-002.exr",
            "frame-003.exr",
            "frame-004.exr",
        ] {
            std::fs::remove_file(dir.join(f)).unwrap();
        }
        for _ in 0..3 {
            match looping.next_frame(&mut out) {
                Err(SourceError::BadFrame(e)) => assert!(e.contains("retrying"), "{e}"),
                other => panic!(
                    "expected a bad frame, got {:?}",
                    other.map_err(|e| e.to_string())
                ),
            }
        }
        write(&dir.join("frame-009.exr"), 9.0);
        assert!(looping.next_frame(&mut out).unwrap());
        assert_eq!(out.pixels[0][0], 9.0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
