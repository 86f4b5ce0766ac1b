//! The daemon's capture → extract → filter → publish loop, and the [`Hub`] through which the
//! server reads what it publishes.

use super::{FrameSource, SourceError};
use crate::envmap::{EnvMap, Projection};
use crate::lights::{Extractor, Method};
use crate::lightset::{LightSet, Timings, default_domain, now_ns};
use crate::metrics::Metrics;
use crate::sampling::{Domain, DomainImage, N_MAX, Resampler};
use crate::temporal::{FilterInfo, FilterSpec, TemporalFilter};
use std::collections::{BTreeMap, HashMap};
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// How the pipeline turns frames into light sets.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    pub method: Method,
    /// `None`: sphere for lat-long sources, upper hemisphere otherwise.
    pub domain: Option<Domain>,
    /// Light count published even with no client (and served by `/v1/lights/latest`).
    pub default_lights: usize,
    pub filter: FilterSpec,
    pub sh9: bool,
    /// Most distinct light counts served at once (each costs one assignment pass per frame).
    pub max_light_counts: usize,
    /// Threads for resampling a whole frame (a streaming source's rows are resampled as they
    /// arrive, on the capture thread). One by default: the capture thread has just written the
    /// frame, and a second thread, started per frame on the other core, reads it cold. At
    /// 1024×512 on this 2-core guest, four interleaved pairs of `cargo bench --bench serve` runs
    /// with the file source: mean resample 1.58 / 1.83 / 1.73 / 1.94 ms on one thread against
    /// 2.08 / 2.30 / 2.10 / 2.23 ms on two.
    pub threads: usize,
    /// Extra Lloyd steps of the voronoi method (see `Extractor::set_refine`).
    pub refine: usize,
    /// Each frame's lights start from the last frame's (`Extractor::set_video`; on by default,
    /// off to get exactly what `vemlight lights` gives for each frame).
    pub video: bool,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        PipelineConfig {
            method: Method::Voronoi,
            domain: None,
            default_lights: 64,
            filter: FilterSpec::default(),
            sh9: true,
            max_light_counts: 16,
            threads: 1,
            refine: crate::lights::DEFAULT_REFINE,
            video: true,
        }
    }
}

/// One published LightSet, serialised once for every reader.
#[derive(Debug)]
pub struct Published {
    pub seq: u64,
    pub frame: u64,
    pub t_capture_ns: u64,
    /// When the frame entered the pipeline (for latency measurements in this process).
    pub captured_at: Instant,
    /// The LightSet document, shared by every reader without copying.
    pub json: axum::extract::ws::Utf8Bytes,
}

/// The source's state as `/healthz` reports it.
#[derive(Clone, Debug, serde::Serialize)]
pub struct SourceHealth {
    pub source: String,
    /// "starting", "running", "ended" or "failed".
    pub state: &'static str,
    pub last_error: Option<String>,
    pub frames_captured: u64,
    /// Seconds since the last good frame; `None` before the first.
    pub last_frame_age_s: Option<f64>,
    /// Running, but no good frame for `stall_after_s`: a camera pipe that froze without closing,
    /// say. The last good set is still served, as when the source fails.
    pub stalled: bool,
    /// See [`stall_after`].
    pub stall_after_s: f64,
}

impl SourceHealth {
    /// Running and not stalled: frames are coming.
    pub fn delivering(&self) -> bool {
        self.state == "running" && !self.stalled
    }
}

/// How long a running source may go without a good frame before `/healthz` calls it stalled: ten
/// frame periods, at least 2 s; 5 s for a source with no nominal rate (stdin).
pub fn stall_after(nominal_fps: f64) -> Duration {
    if nominal_fps > 0.0 && nominal_fps.is_finite() {
        Duration::from_secs_f64((10.0 / nominal_fps).max(2.0))
    } else {
        Duration::from_secs(5)
    }
}

struct HealthState {
    source: String,
    state: &'static str,
    last_error: Option<String>,
    frames: u64,
    last_frame: Option<Instant>,
    stall_after: Duration,
}

/// One light count's channel and how many subscribers want it.
struct Channel {
    subscribers: usize,
    tx: watch::Sender<Option<Arc<Published>>>,
}

