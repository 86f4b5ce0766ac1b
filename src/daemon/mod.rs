//! The capture daemon's pipeline: frames from a [`FrameSource`] → domain image → lights per light
//! count → temporal filter → LightSet documents published into the [`Hub`], which the server reads
//! (DESIGN.md, "The pipeline").
//!
//! Threads: one reads frames and resamples each into the domain square (a streaming source's, such
//! as a camera pipe's, a batch of rows at a time as they arrive, so that little is left when the
//! last row is in), into a one-slot mailbox (a frame not yet taken when the next arrives is dropped
//! and counted); one takes the newest frame, extracts lights for every light count clients ask for
//! (one warp shared by all), filters each id over time and publishes. Publication is latest-state
//! (a `watch` channel per light count): a slow reader skips sets and never holds up the capture
//! loop.

pub mod hub;

pub use hub::{Hub, Published, SourceHealth, SourceState, StreamKey, Subscription, stall_after};

use crate::capture::{FrameSource, SourceError};
use crate::envmap::{EnvMap, Projection};
use crate::lights::budget::{self, AdaptiveCount};
use crate::lights::error::IrradianceReference;
use crate::lights::{Extraction, Extractor, FrameLights, FrameRequest, Method};
use crate::lightset::{LightSet, Timings, default_domain, now_ns};
use crate::mapping::Domain;
use crate::metrics::Metrics;
use crate::sampling::{DomainImage, Resampler};
use crate::temporal::{FilterInfo, FilterSpec, TemporalFilter};
use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

/// Most distinct light counts the daemon serves at once: each costs one assignment pass a frame.
pub const MAX_LIGHT_COUNTS: usize = 16;

/// How the pipeline turns frames into light sets.
#[derive(Clone, Debug)]
pub struct PipelineConfig {
    pub method: Method,
    /// `None`: sphere for lat-long sources, upper hemisphere otherwise.
    pub domain: Option<Domain>,
    pub filter: FilterSpec,
    pub sh9: bool,
    /// Threads for resampling a whole frame (a streaming source's rows are resampled as they
    /// arrive, on the capture thread). One by default: the capture thread has just written the
    /// frame, and a second thread, started per frame, reads it cold and was measured slower
    /// (docs/PERFORMANCE.md).
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
            filter: FilterSpec::default(),
            sh9: true,
            threads: 1,
            refine: crate::lights::DEFAULT_REFINE,
            video: true,
        }
    }
}

/// A captured frame, already resampled into the domain square: waiting for processing, then kept
/// as the last frame to serve light counts asked for after it.
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
                    h.state = SourceState::Running;
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
                hub.set_health(|h| h.state = SourceState::Ended);
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
                    h.state = SourceState::Failed;
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
        streams: HashMap::new(),
        filter_info: FilterInfo::new(&cfg.filter, fps),
    };
    p.extractor.set_refine(cfg.refine);
    // One camera's frames: each frame's lights start from the last frame's.
    p.extractor.set_video(cfg.video);
    // The newest processed frame, kept to serve light counts asked for after it.
    let mut last: Option<Frame> = None;
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
                if last.is_some() && !hub.unserved_keys().is_empty() {
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
            // No new frame for a while: serve the counts nobody has a set for from the last one
            // (its resampling is not part of these sets' latency).
            let keys = hub.unserved_keys();
            if let Some(l) = &last {
                p.publish(hub, cfg, source, l, Duration::ZERO, &keys);
            }
            continue;
        };
        let keys = hub.keys();
        // Forget the state (filter, count, marks) of streams nobody asks for any more.
        p.streams.retain(|k, _| keys.contains(k));
        p.publish(hub, cfg, source, &frame, frame.resample_tail, &keys);
        Metrics::inc(&hub.metrics.frames_processed);
        let mut s = mailbox.slot.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(older) = last.replace(frame) {
            s.spare.push(older.map);
            s.spare_images.push(older.image);
        }
    }
}

/// The processing thread's state across frames: extraction caches and each stream's state.
struct Processor {
    extractor: Extractor,
    streams: HashMap<StreamKey, StreamState>,
    filter_info: FilterInfo,
}

/// One stream's state across frames.
struct StreamState {
    filter: TemporalFilter,
    /// The light count `filter` has history for.
    filter_count: usize,
    seq: u64,
    /// The count of a stream with an error target.
    adaptive: Option<AdaptiveCount>,
    /// The ids marked for shadow maps in the last set (see [`budget::mark`]).
    marked: Vec<u32>,
}

