//! Raw frames on a byte stream (stdin): any camera pipeline can feed the daemon, e.g.
//! `ffmpeg -f v4l2 -i /dev/video0 -pix_fmt rgb48le -f rawvideo - | vemlight serve --source stdin …`.

use super::{FrameSource, SourceError};
use crate::envmap::{EnvMap, Projection, sanitize};
use std::io::Read;

/// Pixel layout of raw frames: three channels, little-endian, row-major from the top row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RawPixel {
    /// 32-bit float per channel, linear radiance.
    Rgbf32le,
    /// 16-bit half float per channel, linear radiance.
    Rgbf16le,
    /// 16-bit unsigned integer per channel, read as linear values in [0, 1] (value / 65535).
    Rgb48le,
}

impl RawPixel {
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            RawPixel::Rgbf32le => 12,
            RawPixel::Rgbf16le | RawPixel::Rgb48le => 6,
        }
    }
}

impl std::str::FromStr for RawPixel {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "rgbf32le" => Ok(RawPixel::Rgbf32le),
            "rgbf16le" => Ok(RawPixel::Rgbf16le),
            "rgb48le" => Ok(RawPixel::Rgb48le),
            _ => Err(format!(
                "unknown pixel format '{s}' (expected rgbf32le, rgbf16le or rgb48le)"
            )),
        }
    }
}

/// Fixed-size raw frames read back to back from a reader.
pub struct RawSource<R: Read + Send> {
    reader: R,
    width: usize,
    height: usize,
    pixel: RawPixel,
    projection: Projection,
    buf: Vec<u8>,
    name: String,
}

impl<R: Read + Send> RawSource<R> {
    pub fn new(
        reader: R,
        width: usize,
        height: usize,
        pixel: RawPixel,
        projection: Projection,
        name: &str,
    ) -> anyhow::Result<Self> {
        projection.check_size(width, height)?;
        let bytes = width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(pixel.bytes_per_pixel()))
            .filter(|&b| b <= 1 << 31)
            .ok_or_else(|| anyhow::anyhow!("raw frames of {width}×{height} are too large"))?;
        Ok(RawSource {
            reader,
            width,
            height,
            pixel,
            projection,
            buf: vec![0; bytes],
            name: name.to_owned(),
        })
    }
}

impl<R: Read + Send> FrameSource for RawSource<R> {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError> {
        // Read one whole frame; a clean end of stream between frames is the normal end, one in
        // the middle of a frame is a truncated frame.
        let mut filled = 0;
        while filled < self.buf.len() {
            match self.reader.read(&mut self.buf[filled..]) {
                Ok(0) if filled == 0 => return Ok(false),
                Ok(0) => {
                    return Err(SourceError::Fatal(format!(
                        "stream ended inside a frame ({filled} of {} bytes)",
                        self.buf.len()
                    )));
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(SourceError::Fatal(e.to_string())),
            }
        }
        out.width = self.width;
        out.height = self.height;
        out.projection = self.projection;
        out.pixels.clear();
        match self.pixel {
            RawPixel::Rgbf32le => out.pixels.extend(self.buf.chunks_exact(12).map(|c| {
                [0, 4, 8].map(|o| f32::from_le_bytes(c[o..o + 4].try_into().expect("4 bytes")))
            })),
            RawPixel::Rgbf16le => out.pixels.extend(self.buf.chunks_exact(6).map(|c| {
                [0, 2, 4].map(|o| {
                    half::f16::from_le_bytes(c[o..o + 2].try_into().expect("2 bytes")).to_f32()
                })
            })),
            RawPixel::Rgb48le => out.pixels.extend(self.buf.chunks_exact(6).map(|c| {
                [0, 2, 4].map(|o| {
                    u16::from_le_bytes(c[o..o + 2].try_into().expect("2 bytes")) as f32 / 65535.0
                })
            })),
        }
        out.repairs = sanitize(&mut out.pixels);
        Ok(true)
    }

    fn describe(&self) -> String {
        format!(
            "{}:{}x{}:{:?}",
            self.name, self.width, self.height, self.pixel
        )
    }

    fn nominal_fps(&self) -> f64 {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn blank() -> EnvMap {
        EnvMap::from_pixels(2, 1, vec![[0.0; 3]; 2], Projection::LatLong).unwrap()
    }

    #[test]
    fn reads_each_pixel_format_and_ends_cleanly() {
        let (w, h) = (4, 2);
        let values: Vec<f32> = (0..w * h * 3).map(|k| k as f32 * 0.25).collect();
        let mut f32_bytes = Vec::new();
        let mut f16_bytes = Vec::new();
        let mut u16_bytes = Vec::new();
        for &v in &values {
            f32_bytes.extend_from_slice(&v.to_le_bytes());
            f16_bytes.extend_from_slice(&half::f16::from_f32(v).to_le_bytes());
            u16_bytes.extend_from_slice(&((v / 6.0 * 65535.0).round() as u16).to_le_bytes());
        }
        for (pixel, bytes, scale) in [
            (RawPixel::Rgbf32le, f32_bytes, 1.0),
            (RawPixel::Rgbf16le, f16_bytes, 1.0),
            (RawPixel::Rgb48le, u16_bytes, 1.0 / 6.0),
        ] {
            // Two frames back to back.
            let stream = [bytes.clone(), bytes].concat();
            let mut src =
                RawSource::new(&stream[..], w, h, pixel, Projection::LatLong, "test").unwrap();
            let mut out = blank();
            for _ in 0..2 {
                assert!(src.next_frame(&mut out).unwrap());
                assert_eq!((out.width, out.height), (w, h));
                for (k, p) in out.pixels.iter().flatten().enumerate() {
                    assert!((p - values[k] * scale).abs() < 1e-3, "{pixel:?} {k}: {p}");
                }
            }
            assert!(!src.next_frame(&mut out).unwrap(), "clean end of stream");
        }
    }

    #[test]
    fn truncated_frame_and_bad_pixels() {
        let mut bytes = Vec::new();
        for v in [f32::NAN, -1.0, 2.0, 1.0, 1.0, 1.0] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let mut src = RawSource::new(
            &bytes[..],
            2,
            1,
            RawPixel::Rgbf32le,
            Projection::LatLong,
            "t",
        )
        .unwrap();
        let mut out = blank();
        assert!(src.next_frame(&mut out).unwrap());
        assert_eq!(out.repairs.clamped_pixels(), 1);
        assert_eq!(out.pixels[0], [0.0, 0.0, 2.0]);

        let mut src = RawSource::new(
            &bytes[..20],
            2,
            1,
            RawPixel::Rgbf32le,
            Projection::LatLong,
            "t",
        )
        .unwrap();
        assert!(matches!(
            src.next_frame(&mut out),
            Err(SourceError::Fatal(_))
        ));
        assert!(
            RawSource::new(&b""[..], 3, 1, RawPixel::Rgb48le, Projection::LatLong, "t").is_err()
        );
    }
}
