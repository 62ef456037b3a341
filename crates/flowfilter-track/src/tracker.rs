//! [`Tracker`]: frames pushed one at a time, the object's pose in each relative to the first,
//! measured against keyframes so that drift stays bounded.

use crate::boxed::PixelBox;
use crate::carry::carry_mask;
use crate::region;
use crate::reveal::{self, RevealParams};
use flowfilter_geometry::Pose;
use flowfilter_pipeline::{
    Estimate, PairTrace, Pipeline, PipelineError, PipelineWarning, PreparedFrame, RegistrationSummary,
    RegistrationWarning, RgbdFrame, StageTimes, Uncertainty,
};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// How the tracker keeps keyframes and carries the mask.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrackerConfig {
    /// A frame tracked this many degrees away from its keyframe becomes a keyframe.
    pub keyframe_deg: f64,
    /// ... or its motion's translation (that of the camera frame's origin, so an object turning
    /// about an axis away from the camera counts its turn here too: the bench's turntable loops
    /// get a keyframe every 6-9 deg at the defaults) reaches this many metres.
    pub keyframe_m: f64,
    /// Keyframes kept for recovery after a loss (the first frame always stays).
    pub max_keyframes: usize,
    /// The carried mask: each moved object point covers this many pixels around it.
    pub splat_px: usize,
    /// The carried mask: pixels whose depth differs from the moved object's by more than this
    /// (metres) are dropped.
    pub depth_tolerance_m: f64,
    /// A carried mask smaller than this (pixels) means the object left the view or is hidden.
    pub min_mask_px: usize,
    /// The predicted mask (the previous frame's carried by the constant-velocity motion, each
    /// moved point covering this many pixels around it) the new frame is first estimated with
    /// against the nearest keyframe, so that its cloud is the object's and no mask is
    /// propagated; when that estimate does not converge, the frame is estimated again unmasked
    /// against every candidate. 0: always unmasked.
    pub predicted_splat_px: usize,
    /// Estimate each frame first on the images alone (the aligned path): the direct alignment
    /// (`[align]`, both ways) of the nearest keyframe and the new frame, its object pixels
    /// predicted by the constant-velocity motion, from the predicted pose; kept when the images
    /// confirm it ([`TrackerConfig::aligned_max_score`], [`TrackerConfig::aligned_min_visible`])
    /// and the frame does not become a keyframe (keyframes always come from the full estimate).
    /// Else, and after a loss or an uncertain frame, the full estimate runs. Off by default:
    /// on the real YCB-Video sample it moved the tracks' last frames by -0.01 to +0.27 deg for
    /// 1.3-1.5x the frames per second (`docs/tracking.md`).
    pub aligned_path: bool,
    /// The aligned path's estimate is kept only when the keyframe's texture moved by it
    /// correlates with the new frame's: its photometric score (one minus the normalised
    /// cross-correlation, the judge's) at most this...
    pub aligned_max_score: f64,
    /// ... at least this fraction of the keyframe's compared pixels land where the new frame's
    /// depth agrees (visible), and the alignment lowered its cost from the prediction.
    pub aligned_min_visible: f64,
    /// Consecutive uncertain frames after which the track is lost.
    pub max_uncertain: usize,
    /// After a loss, the keyframes tried per frame (nearest to the last pose first): a lost
    /// frame's cost stays bounded however many keyframes are held.
    pub recovery_tries: usize,
    /// A doubtful estimate whose only doubts a motion prediction can answer (other turns about
    /// an axis fit as well: `ambiguous_pose`, with or without the wide error bounds those turns
    /// bring: `wide_bounds`) is taken as tracking when its pose from the first frame lies within
    /// this many degrees of the constant-velocity prediction (and
    /// [`TrackerConfig::motion_gate_m`]) and every other turn it names is more than three times
    /// this from the estimate, so more than twice this from the prediction: the motion tells the
    /// poses apart where the images do not (a can's lid seen from above). 0: never.
    pub motion_gate_deg: f64,
    /// See [`TrackerConfig::motion_gate_deg`] (metres).
    pub motion_gate_m: f64,
    /// Prepare each frame of an object's stream on the region where the object is predicted
    /// (the previous frame's object moved on by the constant-velocity motion, the path it sweeps
    /// and a margin: [`TrackerConfig::region_margin`]) instead of the whole image: the depth
    /// stage's cost follows the object's size, not the image's. A frame whose object is found
    /// too near the region's edge, or that must be searched without a mask, is prepared whole
    /// then. The region of frame `k` is predicted from the track up to frame `k - 2`, so that
    /// frame `k` can be prepared while frame `k - 1` is estimated ([`Tracker::update_stream`]),
    /// and [`Tracker::update`] prepares it the same way.
    pub prepare_region: bool,
    /// The region's margin on each side: this fraction of the object's larger side in pixels,
    /// plus the pixels one frame's motion moves it.
    pub region_margin: f64,
    /// Grow the carried mask onto the object's surface that turns into view: pixels next to it
    /// whose depth continues it and whose surface the reference frame saw edge-on and that has
    /// turned towards the camera since (a convex object's side). Without it the mask keeps only
    /// what the first frame saw. Off by default: it brings a box seen level with its turntable
    /// round a full turn, but moved the real shelves' regions slightly off (`docs/tracking.md`).
    pub reveal: bool,
    /// Keep what each kept estimate weighed ([`TrackedFrame::traced`]: the frames and the
    /// pipeline's trace), for recordings.
    pub trace: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            keyframe_deg: 10.0,
            keyframe_m: 0.05,
            max_keyframes: 12,
            splat_px: 2,
            depth_tolerance_m: 0.03,
            min_mask_px: 300,
            predicted_splat_px: 4,
            aligned_path: false,
            aligned_max_score: 0.3,
            aligned_min_visible: 0.7,
            max_uncertain: 3,
            recovery_tries: 3,
            motion_gate_deg: 2.0,
            motion_gate_m: 0.01,
            prepare_region: true,
            region_margin: 0.25,
            reveal: false,
            trace: false,
        }
    }
}

