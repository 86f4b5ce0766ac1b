//! Raw frames on a byte stream (stdin): any camera pipeline can feed the daemon, e.g.
//! `ffmpeg -f v4l2 -i /dev/video0 -pix_fmt rgb48le -f rawvideo - | vemlight serve --source stdin …`.

use super::{FrameSource, SourceError};
use crate::envmap::{EnvMap, Projection, sanitize};
use std::io::Read;

/// Pixel layout of raw frames: three channels, little-endian, row-major from the top row.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
#[value(rename_all = "lowercase")]
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
        <RawPixel as clap::ValueEnum>::from_str(s, false).map_err(|_| {
            format!("unknown pixel format '{s}' (expected rgbf32le, rgbf16le or rgb48le)")
        })
    }
}

/// Fixed-size raw frames read back to back from a reader, a batch of rows at a time.
pub struct RawSource<R: Read + Send> {
    reader: R,
    width: usize,
    height: usize,
    pixel: RawPixel,
    projection: Projection,
    /// One batch of rows' bytes.
    buf: Vec<u8>,
    rows_per_batch: usize,
    name: String,
    /// The producer's declared frame rate (0: unknown), see [`RawSource::with_declared_fps`].
    declared_fps: f64,
}

/// About how many bytes are read and converted before the rows are handed on: small enough that
/// the last batch's resampling is a small part of a frame's, large enough that the per-batch
/// work is negligible (a pipe delivers 64 KiB per read).
const BATCH_BYTES: usize = 128 << 10;

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
        width
            .checked_mul(height)
            .and_then(|n| n.checked_mul(pixel.bytes_per_pixel()))
            .filter(|&b| b <= 1 << 31)
            .ok_or_else(|| anyhow::anyhow!("raw frames of {width}×{height} are too large"))?;
        let row_bytes = width * pixel.bytes_per_pixel();
        let rows_per_batch = (BATCH_BYTES / row_bytes).clamp(1, height);
        Ok(RawSource {
            reader,
            width,
            height,
            pixel,
            projection,
            buf: vec![0; rows_per_batch * row_bytes],
            rows_per_batch,
            name: name.to_owned(),
            declared_fps: 0.0,
        })
    }

    /// The rate the producer is expected to write frames at. Frames are still read as they come;
    /// the rate states the temporal filter's delay and cut-off in time and sets when a silent
    /// producer counts as stalled (ten frame periods, at least 2 s; 5 s when unknown).
    pub fn with_declared_fps(mut self, fps: f64) -> Self {
        self.declared_fps = fps;
        self
    }

    /// Fills `buf` from the reader; `Ok(false)` on a clean end of stream before its first byte
    /// when `may_end`. An error says why and how many bytes of `buf` had come.
    fn fill(reader: &mut R, buf: &mut [u8], may_end: bool) -> Result<bool, (String, usize)> {
        let mut filled = 0;
        while filled < buf.len() {
            match reader.read(&mut buf[filled..]) {
                Ok(0) if filled == 0 && may_end => return Ok(false),
                Ok(0) => return Err(("stream ended inside a frame".into(), filled)),
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err((e.to_string(), filled)),
            }
        }
        Ok(true)
    }
}

/// Decodes raw little-endian pixels into linear RGB.
fn convert(pixel: RawPixel, bytes: &[u8], out: &mut [[f32; 3]]) {
    match pixel {
        RawPixel::Rgbf32le => {
            for (o, c) in out.iter_mut().zip(bytes.chunks_exact(12)) {
                *o =
                    [0, 4, 8].map(|k| f32::from_le_bytes(c[k..k + 4].try_into().expect("4 bytes")));
            }
        }
        RawPixel::Rgbf16le => {
            // Through a small buffer, so that `half` converts 4 or 8 values an instruction
            // (F16C where the CPU has it: 10× faster than one by one).
            use half::slice::HalfFloatSliceExt;
            let mut halves = [half::f16::ZERO; 96];
            let values = out.as_flattened_mut();
            for (o, b) in values
                .chunks_mut(halves.len())
                .zip(bytes.chunks(2 * halves.len()))
            {
                let halves = &mut halves[..o.len()];
                for (h, b) in halves.iter_mut().zip(b.chunks_exact(2)) {
                    *h = half::f16::from_le_bytes([b[0], b[1]]);
                }
                halves.convert_to_f32_slice(o);
            }
        }
        RawPixel::Rgb48le => {
            for (o, c) in out.iter_mut().zip(bytes.chunks_exact(6)) {
                *o = [0, 2, 4].map(|k| {
                    u16::from_le_bytes(c[k..k + 2].try_into().expect("2 bytes")) as f32 / 65535.0
                });
            }
        }
    }
}