/// Shared between the pipeline threads and the server: the latest LightSet per light count,
/// metrics and health.
pub struct Hub {
    channels: Mutex<BTreeMap<usize, Channel>>,
    default_lights: usize,
    max_light_counts: usize,
    pub metrics: Arc<Metrics>,
    health: Mutex<HealthState>,
    shutdown: AtomicBool,
    /// Notified on shutdown so per-client loops can close cleanly.
    pub shutdown_tx: watch::Sender<bool>,
}

/// A client's interest in one light count; dropping it tells the pipeline.
pub struct Subscription {
    hub: Arc<Hub>,
    pub lights: usize,
    pub rx: watch::Receiver<Option<Arc<Published>>>,
}

impl Drop for Subscription {
    fn drop(&mut self) {
        let mut ch = self.hub.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = ch.get_mut(&self.lights) {
            c.subscribers = c.subscribers.saturating_sub(1);
            if c.subscribers == 0 && self.lights != self.hub.default_lights {
                ch.remove(&self.lights);
            }
        }
    }
}

impl Hub {
    pub fn new(default_lights: usize, max_light_counts: usize, source: &str) -> Arc<Self> {
        let mut channels = BTreeMap::new();
        channels.insert(
            default_lights,
            Channel {
                subscribers: 0,
                tx: watch::channel(None).0,
            },
        );
        Arc::new(Hub {
            channels: Mutex::new(channels),
            default_lights,
            max_light_counts: max_light_counts.max(1),
            metrics: Arc::new(Metrics::default()),
            health: Mutex::new(HealthState {
                source: source.into(),
                state: "starting",
                last_error: None,
                frames: 0,
                last_frame: None,
                stall_after: stall_after(0.0),
            }),
            shutdown: AtomicBool::new(false),
            shutdown_tx: watch::channel(false).0,
        })
    }

    pub fn default_lights(&self) -> usize {
        self.default_lights
    }

    /// Subscribes to the sets of `lights` lights (1–1024); refused when that would exceed the
    /// number of distinct light counts served at once.
    pub fn subscribe(self: &Arc<Self>, lights: usize) -> Result<Subscription, String> {
        if !(1..=N_MAX).contains(&lights) {
            return Err(format!(
                "lights must be between 1 and {N_MAX}, got {lights}"
            ));
        }
        let mut ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if !ch.contains_key(&lights) && ch.len() >= self.max_light_counts {
            let served: Vec<String> = ch.keys().map(|k| k.to_string()).collect();
            return Err(format!(
                "the daemon already serves {} distinct light counts ({}); ask for one of them",
                ch.len(),
                served.join(", ")
            ));
        }
        let c = ch.entry(lights).or_insert_with(|| Channel {
            subscribers: 0,
            tx: watch::channel(None).0,
        });
        c.subscribers += 1;
        Ok(Subscription {
            hub: self.clone(),
            lights,
            rx: c.tx.subscribe(),
        })
    }