impl TrackerConfig {
    /// The settings of a TOML file of [`TrackerConfig`]'s keys (the defaults for the others).
    ///
    /// # Errors
    /// [`SettingsError`] naming the file: it cannot be read, or a key is unknown or of the wrong
    /// type.
    pub fn from_file(path: &Path) -> Result<Self, SettingsError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| SettingsError::Read { path: path.to_path_buf(), source })?;
        toml::from_str(&text).map_err(|e| SettingsError::Parse { path: path.to_path_buf(), message: e.to_string() })
    }
}

/// Why a file of tracker settings cannot be used ([`TrackerConfig::from_file`]).
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// The file cannot be read.
    #[error("{}: cannot read: {source}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The file is not TOML of the tracker's keys.
    #[error("{}: {message}", path.display())]
    Parse {
        /// The file.
        path: PathBuf,
        /// What the parser says (the key and what it expected).
        message: String,
    },
}

/// The state of the track at a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackState {
    /// A converged estimate against a keyframe (or the previous frame).
    Tracking,
    /// An estimate the pipeline doubts (not converged): the pose is its best, the reason says why.
    Uncertain,
    /// No usable estimate: the pose is held at the last one; the reason says why.
    Lost,
    /// The first converged estimate after a loss, found by matching against the keyframes.
    Recovered,
}

/// One frame's result.
#[derive(Debug, Clone)]
pub struct TrackedFrame {
    /// Position in the stream (0: the first frame).
    pub index: usize,
    /// The frame's label.
    pub label: String,
    /// The object's motion from the first frame (`P_k = pose * P_0`, colour camera frames).
    pub pose: Pose,
    /// The state.
    pub state: TrackState,
    /// Why the state is not `tracking` (or what the estimate warned of).
    pub reason: Option<String>,
    /// The stream index of the frame the pose was measured against.
    pub reference: Option<usize>,
    /// Whether this frame became a keyframe.
    pub keyframe: bool,
    /// The estimate against the reference, when one was made.
    pub estimate: Option<Estimate>,
    /// Bounds on [`TrackedFrame::pose`]'s error, the motion from the first frame: the
    /// reference's own bounds from the first frame and the estimate's against the reference,
    /// composed ([`chained_bound`]); `None` where an estimate along the chain has none (the
    /// aligned path's, a lost frame's held pose).
    pub bound_from_first: Option<Uncertainty>,
    /// Pixels of the object's carried mask (0 in whole-frame mode).
    pub mask_px: usize,
    /// The estimate came from the aligned path: direct alignment from the motion's prediction,
    /// confirmed on the images, without flow, registration or judge
    /// ([`TrackerConfig::aligned_path`]).
    pub aligned_only: bool,
    /// With [`TrackerConfig::trace`]: the reference and this frame as prepared, and what the
    /// pipeline weighed between them.
    pub traced: Option<Box<TracedPair>>,
    /// The part of the image the frame was prepared on
    /// ([`TrackerConfig::prepare_region`]); `None`: the whole image.
    pub prepared_region: Option<PixelBox>,
}

/// A kept estimate's inputs and trace.
#[derive(Debug, Clone)]
pub struct TracedPair {
    /// The reference frame (a keyframe or the previous frame), prepared.
    pub model: PreparedFrame,
    /// This frame, prepared.
    pub target: PreparedFrame,
    /// What the pipeline weighed.
    pub trace: PairTrace,
}

impl TrackedFrame {
    /// The frame's result as an estimate of the motion from the first frame (`first`, its
    /// label) to this one: the estimate against the reference with its transform replaced by
    /// the motion from the first frame and its uncertainty by the bounds from the first frame
    /// (`bound_from_first`; none without them), converged only when tracking or recovered; for
    /// a frame without an estimate (lost), the held pose, not converged, the reason as a
    /// warning-free estimate of `method`.
    pub fn from_first(&self, first: &str, method: &str) -> Estimate {
        let trusted = matches!(self.state, TrackState::Tracking | TrackState::Recovered);
        let mut e = match &self.estimate {
            Some(e) => e.clone(),
            None => Estimate {
                schema: flowfilter_pipeline::ESTIMATE_SCHEMA,
                method: method.to_string(),
                flow_estimator: None,
                model: String::new(),
                target: String::new(),
                transform: [[0.0; 4]; 4],
                rotation_angle_deg: 0.0,
                rotation_axis: [0.0; 3],
                translation_m: [0.0; 3],
                registration: RegistrationSummary {
                    iterations: 0,
                    converged: false,
                    fitness: 0.0,
                    inlier_rmse_m: 0.0,
                    sigma2: None,
                    model_points: 0,
                    target_points: 0,
                    uncertainty: None,
                },
                correspondences: None,
                stage_ms: StageTimes::default(),
                judge: None,
                align: None,
                geometry_first: None,
                warnings: vec![],
                ground_truth: None,
                pose: Pose::identity(),
            },
        };
        e.model = first.to_string();
        e.target.clone_from(&self.label);
        e.registration.converged &= trusted;
        e.registration.uncertainty = self.bound_from_first;
        e.with_pose(self.pose)
    }
}

/// A keyframe: a frame prepared with the object's mask, and its pose from the first frame.
struct Keyframe {
    index: usize,
    frame: PreparedFrame,
    pose: Pose,
    /// Its pose rests on an uncertain frame ([`Previous::doubtful`]).
    doubtful: bool,
    /// Bounds on its pose's error ([`TrackedFrame::bound_from_first`]).
    bound: Option<Uncertainty>,
}