impl Processor {
    /// Extracts what each stream of `keys` needs from `frame`, filters it, builds each stream's
    /// LightSet and publishes it.
    fn publish(
        &mut self,
        hub: &Hub,
        cfg: &PipelineConfig,
        source: &str,
        frame: &Frame,
        resample_tail: Duration,
        keys: &[StreamKey],
    ) {
        let m = &hub.metrics;
        // The counts this frame needs: each stream's own, and what an adaptive stream needs to
        // choose its count (see `AdaptiveCount`).
        let mut counts: Vec<usize> = Vec::new();
        for key in keys {
            match (self.streams.get(key), key.max_error()) {
                (
                    Some(StreamState {
                        adaptive: Some(a), ..
                    }),
                    _,
                ) => counts.extend(a.counts_needed()),
                (None, Some(target)) => {
                    counts.extend(AdaptiveCount::new(key.lights, target).counts_needed())
                }
                _ => counts.push(key.lights),
            }
        }
        counts.sort_unstable();
        counts.dedup();
        let FrameLights {
            extractions,
            sh9,
            sh9_s,
        } = self.extractor.extract_frame(
            &frame.map,
            &frame.image,
            &FrameRequest {
                method: cfg.method,
                counts: &counts,
                sh9: cfg.sh9 || keys.iter().any(|k| k.shadowed.is_some()),
            },
        );
        if let Some(first) = extractions.first() {
            m.stage_warp.record_secs(first.timings.warp_s);
        }
        m.stage_sh.record_secs(sh9_s);
        for ex in &extractions {
            m.stage_assign.record_secs(ex.timings.assign_s);
        }
        let by_count: HashMap<usize, &Extraction> =
            counts.iter().copied().zip(&extractions).collect();
        // The irradiance reference of the adaptive streams' error estimates, made once a frame.
        let mut reference: Option<IrradianceReference> = None;
        for &key in keys {
            let t = Instant::now();
            let st = self.streams.entry(key).or_insert_with(|| StreamState {
                filter: TemporalFilter::new(&cfg.filter),
                filter_count: 0,
                seq: 0,
                adaptive: key.max_error().map(|e| AdaptiveCount::new(key.lights, e)),
                marked: Vec::new(),
            });
            let (count, estimated_error) = match &mut st.adaptive {
                Some(adaptive) => {
                    let reference = reference.get_or_insert_with(|| {
                        IrradianceReference::from_domain_image(&frame.image)
                    });
                    let before = adaptive.count();
                    let served = adaptive.update(|n| {
                        by_count
                            .get(&n)
                            .map(|ex| reference.error(&ex.lights).rel_rms)
                    });
                    if before != 0 && adaptive.count() != before {
                        Metrics::inc(&m.adaptive_count_changes);
                    }
                    served
                }
                None => (key.lights, None),
            };
            let Some(ex) = by_count.get(&count) else {
                continue;
            };
            if st.filter_count != count {
                // Another count's ids are other lights: its history does not carry over.
                st.filter = TemporalFilter::new(&cfg.filter);
                st.filter_count = count;
            }
            let lights = st.filter.filter(&ex.lights);
            m.stage_filter.record(t.elapsed());
            let t = Instant::now();
            st.seq += 1;
            let mut set = LightSet::new(
                lights,
                &frame.map,
                cfg.method,
                frame.domain,
                source,
                count,
                ex.side,
            );
            set.seq = st.seq;
            set.frame = frame.index;
            set.t_capture_ns = frame.t_capture_ns;
            if cfg.sh9 {
                set.sh9 = sh9.clone();
            }
            if let Some(target) = key.max_error() {
                let d = &mut set.diagnostics;
                d.lights_requested = key.lights;
                d.lights_chosen = Some(count);
                d.estimated_error = estimated_error;
                d.max_error = Some(target);
                d.max_error_met = estimated_error.map(|e| e <= target);
            }
            if let (Some(k), Some(sh9)) = (key.shadowed, &sh9) {
                st.marked = budget::mark(&mut set.lights, k, &st.marked);
                set.sh9_unshadowed = Some(budget::remainder_sh(sh9, &set.lights));
            }
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
                    key,
                    Arc::new(Published {
                        seq: st.seq,
                        frame: frame.index,
                        t_capture_ns: frame.t_capture_ns,
                        captured_at: frame.captured_at,
                        json: json.into_bytes().into(),
                    }),
                ),
                Err(e) => tracing::error!("cannot serialise a light set: {e}"),
            }
            Metrics::inc(&m.lightsets_published);
            m.stage_publish.record(t.elapsed());
        }
    }
}