    /// The latest set for the default light count.
    pub fn latest(&self) -> Option<Arc<Published>> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.get(&self.default_lights)
            .and_then(|c| c.tx.borrow().clone())
    }

    fn light_counts(&self) -> Vec<usize> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.keys().copied().collect()
    }

    /// The light counts asked for that have no set yet.
    fn unserved_light_counts(&self) -> Vec<usize> {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        ch.iter()
            .filter(|(_, c)| c.tx.borrow().is_none())
            .map(|(&n, _)| n)
            .collect()
    }

    fn publish(&self, lights: usize, p: Arc<Published>) {
        let ch = self.channels.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(c) = ch.get(&lights) {
            c.tx.send_replace(Some(p));
        }
    }

    pub fn health(&self) -> SourceHealth {
        let h = self.health.lock().unwrap_or_else(|e| e.into_inner());
        SourceHealth {
            source: h.source.clone(),
            state: h.state,
            last_error: h.last_error.clone(),
            frames_captured: h.frames,
            last_frame_age_s: h.last_frame.map(|t| t.elapsed().as_secs_f64()),
            stalled: h.state == "running"
                && h.last_frame.is_some_and(|t| t.elapsed() > h.stall_after),
            stall_after_s: h.stall_after.as_secs_f64(),
        }
    }

    fn set_health(&self, f: impl FnOnce(&mut HealthState)) {
        f(&mut self.health.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// Stops the pipeline threads and tells every client loop to close.
    pub fn shutdown(&self) {
        self.shutdown.store(true, Ordering::SeqCst);
        self.shutdown_tx.send_replace(true);
    }

    pub fn is_shut_down(&self) -> bool {
        self.shutdown.load(Ordering::SeqCst)
    }
}

/// A captured frame waiting for processing, already resampled into the domain square.
struct Frame {
    map: EnvMap,
    image: DomainImage,
    domain: Domain,
    /// Resampling time after the frame's last rows arrived (all of it for a whole-frame source).
    resample_tail: Duration,
    index: u64,
    t_capture_ns: u64,
    /// When the frame's last rows were in (the start of its end-to-end latency).
    captured_at: Instant,
}

/// The one-slot mailbox between the capture and the processing thread: newest frame wins.
#[derive(Default)]
struct Mailbox {
    slot: Mutex<MailboxState>,
    ready: Condvar,
}

#[derive(Default)]
struct MailboxState {
    frame: Option<Frame>,
    /// Maps and images handed back by the processing thread for reuse.
    spare: Vec<EnvMap>,
    spare_images: Vec<DomainImage>,
}

/// Starts the capture and processing threads. Capture runs until the source ends or fails for
/// good; processing until [`Hub::shutdown`], serving light counts asked for later from the last
/// frame.
pub fn spawn(
    mut source: Box<dyn FrameSource>,
    hub: Arc<Hub>,
    cfg: PipelineConfig,
) -> std::io::Result<()> {
    let mailbox = Arc::new(Mailbox::default());
    let fps = source.nominal_fps();
    let source_name = source.describe();
    hub.set_health(|h| h.stall_after = stall_after(fps));

    let (mb, h, c) = (mailbox.clone(), hub.clone(), cfg.clone());
    std::thread::Builder::new()
        .name("vemlight-capture".into())
        .spawn(move || capture_loop(source.as_mut(), &h, &mb, &c))?;

    std::thread::Builder::new()
        .name("vemlight-extract".into())
        .spawn(move || process_loop(&hub, &mailbox, &cfg, fps, &source_name))?;
    Ok(())
}

/// Resamples each frame into the domain square on the capture thread, batch by batch as a
/// streaming source's rows arrive ([`FrameSource::next_frame_by_rows`]), so that the processing
/// thread starts from the image; a whole-frame source is resampled on `cfg.threads` threads.
struct CaptureResampler {
    domain: Option<Domain>,
    threads: usize,
    resampler: Option<Resampler>,
}

impl CaptureResampler {
    /// Takes the rows `rows` of `map`, which arrived just now; returns the frame's domain once
    /// its last rows are in.
    fn rows(&mut self, map: &EnvMap, rows: Range<usize>, image: &mut DomainImage) -> Domain {
        let domain = self
            .domain
            .unwrap_or_else(|| default_domain(&map.projection));
        let r = Resampler::reuse(&mut self.resampler, map, domain, None, self.threads);
        if rows.start == 0 && rows.end == map.height {
            r.resample_into(map, image);
            return domain;
        }
        if rows.start == 0 {
            r.begin_rows(image);
        }
        r.add_rows(map, rows.clone(), image);
        if rows.end == map.height {
            r.finish_rows(image);
        }
        domain
    }
}

fn capture_loop(source: &mut dyn FrameSource, hub: &Hub, mailbox: &Mailbox, cfg: &PipelineConfig) {
    let mut index = 0u64;
    let mut resampler = CaptureResampler {
        domain: cfg.domain,
        threads: cfg.threads,
        resampler: None,
    };
    let blank = || EnvMap {
        width: 0,
        height: 0,
        pixels: Vec::new(),
        projection: Projection::LatLong,
        repairs: Default::default(),
    };
    while !hub.is_shut_down() {
        let (mut map, mut image) = {
            let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
            let map = s.spare.pop().unwrap_or_else(blank);
            (map, s.spare_images.pop().unwrap_or_else(DomainImage::empty))
        };
        let t = Instant::now();
        // (when the last rows were in, its wall-clock time, the frame's domain, the resampling
        // after that)
        let mut complete: Option<(Instant, u64, Domain, Duration)> = None;
        let result = source.next_frame_by_rows(&mut map, &mut |m, rows| {
            let arrived = (rows.end == m.height).then(|| (Instant::now(), now_ns()));
            let domain = resampler.rows(m, rows, &mut image);
            if let Some((at, at_ns)) = arrived {
                complete = Some((at, at_ns, domain, at.elapsed()));
            }
        });
        hub.metrics.stage_capture.record(t.elapsed());
        match result {
            Ok(true) => {
                let Some((captured_at, t_capture_ns, domain, resample_tail)) = complete else {
                    // A source that broke the contract (no last rows): nothing to process.
                    tracing::error!("the source returned a frame without its last rows");
                    Metrics::inc(&hub.metrics.source_errors);
                    let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
                    s.spare.push(map);
                    s.spare_images.push(image);
                    continue;
                };
                hub.metrics.stage_resample.record(resample_tail);
                Metrics::inc(&hub.metrics.frames_captured);
                hub.set_health(|h| {
                    h.state = "running";
                    h.frames += 1;
                    h.last_frame = Some(Instant::now());
                });
                let frame = Frame {
                    map,
                    image,
                    domain,
                    resample_tail,
                    index,
                    t_capture_ns,
                    captured_at,
                };
                index += 1;
                let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
                if let Some(old) = s.frame.replace(frame) {
                    Metrics::inc(&hub.metrics.frames_dropped);
                    s.spare.push(old.map);
                    s.spare_images.push(old.image);
                }
                mailbox.ready.notify_one();
            }
            Ok(false) => {
                tracing::info!("source ended; serving the last light set");
                hub.set_health(|h| h.state = "ended");
                break;
            }
            Err(SourceError::BadFrame(e)) => {
                Metrics::inc(&hub.metrics.source_errors);
                tracing::warn!("skipping a bad frame: {e}");
                hub.set_health(|h| h.last_error = Some(e));
                let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
                s.spare.push(map);
                s.spare_images.push(image);
            }
            Err(SourceError::Fatal(e)) => {
                Metrics::inc(&hub.metrics.source_errors);
                tracing::error!("source failed: {e}; serving the last light set");
                hub.set_health(|h| {
                    h.state = "failed";
                    h.last_error = Some(e);
                });
                break;
            }
        }
    }
}

/// How often the processing thread, with no new frame, looks for light counts that clients ask
/// for and that have no set yet (the source has ended, failed or stalled): those are served from
/// the last frame.
const UNSERVED_POLL: Duration = Duration::from_millis(50);

fn process_loop(hub: &Hub, mailbox: &Mailbox, cfg: &PipelineConfig, fps: f64, source: &str) {
    let mut p = Processor {
        extractor: Extractor::new(),
        filters: HashMap::new(),
        seqs: HashMap::new(),
        filter_info: FilterInfo::new(&cfg.filter, fps),
    };
    p.extractor.set_refine(cfg.refine);
    // One camera's frames: each frame's lights start from the last frame's.
    p.extractor.set_video(cfg.video);
    // The newest processed frame (its image stays in the extractor).
    let mut last: Option<LastFrame> = None;
    loop {
        let frame = {
            let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
            loop {
                if hub.is_shut_down() {
                    return;
                }
                if let Some(f) = s.frame.take() {
                    break Some(f);
                }
                if last.is_some() && !hub.unserved_light_counts().is_empty() {
                    break None;
                }
                s = mailbox
                    .ready
                    .wait_timeout(s, UNSERVED_POLL)
                    .unwrap_or_else(|e| e.into_inner())
                    .0;
            }
        };
        let Some(frame) = frame else {
            // No new frame for a while: serve the counts nobody has a set for from the last one.
            let counts = hub.unserved_light_counts();
            if let Some(l) = &last {
                let extractions = p
                    .extractor
                    .extract_many_resampled(&l.map, cfg.method, &counts);
                p.publish(hub, cfg, source, l, Duration::ZERO, &counts, extractions);
            }
            continue;
        };
        let Frame {
            map,
            image,
            domain,
            resample_tail,
            index,
            t_capture_ns,
            captured_at,
        } = frame;
        let counts = hub.light_counts();
        let previous_image = p.extractor.put_image(image);
        let extractions = p
            .extractor
            .extract_many_resampled(&map, cfg.method, &counts);
        if let Some(first) = extractions.first() {
            hub.metrics.stage_warp.record_secs(first.timings.warp_s);
        }
        // Forget the filter state of light counts nobody asks for any more.
        p.filters.retain(|n, _| counts.contains(n));
        let this = LastFrame {
            map,
            domain,
            index,
            t_capture_ns,
            captured_at,
        };
        p.publish(hub, cfg, source, &this, resample_tail, &counts, extractions);
        Metrics::inc(&hub.metrics.frames_processed);
        let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(older) = last.replace(this) {
            s.spare.push(older.map);
        }
        s.spare_images.extend(previous_image);
    }
}

/// A processed frame, kept to serve light counts asked for after it.
struct LastFrame {
    map: EnvMap,
    domain: Domain,
    index: u64,
    t_capture_ns: u64,
    captured_at: Instant,
}

/// The processing thread's state across frames: extraction caches, each light count's filter and
/// sequence number.
struct Processor {
    extractor: Extractor,
    filters: HashMap<usize, TemporalFilter>,
    seqs: HashMap<usize, u64>,
    filter_info: FilterInfo,
}

impl Processor {
    /// Filters each light count's extraction of `frame`, builds its LightSet and publishes it.
    #[allow(clippy::too_many_arguments)]
    fn publish(
        &mut self,
        hub: &Hub,
        cfg: &PipelineConfig,
        source: &str,
        frame: &LastFrame,
        resample_tail: Duration,
        counts: &[usize],
        extractions: Vec<crate::lights::Extraction>,
    ) {
        let m = &hub.metrics;
        let t = Instant::now();
        let sh9 = if cfg.sh9 { self.extractor.sh9() } else { None };
        m.stage_sh.record(t.elapsed());
        for (&n, ex) in counts.iter().zip(extractions) {
            m.stage_assign.record_secs(ex.timings.assign_s);
            let t = Instant::now();
            let filter = self
                .filters
                .entry(n)
                .or_insert_with(|| TemporalFilter::new(&cfg.filter));
            let lights = filter.filter(&ex.lights);
            m.stage_filter.record(t.elapsed());

            let t = Instant::now();
            let seq = self.seqs.entry(n).or_insert(0);
            *seq += 1;
            let mut set = LightSet::new(
                lights,
                &frame.map,
                cfg.method,
                frame.domain,
                source,
                n,
                ex.side,
            );
            set.seq = *seq;
            set.frame = frame.index;
            set.t_capture_ns = frame.t_capture_ns;
            set.sh9 = sh9.clone();
            set.filter = Some(self.filter_info.clone());
            // From the frame's last rows in to this document; resampling done while the frame
            // arrived is not in it.
            set.diagnostics.timings_ms = Timings {
                decode: 0.0,
                resample: resample_tail.as_secs_f64() * 1e3,
                warp: ex.timings.warp_s * 1e3,
                assign: ex.timings.assign_s * 1e3,
                total: frame.captured_at.elapsed().as_secs_f64() * 1e3,
            };
            set.t_emit_ns = now_ns();
            match serde_json::to_string(&set) {
                Ok(json) => hub.publish(
                    n,
                    Arc::new(Published {
                        seq: *seq,
                        frame: frame.index,
                        t_capture_ns: frame.t_capture_ns,
                        captured_at: frame.captured_at,
                        json: json.into(),
                    }),
                ),
                Err(e) => tracing::error!("cannot serialise a light set: {e}"),
            }
            Metrics::inc(&m.lightsets_published);
            m.stage_publish.record(t.elapsed());
        }
    }
}
