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

/// Every counter the daemon exports.
#[derive(Default)]
pub struct Metrics {
    pub frames_captured: AtomicU64,
    pub frames_processed: AtomicU64,
    /// Frames the source delivered while the previous one was still waiting to be processed.
    pub frames_dropped: AtomicU64,
    pub source_errors: AtomicU64,
    pub lightsets_published: AtomicU64,
    pub ws_clients: AtomicU64,
    pub ws_connections_total: AtomicU64,
    pub ws_messages_sent: AtomicU64,
    pub ws_bytes_sent: AtomicU64,
    /// Clients dropped because they stopped reading for longer than the send timeout.
    pub ws_clients_stalled: AtomicU64,
    pub http_lights_requests: AtomicU64,
    pub http_lights_errors: AtomicU64,
    pub stage_capture: StageTimer,
    pub stage_resample: StageTimer,
    pub stage_warp: StageTimer,
    pub stage_assign: StageTimer,
    /// The L2 spherical-harmonic projection of the domain image.
    pub stage_sh: StageTimer,
    pub stage_filter: StageTimer,
    pub stage_publish: StageTimer,
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
            "# HELP vemlight_stage_seconds Time spent per pipeline stage."
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
        s
    }
}