/// The previous frame, prepared with the object's mask, when it was tracked.
struct Previous {
    index: usize,
    frame: PreparedFrame,
    pose: Pose,
    /// Its pose rests on a doubtful estimate: it was uncertain, or it converged against a
    /// frame whose pose does.
    doubtful: bool,
    /// Bounds on its pose's error ([`TrackedFrame::bound_from_first`]).
    bound: Option<Uncertainty>,
}

/// An estimate that did not converge, kept in case no other does.
struct Doubtful {
    reference: usize,
    estimate: Estimate,
    reference_pose: Pose,
    traced: Option<Box<TracedPair>>,
}

impl Doubtful {
    /// The estimate's rotation bound (degrees; unbounded without one).
    fn bound_deg(&self) -> f64 {
        self.estimate.registration.uncertainty.map_or(f64::INFINITY, |u| u.rotation_deg)
    }
}

/// Whether no warning says the clouds do not support the estimate.
fn plausible(e: &Estimate) -> bool {
    !e.warnings.iter().any(PipelineWarning::is_implausible)
}

/// Keyframes tried first: this many nearest to the last pose.
const NEAREST_KEYFRAMES: usize = 2;

/// Bounds on a pose from the first frame `e.pose * T_0r` given bounds on the reference's pose
/// `T_0r` (`reference`) and the estimate's own (`e.pose`, against the reference), each meant
/// to hold on 90% of estimates: their errors compose as independent errors do, in root sum of
/// squares, the rotation bounds and the translation bounds, the latter with the reference's
/// rotation bound (radians) times the estimate's translation (a turn error of the reference
/// moves the estimate's translation with it). Along a chain of `n` estimates of like bounds
/// `b` that is `b sqrt(n)`, drift's growth; their plain sum (`n b`, what holds whenever every
/// bound does) held on every frame of the SR300 twin's loops at a median of 21-56 deg
/// (`docs/tracking.md`). `None` when either has none.
pub fn chained_bound(reference: Option<Uncertainty>, e: &Estimate) -> Option<Uncertainty> {
    let (r, own) = (reference?, e.registration.uncertainty?);
    let lever = r.rotation_deg.to_radians() * e.pose.translation.vector.norm();
    Some(Uncertainty {
        rotation_deg: r.rotation_deg.hypot(own.rotation_deg),
        translation_m: (r.translation_m.powi(2) + own.translation_m.powi(2) + lever.powi(2)).sqrt(),
    })
}

/// How far apart two poses are: degrees of rotation plus centimetres of translation.
fn pose_distance(a: &Pose, b: &Pose) -> f64 {
    let d = a.inverse() * b;
    d.rotation.angle().to_degrees() + 100.0 * d.translation.vector.norm()
}

/// Why a tracker cannot start.
#[derive(Debug, thiserror::Error)]
pub enum TrackError {
    /// The first frame cannot be prepared (no depth in its mask, a camera that does not fit).
    #[error("the first frame: {0}")]
    FirstFrame(#[source] PipelineError),
}

/// Tracks one object (or the whole scene, without a mask) through a stream of RGB-D frames of
/// one camera: each frame is prepared once, estimated against the current keyframe (falling
/// back to the previous frame), and gets a state and a reason; after a loss every keyframe is
/// tried.
pub struct Tracker {
    pipeline: Arc<Pipeline>,
    config: TrackerConfig,
    keyframes: Vec<Keyframe>,
    current: usize,
    previous: Option<Previous>,
    /// Whether an object is tracked (a mask given with the first frame).
    object: bool,
    size: (usize, usize),
    next: usize,
    last_pose: Pose,
    /// The motion between the last two tracked frames (`T_0k * inv(T_0,k-1)`), for the
    /// prediction that picks the nearest keyframes.
    velocity: Pose,
    lost: bool,
    uncertain_run: usize,
    /// The keyframe the aligned path last failed against ([`TrackerConfig::aligned_path`]).
    unconfirmed: Option<usize>,
    /// The regions the next frame and the one after it are prepared on
    /// ([`TrackerConfig::prepare_region`]; `None`: whole).
    regions: [Option<PixelBox>; 2],
}

/// Prepares a stream's frames for its [`Tracker`] ([`Tracker::preparer`]); cheap to clone,
/// usable from another thread.
#[derive(Clone)]
pub struct StreamPreparer {
    pipeline: Arc<Pipeline>,
    size: (usize, usize),
    /// The region frames are prepared on ([`TrackerConfig::prepare_region`]; `None`: whole).
    region: Option<PixelBox>,
}

/// A frame prepared by a [`StreamPreparer`], or why it could not be (its file could not be read,
/// another size than the stream's, no usable depth).
pub struct ReadyFrame {
    label: Option<String>,
    prepared: Result<PreparedFrame, String>,
    /// Where only a region of the frame was prepared: the region, and the frame itself (to
    /// prepare it whole when the object lies beyond the region or the frame is searched unmasked).
    region: Option<(PixelBox, RgbdFrame)>,
}

impl StreamPreparer {
    /// The frame prepared as [`Tracker::update`] prepares it (never fails: a frame that cannot
    /// be used carries the reason, and the tracker reports it `lost`): on the preparer's region
    /// when the frame comes without a mask of its own and the region holds depth, else whole.
    pub fn prepare(&self, frame: Result<RgbdFrame, String>) -> ReadyFrame {
        let label = frame.as_ref().ok().map(|f| f.label.clone());
        let frame = match frame.and_then(|f| self.of_size(f)) {
            Ok(frame) => frame,
            Err(reason) => return ReadyFrame { label, prepared: Err(reason), region: None },
        };
        match self.region.filter(|_| flowfilter_pipeline::frame_checks::is_unmasked(&frame)) {
            Some(region) => self.prepare_on(region, frame, label),
            None => self.prepare_whole(&frame, label),
        }
    }