impl<R: Read + Send> FrameSource for RawSource<R> {
    fn next_frame(&mut self, out: &mut EnvMap) -> Result<bool, SourceError> {
        self.next_frame_by_rows(out, &mut |_, _| {})
    }

    /// Reads, converts and repairs a batch of rows at a time and hands each on at once. A clean
    /// end of stream between frames is the normal end, one inside a frame a truncated frame.
    fn next_frame_by_rows(
        &mut self,
        out: &mut EnvMap,
        rows: &mut dyn FnMut(&EnvMap, std::ops::Range<usize>),
    ) -> Result<bool, SourceError> {
        out.width = self.width;
        out.height = self.height;
        out.projection = self.projection;
        out.repairs = Default::default();
        out.pixels.resize(self.width * self.height, [0.0; 3]);
        let row_bytes = self.width * self.pixel.bytes_per_pixel();
        let mut row = 0;
        while row < self.height {
            let end = (row + self.rows_per_batch).min(self.height);
            let bytes = &mut self.buf[..(end - row) * row_bytes];
            match Self::fill(&mut self.reader, bytes, row == 0) {
                Ok(true) => {}
                Ok(false) => return Ok(false),
                Err((e, filled)) => {
                    let at = format!(
                        "after {} of the frame's {} bytes",
                        row * row_bytes + filled,
                        self.height * row_bytes
                    );
                    return Err(SourceError::Fatal(format!("{e} ({at})")));
                }
            }
            let pixels = &mut out.pixels[row * self.width..end * self.width];
            convert(self.pixel, bytes, pixels);
            out.repairs.add(sanitize(pixels));
            rows(out, row..end);
            row = end;
        }
        Ok(true)
    }

    fn describe(&self) -> String {
        format!(
            "{}:{}x{}:{:?}",
            self.name, self.width, self.height, self.pixel
        )
    }

    fn nominal_fps(&self) -> f64 {
        self.declared_fps
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

    /// Half floats are converted through the buffer exactly as one by one, whatever the bits
    /// (subnormals, infinities, NaN) and across the buffer's boundaries.
    #[test]
    fn half_floats_convert_as_one_by_one() {
        let bits: Vec<u16> = (0..1001u32).map(|k| (k * 65_519 % 65_536) as u16).collect();
        let bytes: Vec<u8> = bits.iter().flat_map(|b| b.to_le_bytes()).collect();
        let mut out = vec![[0.0f32; 3]; bits.len() / 3];
        convert(RawPixel::Rgbf16le, &bytes, &mut out);
        for (k, got) in out.as_flattened().iter().enumerate() {
            let want = half::f16::from_bits(bits[k]).to_f32();
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "{k}: {:#06x} gave {got}, not {want}",
                bits[k]
            );
        }
    }

    /// Rows are handed on in order, in batches that cover the frame, each final when handed on.
    #[test]
    fn rows_are_handed_on_in_batches_as_they_arrive() {
        let (w, h) = (64, 100); // 768-byte rows: batches of BATCH_BYTES / 768 rows
        let value = |k: usize| [k as f32, 0.5, (k % 7) as f32];
        let bytes: Vec<u8> = (0..w * h)
            .flat_map(|k| value(k).into_iter().flat_map(|c| c.to_le_bytes()))
            .collect();
        let mut src = RawSource::new(
            &bytes[..],
            w,
            h,
            RawPixel::Rgbf32le,
            Projection::Fisheye {
                lens: crate::envmap::Lens::Equidistant,
                fov_deg: 180.0,
                centre: None,
                radius: None,
            },
            "t",
        )
        .unwrap();
        src.rows_per_batch = 16;
        let mut out = blank();
        let mut batches = Vec::new();
        assert!(
            src.next_frame_by_rows(&mut out, &mut |m, rows| {
                assert_eq!(m.pixels.len(), w * h);
                for k in rows.start * w..rows.end * w {
                    assert_eq!(m.pixels[k], value(k), "pixel {k} not final");
                }
                batches.push(rows);
            })
            .unwrap()
        );
        let expected: Vec<_> = (0..h).step_by(16).map(|r| r..(r + 16).min(h)).collect();
        assert_eq!(batches, expected);
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
        match src.next_frame(&mut out) {
            Err(SourceError::Fatal(e)) => {
                assert!(e.contains("after 20 of the frame's 24 bytes"), "{e}")
            }
            other => panic!("{:?}", other.map_err(|e| e.to_string())),
        }
        assert!(
            RawSource::new(&b""[..], 3, 1, RawPixel::Rgb48le, Projection::LatLong, "t").is_err()
        );
    }
}
