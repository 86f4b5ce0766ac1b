//! Counters shared by the capture pipeline and the server, rendered in the Prometheus text format
//! for `GET /metrics`.

use std::fmt::Write;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::time::Duration;

/// Accumulated time of one pipeline stage.
#[derive(Default)]
pub struct StageTimer {
    nanos: AtomicU64,
    count: AtomicU64,
}

impl StageTimer {
    pub fn record(&self, d: Duration) {
        self.nanos.fetch_add(d.as_nanos() as u64, Relaxed);
        self.count.fetch_add(1, Relaxed);
    }

    pub fn record_secs(&self, s: f64) {
        self.record(Duration::from_secs_f64(s.max(0.0)));
    }

    /// Mean time per record in milliseconds (NaN before the first).
    pub fn mean_ms(&self) -> f64 {
        self.nanos.load(Relaxed) as f64 * 1e-6 / self.count.load(Relaxed) as f64
    }
}

/// Upper bounds (seconds) of [`LatencyHistogram`]'s buckets: fine around the 5 ms delivery target,
/// coarse beyond.
pub const LATENCY_BUCKETS_S: [f64; 14] = [
    0.0005, 0.001, 0.002, 0.003, 0.004, 0.005, 0.0075, 0.01, 0.02, 0.05, 0.1, 0.25, 1.0, 10.0,
];

/// A Prometheus histogram of latencies with the fixed bounds [`LATENCY_BUCKETS_S`] (and +Inf).
#[derive(Default)]
pub struct LatencyHistogram {
    /// Per bucket, not cumulative; the last one is +Inf.
    counts: [AtomicU64; LATENCY_BUCKETS_S.len() + 1],
    nanos: AtomicU64,
}

impl LatencyHistogram {
    pub fn observe(&self, d: Duration) {
        let secs = d.as_secs_f64();
        let bucket = LATENCY_BUCKETS_S
            .iter()
            .position(|&le| secs <= le)
            .unwrap_or(LATENCY_BUCKETS_S.len());
        self.counts[bucket].fetch_add(1, Relaxed);
        self.nanos.fetch_add(d.as_nanos() as u64, Relaxed);
    }

    /// The per-bucket counts now.
    pub fn snapshot(&self) -> HistogramCounts {
        HistogramCounts(self.counts.each_ref().map(|c| c.load(Relaxed)))
    }

    /// The histogram's lines in the Prometheus text format (cumulative buckets, sum, count).
    fn render(&self, s: &mut String, name: &str, help: &str) {
        let _ = writeln!(s, "# HELP vemlight_{name} {help}");
        let _ = writeln!(s, "# TYPE vemlight_{name} histogram");
        let mut cumulative = 0;
        for (k, c) in self.snapshot().0.iter().enumerate() {
            cumulative += c;
            let le = LATENCY_BUCKETS_S
                .get(k)
                .map_or("+Inf".to_string(), |b| b.to_string());
            let _ = writeln!(s, "vemlight_{name}_bucket{{le=\"{le}\"}} {cumulative}");
        }
        let secs = self.nanos.load(Relaxed) as f64 * 1e-9;
        let _ = writeln!(s, "vemlight_{name}_sum {secs}");
        let _ = writeln!(s, "vemlight_{name}_count {cumulative}");
    }
}

/// Per-bucket counts of a [`LatencyHistogram`] at one moment; two snapshots' difference is what
/// happened between them.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HistogramCounts(pub [u64; LATENCY_BUCKETS_S.len() + 1]);

impl HistogramCounts {
    pub fn count(&self) -> u64 {
        self.0.iter().sum()
    }

    /// What was observed after `earlier`.
    pub fn since(&self, earlier: &HistogramCounts) -> HistogramCounts {
        let mut d = *self;
        for (a, b) in d.0.iter_mut().zip(&earlier.0) {
            *a = a.saturating_sub(*b);
        }
        d
    }

    /// Fraction of observations at most `le` seconds, where `le` is one of the bucket bounds.
    pub fn fraction_within(&self, le: f64) -> f64 {
        let within: u64 = LATENCY_BUCKETS_S
            .iter()
            .zip(&self.0)
            .filter(|(b, _)| **b <= le)
            .map(|(_, c)| c)
            .sum();
        within as f64 / self.count().max(1) as f64
    }