    fn prepare_whole(&self, frame: &RgbdFrame, label: Option<String>) -> ReadyFrame {
        ReadyFrame { label, prepared: self.pipeline.prepare(frame).map_err(|e| e.to_string()), region: None }
    }

    /// The frame prepared on `region` (whole when the region holds no usable depth).
    fn prepare_on(&self, region: PixelBox, mut frame: RgbdFrame, label: Option<String>) -> ReadyFrame {
        // The frame came without a mask (the whole image, or, from a registered sensor, every
        // pixel with depth): the region's every pixel, so that the depth stage fills its holes.
        let on = region.mask(frame.mask.dims());
        let own = std::mem::replace(&mut frame.mask, on);
        let on_region = self.pipeline.prepare(&frame);
        frame.mask = own;
        match on_region {
            Ok(prepared) => ReadyFrame { label, prepared: Ok(prepared), region: Some((region, frame)) },
            Err(_) => self.prepare_whole(&frame, label),
        }
    }

    fn of_size(&self, frame: RgbdFrame) -> Result<RgbdFrame, String> {
        of_stream_size((frame.color.width() as usize, frame.color.height() as usize), self.size).map(|()| frame)
    }
}

/// A frame to track: as prepared, and, where only a region of it was, the region and the frame.
struct Target {
    prepared: PreparedFrame,
    region: Option<(PixelBox, RgbdFrame)>,
}

impl Target {
    /// A frame prepared whole.
    fn whole(prepared: PreparedFrame) -> Self {
        Self { prepared, region: None }
    }

    /// The frame prepared whole: as it is when it was, else prepared now (the region's
    /// preparation when that fails).
    fn into_whole(self, pipeline: &Pipeline) -> PreparedFrame {
        match self.region {
            None => self.prepared,
            Some((_, frame)) => pipeline.prepare(&frame).unwrap_or(self.prepared),
        }
    }

    /// Whether `mask` lies within the prepared part of the frame.
    fn holds(&self, mask: &flowfilter_geometry::Mask) -> bool {
        self.region.as_ref().is_none_or(|(r, _)| region::holds(r, mask))
    }
}

/// Why a frame of `size` does not belong to a stream of `stream` pixels, if it does not.
fn of_stream_size(size: (usize, usize), stream: (usize, usize)) -> Result<(), String> {
    if size == stream {
        return Ok(());
    }
    Err(format!("a frame of another size: {}x{}, the stream's is {}x{}", size.0, size.1, stream.0, stream.1))
}

impl Tracker {
    /// Start with the first frame: its mask is the object's (a mask covering the frame tracks the
    /// whole scene).
    ///
    /// # Errors
    /// [`TrackError::FirstFrame`] when the first frame cannot be prepared.
    ///
    /// ```
    /// use flowfilter_bigbird::SensorId;
    /// use flowfilter_pipeline::{Pipeline, PipelineConfig, RgbdFrame};
    /// use flowfilter_synth::{Rig, Scene, procedural, render_frame};
    /// use flowfilter_track::{TrackState, Tracker, TrackerConfig};
    ///
    /// let (rig, sensor) = (Rig::bigbird_like(), SensorId::new(3).unwrap());
    /// let scene = Scene::new(procedural("box", 1)?.placed_on_table(0.01, -0.005), 1);
    /// let frame = |angle| {
    ///     let f = render_frame(&scene, &rig, sensor, angle, None, 7);
    ///     let sensor = rig.sensors[&sensor].rgbd;
    ///     RgbdFrame { label: format!("NP3_{angle}"), color: f.color, depth: f.raw_depth, mask: f.mask, sensor }
    /// };
    /// let pipeline = Pipeline::from_config(PipelineConfig::default())?;
    /// let mut tracker = Tracker::new(pipeline, TrackerConfig::default(), &frame(0))?;
    /// let mut unmasked = frame(4);
    /// unmasked.mask.as_mut_slice().fill(true); // later frames need no mask
    /// let tracked = tracker.update(Ok(unmasked));
    /// assert_eq!(tracked.state, TrackState::Tracking);
    /// assert!((tracked.pose.rotation.angle().to_degrees() - 4.0).abs() < 1.0);
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn new(pipeline: Pipeline, config: TrackerConfig, first: &RgbdFrame) -> Result<Self, TrackError> {
        let frame = pipeline.prepare(first).map_err(TrackError::FirstFrame)?;
        let object = !frame.unmasked;
        let size = frame.gray.dims();
        let previous = Previous {
            index: 0,
            frame: frame.clone(),
            pose: Pose::identity(),
            doubtful: false,
            bound: Some(Uncertainty::EXACT),
        };
        let mut tracker = Self {
            pipeline: Arc::new(pipeline),
            config,
            keyframes: vec![Keyframe {
                index: 0,
                frame,
                pose: Pose::identity(),
                doubtful: false,
                bound: Some(Uncertainty::EXACT),
            }],
            current: 0,
            previous: Some(previous),
            object,
            size,
            next: 1,
            last_pose: Pose::identity(),
            velocity: Pose::identity(),
            lost: false,
            uncertain_run: 0,
            unconfirmed: None,
            regions: [None, None],
        };
        tracker.regions = [tracker.region_ahead(1), tracker.region_ahead(2)];
        Ok(tracker)
    }

