//! Corrupt files never panic or abort the decoder, whatever the compression: every EXR
//! compression the exr crate reads and Radiance HDR, damaged where the decoders size their
//! buffers (each u64 of every chunk's leader set to huge values) and at random (truncations, bit
//! flips, bytes and words overwritten). Each must decode to a clean map or give an error. An
//! allocation failure aborts the process instead of panicking, so the test binary dying is this
//! test failing (the DWA leader check in `envmap::check_exr_header` was found this way).

mod common;

use exr::prelude::*;
use vemlight::envmap::EnvMap;

const W: usize = 256;
const H: usize = 128;

/// A small HDR map (night.exr's pixels, every 8th) in each EXR compression, in scan lines.
fn small_exrs() -> Vec<(String, Vec<u8>, usize)> {
    let night = common::load("night.exr");
    let step = night.width / W;
    let px = |x: usize, y: usize| night.pixels[y * step * night.width + x * step];
    [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
        Compression::B44A,
        Compression::DWAA(None),
        Compression::DWAB(None),
    ]
    .into_iter()
    .map(|compression| {
        let channels = SpecificChannels::rgb(|p: Vec2<usize>| {
            let v = px(p.0, p.1);
            (
                f16::from_f32(v[0]),
                f16::from_f32(v[1]),
                f16::from_f32(v[2]),
            )
        });
        let encoding = Encoding {
            compression,
            blocks: Blocks::ScanLines,
            line_order: LineOrder::Increasing,
        };
        let layer = Layer::new((W, H), LayerAttributes::default(), encoding, channels);
        let mut bytes = std::io::Cursor::new(Vec::new());
        Image::from_layer(layer)
            .write()
            .to_buffered(&mut bytes)
            .expect("writes");
        let chunks = H.div_ceil(compression.scan_lines_per_block());
        (format!("{compression:?}"), bytes.into_inner(), chunks)
    })
    .collect()
}

fn small_hdr() -> Vec<u8> {
    let night = common::load("night.exr");
    let px: Vec<image::Rgb<f32>> = night.pixels.iter().map(|&p| image::Rgb(p)).collect();
    let mut out = Vec::new();
    image::codecs::hdr::HdrEncoder::new(&mut out)
        .encode(&px, night.width, night.height)
        .expect("encodes");
    out
}

/// Decodes `bytes`: a map whose pixels are all finite and non-negative, or an error; never a
/// panic (an abort ends the test binary). Returns whether it decoded.
fn decodes_cleanly(bytes: &[u8], what: &str) -> bool {
    let result = std::panic::catch_unwind(|| EnvMap::decode(bytes, None, 1 << 22));
    match result {
        Ok(Ok(map)) => {
            assert_eq!(map.pixels.len(), map.width * map.height, "{what}");
            assert!(
                map.pixels
                    .iter()
                    .flatten()
                    .all(|c| c.is_finite() && *c >= 0.0),
                "{what}: unclean pixels"
            );
            true
        }
        Ok(Err(_)) => false,
        Err(_) => panic!("{what}: the decoder panicked"),
    }
}

/// xorshift64: the same mutations every run.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
}

fn mutate(rng: &mut Rng, original: &[u8]) -> Vec<u8> {
    let mut b = original.to_vec();
    match rng.below(4) {
        0 => b.truncate(rng.below(b.len()).max(4)),
        1 => {
            for _ in 0..1 + rng.below(8) {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
        }
        2 => {
            let i = 4 + rng.below(b.len().min(400) - 4);
            b[i] = rng.next() as u8;
        }
        _ => {
            let i = rng.below(b.len() - 8);
            let v = rng.next() >> rng.below(64);
            b[i..i + 8].copy_from_slice(&v.to_le_bytes());
        }
    }
    b
}

#[test]
fn huge_counters_in_chunk_leaders_are_errors_not_aborts() {
    for (name, bytes, chunks) in small_exrs() {
        assert!(
            decodes_cleanly(&bytes, &name),
            "{name}: the intact file decodes"
        );
        let starts = common::exr_chunk_data(&bytes, chunks);
        // The first two chunks and the last.
        let some = [0, 1, chunks - 1].map(|c| (c.min(chunks - 1), starts[c.min(chunks - 1)]));
        for (c, data) in some {
            // The chunk's first eleven u64 (the whole DWA leader; the start of the others).
            for word in 0..11 {
                let at = data + 8 * word;
                if at + 8 > bytes.len() {
                    break;
                }
                for huge in [1u64 << 57, 1 << 40, u32::MAX as u64] {
                    let mut b = bytes.clone();
                    b[at..at + 8].copy_from_slice(&huge.to_le_bytes());
                    decodes_cleanly(&b, &format!("{name}, chunk {c}, word {word} = {huge}"));
                }
            }
        }
    }
}

#[test]
fn random_damage_is_an_error_or_a_clean_map() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let mut files = small_exrs();
    files.push(("Radiance HDR".into(), small_hdr(), 0));
    for (name, bytes, _) in files {
        let mut errors = 0;
        for k in 0..150 {
            if !decodes_cleanly(&mutate(&mut rng, &bytes), &format!("{name}, mutation {k}")) {
                errors += 1;
            }
        }
        // Most damage is noticed (a bit flip in pixel data of an uncompressed file is not).
        assert!(errors > 0, "{name}: no mutation was refused");
    }
}