    /// The upper bound (seconds) of the bucket that holds quantile `q` (+Inf beyond the last).
    pub fn quantile_bound(&self, q: f64) -> f64 {
        let target = ((q * self.count() as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (k, c) in self.0.iter().enumerate() {
            seen += c;
            if seen >= target {
                return LATENCY_BUCKETS_S.get(k).copied().unwrap_or(f64::INFINITY);
            }
        }
        f64::INFINITY
    }
}

/// Every counter the daemon exports.
#[derive(Default)]
pub struct Metrics {
    pub frames_captured: AtomicU64,
    pub frames_processed: AtomicU64,
    /// Frames the source delivered while the previous one was still waiting to be processed.
    pub frames_dropped: AtomicU64,
    pub source_errors: AtomicU64,
    pub lightsets_published: AtomicU64,
    /// Times a stream with an error target (`max_error`) changed its light count.
    pub adaptive_count_changes: AtomicU64,
    pub ws_clients: AtomicU64,
    pub ws_connections_total: AtomicU64,
    pub ws_messages_sent: AtomicU64,
    pub ws_bytes_sent: AtomicU64,
    /// Clients dropped because they stopped reading for longer than the send timeout.
    pub ws_clients_stalled: AtomicU64,
    /// WebSocket handshakes answered 503 because `--max-clients` clients were connected.
    pub ws_clients_refused: AtomicU64,
    /// Connections open now, upgraded WebSocket connections included.
    pub connections_open: AtomicU64,
    /// Times the accept loop stopped accepting because `--max-connections` were open.
    pub accept_paused: AtomicU64,
    /// `GET /v1/lights/latest` requests answered 503 because their light count would have
    /// taken a stream slot beyond the share such requests may hold.
    pub latest_refused: AtomicU64,
    pub http_lights_requests: AtomicU64,
    pub http_lights_errors: AtomicU64,
    /// Getting a frame from the source, with the resampling of the rows handed on while it
    /// arrives (a streaming source's).
    pub stage_capture: StageTimer,
    /// Resampling after the frame's last rows are in (all of it for a frame that lands whole).
    pub stage_resample: StageTimer,
    pub stage_warp: StageTimer,
    pub stage_assign: StageTimer,
    /// The L2 spherical-harmonic projection of the domain image.
    pub stage_sh: StageTimer,
    pub stage_filter: StageTimer,
    pub stage_publish: StageTimer,
    /// From a frame entering the pipeline to its LightSet handed to a client's socket, per
    /// message (the temporal filter's signal delay not included). Only messages that go out as
    /// soon as they are published count: not the set a client gets on connecting, nor those of
    /// clients that asked for `max_hz` (they wait on purpose).
    pub ws_delivery: LatencyHistogram,
}

impl Metrics {
    pub fn inc(counter: &AtomicU64) {
        counter.fetch_add(1, Relaxed);
    }

    /// The Prometheus text exposition (version 0.0.4).
    pub fn render(&self) -> String {
        let mut s = String::new();
        let counter = |s: &mut String, name: &str, help: &str, v: &AtomicU64| {
            let _ = writeln!(s, "# HELP vemlight_{name} {help}");
            let _ = writeln!(s, "# TYPE vemlight_{name} counter");
            let _ = writeln!(s, "vemlight_{name} {}", v.load(Relaxed));
        };
        counter(
            &mut s,
            "frames_captured_total",
            "Frames read from the source.",
            &self.frames_captured,
        );
        counter(
            &mut s,
            "frames_processed_total",
            "Frames turned into light sets.",
            &self.frames_processed,
        );
        counter(
            &mut s,
            "frames_dropped_total",
            "Frames skipped because processing was busy.",
            &self.frames_dropped,
        );
        counter(
            &mut s,
            "source_errors_total",
            "Bad frames and source failures.",
            &self.source_errors,
        );
        counter(
            &mut s,
            "lightsets_published_total",
            "LightSet documents published (all light counts).",
            &self.lightsets_published,
        );
        counter(
            &mut s,
            "adaptive_count_changes_total",
            "Light-count changes of streams with an error target (max_error).",
            &self.adaptive_count_changes,
        );
        counter(
            &mut s,
            "ws_connections_total",
            "WebSocket clients accepted.",
            &self.ws_connections_total,
        );
        counter(
            &mut s,
            "ws_messages_sent_total",
            "WebSocket messages sent.",
            &self.ws_messages_sent,
        );
        counter(
            &mut s,
            "ws_bytes_sent_total",
            "WebSocket payload bytes sent.",
            &self.ws_bytes_sent,
        );
        counter(
            &mut s,
            "ws_clients_stalled_total",
            "WebSocket clients dropped for not reading.",
            &self.ws_clients_stalled,
        );
        counter(
            &mut s,
            "ws_clients_refused_total",
            "WebSocket handshakes refused (503) because --max-clients clients were connected.",
            &self.ws_clients_refused,
        );
        counter(
            &mut s,
            "accept_paused_total",
            "Times the accept loop paused at --max-connections open connections (new ones wait in the listen backlog).",
            &self.accept_paused,
        );
        counter(
            &mut s,
            "latest_refused_total",
            "GET /v1/lights/latest requests refused (503): too many light counts asked for by nothing but such requests.",
            &self.latest_refused,
        );
        counter(
            &mut s,
            "http_lights_requests_total",
            "POST /v1/lights requests.",
            &self.http_lights_requests,
        );
        counter(
            &mut s,
            "http_lights_errors_total",
            "POST /v1/lights requests answered with an error.",
            &self.http_lights_errors,
        );
        let _ = writeln!(
            s,
            "# HELP vemlight_ws_clients WebSocket clients connected now."
        );
        let _ = writeln!(s, "# TYPE vemlight_ws_clients gauge");
        let _ = writeln!(s, "vemlight_ws_clients {}", self.ws_clients.load(Relaxed));
        let _ = writeln!(
            s,
            "# HELP vemlight_connections_open Connections open now (WebSocket clients included)."
        );
        let _ = writeln!(s, "# TYPE vemlight_connections_open gauge");
        let _ = writeln!(
            s,
            "vemlight_connections_open {}",
            self.connections_open.load(Relaxed)
        );
        let _ = writeln!(
            s,
            "# HELP vemlight_stage_seconds Time spent per pipeline stage (capture is the whole wait for \
             each frame: until it is due or arrives, reading or decoding it, and resampling its rows \
             as they arrive, so at a source's full rate it is about one frame period; resample is \
             what is left once the frame is in)."
        );
        let _ = writeln!(s, "# TYPE vemlight_stage_seconds summary");
        for (stage, t) in [
            ("capture", &self.stage_capture),
            ("resample", &self.stage_resample),
            ("warp", &self.stage_warp),
            ("assign", &self.stage_assign),
            ("sh", &self.stage_sh),
            ("filter", &self.stage_filter),
            ("publish", &self.stage_publish),
        ] {
            let secs = t.nanos.load(Relaxed) as f64 * 1e-9;
            let _ = writeln!(s, "vemlight_stage_seconds_sum{{stage=\"{stage}\"}} {secs}");
            let _ = writeln!(
                s,
                "vemlight_stage_seconds_count{{stage=\"{stage}\"}} {}",
                t.count.load(Relaxed)
            );
        }
        self.ws_delivery.render(
            &mut s,
            "ws_delivery_seconds",
            "From a frame entering the pipeline to its LightSet written to a WebSocket client (clients without max_hz; not the first set after connecting).",
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn histogram_buckets_are_cumulative_and_quantiles_land_in_the_right_bucket() {
        let h = LatencyHistogram::default();
        for ms in [0.3, 0.8, 1.5, 1.5, 4.5, 4.9, 6.0, 30.0, 20_000.0] {
            h.observe(Duration::from_secs_f64(ms * 1e-3));
        }
        // One more on a bound: `le` is inclusive.
        h.observe(Duration::from_micros(5000));
        let c = h.snapshot();
        assert_eq!(c.count(), 10);
        assert!((c.fraction_within(0.005) - 0.7).abs() < 1e-12);
        assert_eq!(c.quantile_bound(0.4), 0.002); // the 4th of 10: 1.5 ms
        assert_eq!(c.quantile_bound(0.5), 0.005); // the 5th: 4.5 ms
        assert_eq!(c.quantile_bound(0.8), 0.0075);
        assert_eq!(c.quantile_bound(0.9), 0.05);
        assert_eq!(c.quantile_bound(1.0), f64::INFINITY);
        let mut text = String::new();
        h.render(&mut text, "x_seconds", "test");
        assert!(
            text.contains("vemlight_x_seconds_bucket{le=\"0.002\"} 4\n"),
            "{text}"
        );
        assert!(
            text.contains("vemlight_x_seconds_bucket{le=\"0.005\"} 7\n"),
            "{text}"
        );
        assert!(
            text.contains("vemlight_x_seconds_bucket{le=\"+Inf\"} 10\n"),
            "{text}"
        );
        assert!(text.contains("vemlight_x_seconds_count 10\n"), "{text}");
        // Cumulative counts never fall.
        let counts: Vec<u64> = text
            .lines()
            .filter(|l| l.contains("_bucket"))
            .map(|l| l.rsplit(' ').next().unwrap().parse().unwrap())
            .collect();
        assert!(counts.windows(2).all(|w| w[0] <= w[1]), "{counts:?}");
        // What came after a snapshot.
        h.observe(Duration::from_micros(700));
        let d = h.snapshot().since(&c);
        assert_eq!((d.count(), d.quantile_bound(1.0)), (1, 0.001));
    }
}