    /// The first frame's result (identity, tracking, a keyframe).
    pub fn first(&self) -> TrackedFrame {
        let k = &self.keyframes[0];
        TrackedFrame {
            index: 0,
            label: k.frame.label.clone(),
            pose: Pose::identity(),
            state: TrackState::Tracking,
            reason: None,
            reference: None,
            keyframe: true,
            estimate: None,
            bound_from_first: Some(Uncertainty::EXACT),
            mask_px: if self.object { k.frame.mask.count() } else { 0 },
            aligned_only: false,
            traced: None,
            prepared_region: None,
        }
    }

    /// The next frame of the stream, or why it could not be read (a missing file): its result.
    /// Never fails: a frame that cannot be used is `lost`, with the reason.
    pub fn update(&mut self, frame: Result<RgbdFrame, String>) -> TrackedFrame {
        let ready = self.preparer().prepare(frame);
        self.update_prepared(ready)
    }

    /// [`Tracker::update`] on every frame of `frames`, each result handed to `each` in order
    /// with the value that came with its frame (what the caller keeps beside it, e.g. its
    /// colour image for an overlay). Frame k + 1 is read (the iterator's step) and prepared on
    /// the second core while frame k is estimated: the results are `update`'s, the stream's
    /// time nearly that of the estimates alone. Stops at the first error `each` returns.
    ///
    /// # Errors
    /// What `each` returns.
    pub fn update_stream<T: Send, E>(
        &mut self,
        frames: impl Iterator<Item = (T, Result<RgbdFrame, String>)> + Send,
        mut each: impl FnMut(T, TrackedFrame) -> Result<(), E>,
    ) -> Result<(), E> {
        let mut frames = frames;
        let first = self.preparer();
        let mut next = frames.next().map(|(kept, frame)| (kept, first.prepare(frame)));
        while let Some((kept, ready)) = next.take() {
            let ahead = self.preparer_ahead();
            let read = || frames.next().map(|(kept, frame)| (kept, ahead.prepare(frame)));
            let (tracked, upcoming) = rayon::join(|| self.update_prepared(ready), read);
            next = upcoming;
            each(kept, tracked)?;
        }
        Ok(())
    }

    /// A handle that prepares the next frame as [`Tracker::update`] does, apart from the
    /// tracker ([`Tracker::update_prepared`] then takes it). The results are the same as
    /// `update`'s.
    pub fn preparer(&self) -> StreamPreparer {
        StreamPreparer { pipeline: Arc::clone(&self.pipeline), size: self.size, region: self.regions[0] }
    }

    /// A handle that prepares the frame after the next one as [`Tracker::update`] will: it can
    /// be read and prepared on another thread while the tracker estimates the next one
    /// ([`Tracker::update_stream`] runs so; the region a frame is prepared on is predicted from
    /// the track up to two frames before it, [`TrackerConfig::prepare_region`]).
    pub fn preparer_ahead(&self) -> StreamPreparer {
        StreamPreparer { pipeline: Arc::clone(&self.pipeline), size: self.size, region: self.regions[1] }
    }

    /// The region the frame `steps` frames after the previous one is prepared on: the previous
    /// frame's object moved on by the constant velocity. `None` (whole) for whole frames, after
    /// a loss, or when [`TrackerConfig::prepare_region`] is off.
    fn region_ahead(&self, steps: u32) -> Option<PixelBox> {
        if !self.config.prepare_region || !self.object || self.lost {
            return None;
        }
        let previous = self.previous.as_ref()?;
        region::predicted(&previous.frame, &self.velocity, steps, self.config.region_margin)
    }

    /// [`Tracker::update`] for a frame its [`Tracker::preparer`] prepared (a frame prepared for
    /// a stream of another size is `lost`, with the reason).
    pub fn update_prepared(&mut self, ready: ReadyFrame) -> TrackedFrame {
        let index = self.next;
        self.next += 1;
        let label = ready.label.unwrap_or_else(|| format!("#{index}"));
        let prepared = ready.prepared.and_then(|p| of_stream_size(p.gray.dims(), self.size).map(|()| p));
        let result = match prepared {
            Ok(prepared) => self.track(index, Target { prepared, region: ready.region }),
            Err(reason) => self.lose(index, reason),
        };
        // The frame after the next is prepared while the next one is estimated: its region
        // comes from the track as it is now.
        self.regions = [self.regions[1], self.region_ahead(2)];
        TrackedFrame { label, ..result }
    }

    /// The first frame as prepared (its cloud is the object's, or the scene's).
    pub fn first_frame(&self) -> &PreparedFrame {
        &self.keyframes[0].frame
    }

    /// The object's mask in the last frame, as the tracker carried it there from its reference
    /// (and grew it onto the surface turning into view, [`TrackerConfig::reveal`]): the pixels
    /// the next frame's mask is predicted from. `None` for whole frames, and after a frame that
    /// was lost.
    pub fn object_mask(&self) -> Option<&flowfilter_geometry::Mask> {
        self.previous.as_ref().filter(|p| self.object && p.index + 1 == self.next).map(|p| &p.frame.mask)
    }

    /// Keyframes held now (stream indices).
    pub fn keyframes(&self) -> Vec<usize> {
        self.keyframes.iter().map(|k| k.index).collect()
    }

    /// The frame estimated against its candidates, its state decided, the keyframes updated:
    /// first with the predicted mask, then (without a converged estimate there) unmasked.
    fn track(&mut self, index: usize, target: Target) -> TrackedFrame {
        // The predicted mask, made once for both paths; the frame prepared whole when that mask
        // leaves the region it was prepared on.
        let mut predicted = self.predicted_target(&target.prepared);
        let target = match &predicted {
            Some(p) if !target.holds(&p.mask) => {
                let whole = target.into_whole(&self.pipeline);
                predicted = self.predicted_target(&whole);
                Target::whole(whole)
            }
            _ => target,
        };
        if let Some((reference, e, reference_pose)) = self.aligned_estimate(index, &target.prepared, predicted.as_ref())
        {
            let mut tracked = self.accept(index, target, reference, e, reference_pose);
            tracked.aligned_only = tracked.state == TrackState::Tracking;
            return tracked;
        }
        let mut fallback = None;
        if let Some(predicted) = predicted
            && let Some((reference, e, reference_pose, pair)) = self.estimated_with(&predicted)
        {
            if e.registration.converged || self.settled_by_motion(&e, &reference_pose) {
                let mut r = self.accept(index, target, reference, e, reference_pose);
                r.traced = pair;
                return r;
            }
            fallback = Some(Doubtful { reference, estimate: e, reference_pose, traced: pair });
        }
        self.track_unmasked(index, target.into_whole(&self.pipeline), fallback)
    }

