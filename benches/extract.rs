//! Criterion benchmarks of per-frame light extraction (decoding excluded, single thread) and of EXR
//! decoding, on the real sunrise map: `cargo bench --bench extract`. Group `extract-256` has every
//! method (voronoi, paper, median-cut, inverse-cdf) at 256 lights on a 640×480 fisheye and the
//! 1024×512 lat-long view: the reproducible source of the time axis of docs/eval/error_vs_time.svg.
//! `vemlight bench` prints the same cases as medians with ratios to median cut.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vemlight::envmap::{DEFAULT_MAX_PIXELS, EnvMap};
use vemlight::eval::speed::standard_cases;
use vemlight::lights::Extractor;
use vemlight::mapping::Domain;
use vemlight::sampling::{DomainImage, Resampler};

fn sunrise_bytes() -> Vec<u8> {
    std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/data/sunrise.exr"
    ))
    .expect("tests/data/sunrise.exr")
}

fn extraction(c: &mut Criterion) {
    let map = EnvMap::decode(&sunrise_bytes(), None, DEFAULT_MAX_PIXELS).expect("decodes");
    let mut group = c.benchmark_group("extract-256");
    for case in standard_cases(&map, 256) {
        let mut ex = Extractor::new();
        ex.set_video(case.video);
        ex.extract(&case.map, &case.opts); // build the cached tables outside the timing
        group.bench_function(&case.name, |b| {
            b.iter(|| black_box(ex.extract(black_box(&case.map), &case.opts)))
        });
    }
    group.finish();
}

/// The resampling pass alone (the largest part of the daemon's per-frame latency): the 1024×512
/// lat-long map into the sphere's domain square, on one and on two threads.
fn resampling(c: &mut Criterion) {
    let map = EnvMap::decode(&sunrise_bytes(), None, DEFAULT_MAX_PIXELS).expect("decodes");
    let mut group = c.benchmark_group("resample-latlong-1024x512-sphere");
    for threads in [1, 2] {
        let mut r = Resampler::new(map.projection, map.width, map.height, Domain::Sphere, None);
        r.set_threads(threads);
        let mut out = DomainImage::empty();
        group.bench_function(format!("{threads} thread(s)"), |b| {
            b.iter(|| r.resample_into(black_box(&map), &mut out))
        });
    }
    group.finish();
}

fn decoding(c: &mut Criterion) {
    let bytes = sunrise_bytes();
    c.bench_function("decode sunrise.exr 1024x512 DWAB", |b| {
        b.iter(|| black_box(EnvMap::decode(black_box(&bytes), None, DEFAULT_MAX_PIXELS).unwrap()))
    });
}

criterion_group!(benches, extraction, resampling, decoding);
criterion_main!(benches);
