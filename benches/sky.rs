//! Criterion benchmarks of the synthetic sky (`cargo bench --bench sky`): one 1024×512 frame
//! rendered into a reused map on one thread, for the default sky (clouds and the lamp on) and with
//! its layers taken away one by one, so that each layer's cost is the difference of two lines;
//! and building a sky (the cloud texture and the sun's calibration), which `vemlight serve` pays
//! once at start-up.

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vemlight::sky::{SyntheticConfig, SyntheticSky};

type Tweak = fn(&mut SyntheticConfig);

/// The variants, each a change to the default configuration.
const VARIANTS: [(&str, Tweak); 4] = [
    ("default", |_| {}),
    ("no clouds", |c| c.clouds = 0.0),
    ("no clouds, no lamp", |c| {
        c.clouds = 0.0;
        c.switch_light = None;
    }),
    // The sun does not move, so the model's tables are not rebuilt between frames.
    ("static sun, no clouds, no lamp", |c| {
        c.clouds = 0.0;
        c.switch_light = None;
        c.sun_speed_deg_per_s = 0.0;
    }),
];

/// `render_into` at 1024×512, frames 1/30 s apart over t = 30..40 s, round and round (the sun up
/// and moving: the model's tables are rebuilt every frame, as by day in the daemon).
fn rendering(c: &mut Criterion) {
    let mut group = c.benchmark_group("sky-render-1024x512");
    for (name, tweak) in VARIANTS {
        let mut cfg = SyntheticConfig::default();
        tweak(&mut cfg);
        let mut sky = SyntheticSky::new(cfg);
        let mut out = sky.render(0.0); // warm: the grid tables and the buffer
        let mut k = 0u64;
        group.bench_function(name, |b| {
            b.iter(|| {
                k += 1;
                sky.render_into(black_box(30.0 + (k % 300) as f64 / 30.0), &mut out);
            })
        });
        black_box(&out);
    }
    group.finish();
}

/// `SyntheticSky::new` with the default configuration (clouds on: the fBm texture and its blur).
fn building(c: &mut Criterion) {
    c.bench_function("sky-new-default", |b| {
        b.iter(|| black_box(SyntheticSky::new(SyntheticConfig::default())))
    });
}

criterion_group!(benches, rendering, building);
criterion_main!(benches);