    /// The aligned path ([`TrackerConfig::aligned_path`]): the frame estimated against the
    /// keyframe nearest to the predicted pose by direct alignment alone, from the prediction:
    /// the reference, the estimate and the reference's pose when the images confirm it (the
    /// frame is then tracked), else `None` (the full estimate runs).
    /// Not after a loss or an uncertain frame, nor without a motion to predict from.
    /// `predicted_frame`: the frame with its predicted mask ([`Tracker::predicted_target`]).
    fn aligned_estimate(
        &mut self,
        index: usize,
        target: &PreparedFrame,
        predicted_frame: Option<&PreparedFrame>,
    ) -> Option<(usize, Estimate, Pose)> {
        let cfg = &self.config;
        let follows = self.previous.as_ref().is_some_and(|p| p.index + 1 == index && p.index > 0);
        if !cfg.aligned_path || self.lost || self.uncertain_run > 0 || !follows {
            return None;
        }
        let (reference, model, reference_pose) = self.candidates().into_iter().next()?;
        if self.unconfirmed == Some(reference) {
            return None;
        }
        let predicted = self.velocity * self.last_pose * reference_pose.inverse();
        // A frame that becomes a keyframe is estimated in full: keyframes carry the drift of
        // every later frame measured against them.
        if self.makes_keyframe(&predicted) {
            return None;
        }
        // The object's pixels in the new frame as predicted (the alignment runs both ways); a
        // whole frame as it is.
        let predicted_frame = match self.object {
            true => predicted_frame?,
            false => target,
        };
        let (e, agreement) = self.pipeline.estimate_near(model, predicted_frame, &predicted)?;
        let confirmed = e.registration.converged
            && agreement.score.is_some_and(|s| s <= cfg.aligned_max_score)
            && agreement.visible_fraction() >= cfg.aligned_min_visible;
        if confirmed && self.makes_keyframe(&e.pose) {
            return None;
        }
        if !confirmed {
            // Not tried against this keyframe again: what the images did not confirm here (a
            // view whose carried mask lost the surface now in sight) they will not confirm on
            // the next frame either, and each try costs an alignment.
            self.unconfirmed = Some(reference);
            return None;
        }
        Some((reference, e, reference_pose))
    }

    /// Whether a frame at `motion` from its reference (the keyframe nearest to its predicted
    /// pose) would become a keyframe.
    fn makes_keyframe(&self, motion: &Pose) -> bool {
        motion.rotation.angle().to_degrees() >= self.config.keyframe_deg
            || motion.translation.vector.norm() >= self.config.keyframe_m
    }

    /// The new frame with the object's mask predicted from the previous frame by the
    /// constant-velocity motion ([`TrackerConfig::predicted_splat_px`]); `None` for whole
    /// frames, after a loss, and when the predicted mask is too small.
    fn predicted_target(&self, target: &PreparedFrame) -> Option<PreparedFrame> {
        let splat = self.config.predicted_splat_px;
        let previous = self.previous.as_ref().filter(|_| self.object && !self.lost && splat > 0)?;
        let mask = carry_mask(&previous.frame, &self.velocity, target, splat, self.config.depth_tolerance_m);
        (mask.count() >= self.config.min_mask_px).then(|| target.with_mask(mask))
    }

    /// The estimate of `target` against the first candidate (the keyframe nearest to the
    /// predicted pose). Unless it converged the others are left to the unmasked pass, so that a
    /// nearest keyframe the predicted mask does not fit (an old view coming back, where the
    /// drift has moved the prediction) is tried there before any other.
    fn estimated_with(&self, target: &PreparedFrame) -> Option<(usize, Estimate, Pose, Option<Box<TracedPair>>)> {
        let (reference, model, reference_pose) = self.candidates().into_iter().next()?;
        let (e, pair) = self.estimated(model, target).ok()?;
        Some((reference, e, reference_pose, pair))
    }

    /// One estimate, with its trace when [`TrackerConfig::trace`] is set.
    fn estimated(
        &self,
        model: &PreparedFrame,
        target: &PreparedFrame,
    ) -> Result<(Estimate, Option<Box<TracedPair>>), PipelineError> {
        if self.config.trace {
            self.pipeline.estimate_traced(model, target).map(|(e, trace)| {
                let pair = TracedPair { model: model.clone(), target: target.clone(), trace };
                (e, Some(Box::new(pair)))
            })
        } else {
            self.pipeline.estimate_prepared(model, target).map(|e| (e, None))
        }
    }

    /// [`Tracker::track`] on the unmasked frame (the pipeline propagates the reference's mask).
    /// Without a converged estimate the frame is uncertain, its pose the plausible estimate with
    /// the tightest rotation bound among the unmasked ones and the predicted mask's (`fallback`).
    fn track_unmasked(&mut self, index: usize, target: PreparedFrame, fallback: Option<Doubtful>) -> TrackedFrame {
        let mut doubtful: Option<Doubtful> = fallback.filter(|d| plausible(&d.estimate));
        let mut failure: Option<String> = None;
        for (reference, model, reference_pose) in self.candidates() {
            match self.estimated(model, &target) {
                Ok((e, pair)) if e.registration.converged || self.settled_by_motion(&e, &reference_pose) => {
                    let mut r = self.accept(index, Target::whole(target), reference, e, reference_pose);
                    r.traced = pair;
                    return r;
                }
                Ok((estimate, traced)) => {
                    let this = Doubtful { reference, estimate, reference_pose, traced };
                    if plausible(&this.estimate) && doubtful.as_ref().is_none_or(|d| this.bound_deg() < d.bound_deg()) {
                        doubtful = Some(this);
                    }
                }
                Err(err) => failure = Some(err.to_string()),
            }
        }
        match doubtful.filter(|_| !self.lost && self.uncertain_run < self.config.max_uncertain) {
            Some(Doubtful { reference, estimate: e, reference_pose, traced }) => {
                self.uncertain_run += 1;
                let pose = e.pose * reference_pose;
                let reason = warning_codes(&e);
                let bound = chained_bound(self.reference_standing(reference).1, &e);
                let (frame, mask_px, _) = self.carried(reference, &e.pose, Target::whole(target));
                // Not a keyframe, but the next frame's nearest view: it is estimated against this
                // one (a short motion) when no keyframe converges, as chaining would.
                self.velocity = self.velocity_to(index, &pose);
                self.previous = Some(Previous { index, frame, pose, doubtful: true, bound });
                self.last_pose = pose;
                TrackedFrame {
                    index,
                    label: String::new(),
                    pose,
                    state: TrackState::Uncertain,
                    reason: Some(format!("not converged: {reason}")),
                    reference: Some(reference),
                    keyframe: false,
                    mask_px,
                    aligned_only: false,
                    bound_from_first: bound,
                    estimate: Some(e),
                    traced,
                    prepared_region: None,
                }
            }
            None => {
                let reason = failure.unwrap_or_else(|| {
                    if self.uncertain_run >= self.config.max_uncertain {
                        format!("{} uncertain frames in a row", self.uncertain_run)
                    } else {
                        "no keyframe gives a converged estimate".into()
                    }
                });
                self.lose(index, reason)
            }
        }
    }

    /// Whether the constant-velocity prediction settles a doubtful estimate against a reference
    /// at `reference_pose` ([`TrackerConfig::motion_gate_deg`]): its doubts are other turns that
    /// fit as well (and the bounds they widen), which a prediction answers; the clouds support
    /// it; it lies within the gate of the prediction; the other turns it names lie beyond three
    /// gates of it. Never after a loss (no prediction).
    fn settled_by_motion(&self, e: &Estimate, reference_pose: &Pose) -> bool {
        let gate_deg = self.config.motion_gate_deg;
        if gate_deg <= 0.0 || self.lost || !plausible(e) {
            return false;
        }
        // Other turns named: the prediction can rule them out. Bounds widened by those turns go
        // with them; bounds wide on their own, or a registration stopped short, it cannot.
        let ambiguous = e.warnings.iter().any(|w| matches!(w, PipelineWarning::AmbiguousPose { .. }));
        let answerable = |w: &PipelineWarning| match w {
            PipelineWarning::AmbiguousPose { turns_deg, .. } => turns_deg.iter().all(|t| t.abs() > 3.0 * gate_deg),
            PipelineWarning::Registration(RegistrationWarning::IterationLimit { .. }) => false,
            other => !other.is_doubtful(),
        };
        let widened = |w: &&PipelineWarning| matches!(w, PipelineWarning::WideBounds { .. });
        if !ambiguous || !e.warnings.iter().filter(|w| !widened(w)).all(answerable) {
            return false;
        }
        let off = (self.velocity * self.last_pose).inverse() * (e.pose * reference_pose);
        off.rotation.angle().to_degrees() <= gate_deg && off.translation.vector.norm() <= self.config.motion_gate_m
    }

    /// The frames to estimate against, in order: the keyframes nearest to the predicted pose
    /// (constant velocity; the
    /// smallest motions, and the oldest measurements when the object comes back: drift stays
    /// bounded), then the current keyframe and the previous frame; after a loss the
    /// [`TrackerConfig::recovery_tries`] keyframes nearest to the last pose.
    fn candidates(&self) -> Vec<(usize, &PreparedFrame, Pose)> {
        let predicted = if self.lost { self.last_pose } else { self.velocity * self.last_pose };
        let mut keyframes: Vec<&Keyframe> = self.keyframes.iter().collect();
        keyframes.sort_by(|a, b| pose_distance(&a.pose, &predicted).total_cmp(&pose_distance(&b.pose, &predicted)));
        if self.lost {
            let tries = self.config.recovery_tries.max(1);
            return keyframes.into_iter().take(tries).map(|k| (k.index, &k.frame, k.pose)).collect();
        }
        let mut out: Vec<(usize, &PreparedFrame, Pose)> = vec![];
        let current = &self.keyframes[self.current];
        for k in keyframes.into_iter().take(NEAREST_KEYFRAMES).chain([current]) {
            if out.iter().all(|(i, _, _)| *i != k.index) {
                out.push((k.index, &k.frame, k.pose));
            }
        }
        if let Some(p) = self.previous.as_ref().filter(|p| out.iter().all(|(i, _, _)| *i != p.index)) {
            out.push((p.index, &p.frame, p.pose));
        }
        out
    }

    fn reference_frame(&self, index: usize) -> &PreparedFrame {
        match self.keyframes.iter().find(|k| k.index == index) {
            Some(k) => &k.frame,
            None => &self.previous.as_ref().expect("a reference is a keyframe or the previous frame").frame,
        }
    }

    /// A converged estimate (or one the motion settled): the pose from the first frame, the mask
    /// carried, a keyframe when the object moved far enough from the current one.
    fn accept(
        &mut self,
        index: usize,
        target: Target,
        reference: usize,
        e: Estimate,
        reference_pose: Pose,
    ) -> TrackedFrame {
        let pose = e.pose * reference_pose;
        let (rests_on_doubt, reference_bound) = self.reference_standing(reference);
        let bound = chained_bound(reference_bound, &e);
        let (frame, mask_px, region) = self.carried(reference, &e.pose, target);
        if self.object && mask_px < self.config.min_mask_px {
            return self
                .lose(index, format!("the object's mask emptied ({mask_px} pixels): it left the view or is hidden"));
        }
        // Converged against a frame whose own pose rests on an uncertain one: the pose from the
        // first frame rests on that doubt too, and the frame is reported uncertain (its
        // estimate and everything else as for a tracked frame).
        let doubtful = !self.lost && rests_on_doubt;
        let state = match (self.lost, doubtful) {
            (true, _) => TrackState::Recovered,
            (false, true) => TrackState::Uncertain,
            (false, false) => TrackState::Tracking,
        };
        self.velocity = if self.lost { Pose::identity() } else { self.velocity_to(index, &pose) };
        self.lost = false;
        self.uncertain_run = 0;
        self.last_pose = pose;
        if let Some(k) = self.keyframes.iter().position(|k| k.index == reference) {
            self.current = k;
        }
        let from_keyframe = pose * self.keyframes[self.current].pose.inverse();
        let far = self.makes_keyframe(&from_keyframe);
        if far {
            self.add_keyframe(Keyframe { index, frame: frame.clone(), pose, doubtful, bound });
        }
        self.previous = Some(Previous { index, frame, pose, doubtful, bound });
        let codes = warning_codes(&e);
        let reason = match (doubtful, e.registration.converged) {
            (true, _) => Some(format!("converged against frame {reference}, whose pose rests on an uncertain frame")),
            (false, true) => Some(codes).filter(|r| !r.is_empty()),
            (false, false) => Some(format!("{codes}: settled by the motion")),
        };
        TrackedFrame {
            index,
            label: String::new(),
            pose,
            state,
            reason,
            reference: Some(reference),
            keyframe: far,
            mask_px,
            aligned_only: false,
            bound_from_first: bound,
            estimate: Some(e),
            traced: None,
            prepared_region: region,
        }
    }

    /// What the tracker keeps of frame `reference` (the previous frame or a keyframe): whether
    /// its pose rests on an uncertain frame, and the bounds on its pose from the first frame.
    fn reference_standing(&self, reference: usize) -> (bool, Option<Uncertainty>) {
        let previous = self.previous.as_ref().filter(|p| p.index == reference).map(|p| (p.doubtful, p.bound));
        previous
            .or_else(|| self.keyframes.iter().find(|k| k.index == reference).map(|k| (k.doubtful, k.bound)))
            .unwrap_or((false, None))
    }

    /// `target` with the object's mask carried from `reference` by `motion`, and the mask's
    /// area; a whole frame as it is (area 0). A frame prepared on a region that does not hold
    /// the carried mask is prepared whole first. The region the frame stays prepared on, if any.
    fn carried(&self, reference: usize, motion: &Pose, target: Target) -> (PreparedFrame, usize, Option<PixelBox>) {
        if !self.object {
            return (target.prepared, 0, None);
        }
        let (splat, tolerance) = (self.config.splat_px, self.config.depth_tolerance_m);
        let from = self.reference_frame(reference);
        let carry = |frame: &PreparedFrame| {
            let mut mask = carry_mask(from, motion, frame, splat, tolerance);
            if self.config.reveal {
                reveal::grow_revealed(from, motion, frame, &mut mask, &RevealParams::default());
            }
            mask
        };
        let mut mask = carry(&target.prepared);
        let (frame, region) = if target.holds(&mask) {
            (target.prepared, target.region.map(|(r, _)| r))
        } else {
            let whole = target.into_whole(&self.pipeline);
            mask = carry(&whole);
            (whole, None)
        };
        let px = mask.count();
        (frame.with_mask(mask), px, region)
    }

    /// The motion from the previous frame to frame `index` at `pose`, when the previous frame
    /// is the one just before it; else none.
    fn velocity_to(&self, index: usize, pose: &Pose) -> Pose {
        match &self.previous {
            Some(p) if p.index + 1 == index => pose * p.pose.inverse(),
            _ => Pose::identity(),
        }
    }

    fn add_keyframe(&mut self, k: Keyframe) {
        if self.keyframes.len() >= self.config.max_keyframes.max(2) {
            // The first frame stays (recovery to the start); the oldest other one goes.
            self.keyframes.remove(1);
        }
        self.keyframes.push(k);
        self.current = self.keyframes.len() - 1;
    }

    fn lose(&mut self, index: usize, reason: String) -> TrackedFrame {
        self.lost = true;
        self.velocity = Pose::identity();
        self.uncertain_run = 0;
        self.previous = None;
        TrackedFrame {
            index,
            label: String::new(),
            pose: self.last_pose,
            state: TrackState::Lost,
            reason: Some(reason),
            reference: None,
            keyframe: false,
            estimate: None,
            bound_from_first: None,
            mask_px: 0,
            aligned_only: false,
            traced: None,
            prepared_region: None,
        }
    }
}

/// The warnings' codes, comma separated, without those the tracker causes itself: whole frames
/// (`mask_covers_frame`) and the target's mask propagated (later frames come without one).
fn warning_codes(e: &Estimate) -> String {
    let own = ["mask_covers_frame", "mask_propagated"];
    let codes: Vec<&str> = e.warnings.iter().map(PipelineWarning::code).filter(|c| !own.contains(c)).collect();
    codes.join(", ")
}
