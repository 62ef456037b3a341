//! The embedded default datasets: synthesised once in the BigBIRD layout (one object directory
//! per object) and in the BOP layout (scene folders), cached under `target/`.

use anyhow::Context;
use flowfilter_bigbird::SensorId;
use flowfilter_pipeline::RgbdSensor;
use flowfilter_pipeline::camera::{CameraModel, Distortion, ImageSize, Intrinsics};
use flowfilter_pipeline::{Point3, Pose};
use flowfilter_synth::{
    BopSceneOptions, CaptureOptions, FrameEffects, NoiseProfile, Rig, RigSensor, Scene, TexturedMesh, look_at,
    procedural, write_bop_scene, write_capture,
};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Bumped whenever the synthesiser's output changes, to invalidate caches.
const DATASET_VERSION: &str = "flowfilter-default-dataset v4 (mip-mapped textures, label print at millimetre scale)";

/// Where an object comes from.
#[derive(Clone)]
pub enum ObjectSource {
    /// A procedural object by name.
    Procedural(String),
    /// A textured OBJ.
    Mesh(PathBuf),
}

/// One object of the default dataset.
#[derive(Clone)]
pub struct DefaultObject {
    /// Directory name.
    pub name: String,
    /// Its source.
    pub source: ObjectSource,
}

/// The objects of an embedded dataset: with `quick` the procedural ones only, else also the
/// meshes of `meshes` (default: `../shared/data/ycb` when present).
pub fn embedded_objects(quick: bool, meshes: Option<&Path>) -> Vec<DefaultObject> {
    let shared = Path::new("../shared/data/ycb");
    let meshes = if quick { None } else { meshes.or_else(|| Some(shared).filter(|p| p.is_dir())) };
    default_objects(meshes)
}

/// The procedural objects, plus the YCB meshes found in `meshes` (directories holding
/// `textured.obj`).
pub fn default_objects(meshes: Option<&Path>) -> Vec<DefaultObject> {
    let mut out: Vec<DefaultObject> = ["box", "can", "bottle"]
        .iter()
        .map(|n| DefaultObject { name: format!("procedural_{n}"), source: ObjectSource::Procedural((*n).into()) })
        .collect();
    if let Some(dir) = meshes {
        let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
            .map(|rd| {
                rd.filter_map(Result::ok).map(|e| e.path()).filter(|p| p.join("textured.obj").is_file()).collect()
            })
            .unwrap_or_default();
        found.sort();
        for p in found {
            let name = p.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
            out.push(DefaultObject { name, source: ObjectSource::Mesh(p.join("textured.obj")) });
        }
    }
    out
}

/// Run `make` into `dir` unless `dir` already holds what `signature` describes; the marker
/// file is written last, so an interrupted run is redone.
fn cached(dir: &Path, signature: &str, make: impl FnOnce() -> anyhow::Result<()>) -> anyhow::Result<()> {
    let marker = dir.join(".synth-signature");
    if std::fs::read_to_string(&marker).ok().as_deref() == Some(signature) {
        return Ok(());
    }
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("clearing stale cache {}", dir.display()))?;
    }
    make().with_context(|| format!("synthesising {}", dir.display()))?;
    std::fs::write(&marker, signature).with_context(|| format!("writing {}", marker.display()))
}

impl DefaultObject {
    /// The object standing on the turntable (the same placement in both layouts).
    fn scene(&self, seed: u64) -> anyhow::Result<Scene> {
        let mesh = match &self.source {
            ObjectSource::Procedural(name) => procedural(name, seed)?,
            ObjectSource::Mesh(path) => TexturedMesh::load_obj(path)?,
        };
        Ok(Scene::new(mesh.placed_on_table(0.01, -0.005), seed))
    }
}

/// Where `bench-bigbird` (and `bench-speed`) cache the embedded default dataset.
pub const DEFAULT_DATASET_ROOT: &str = "target/bigbird-default";

/// The seed of the embedded default dataset's captures.
pub const DEFAULT_DATASET_SEED: u64 = 7;

/// [`ensure_object`] in the default dataset's cache, with its seed: one cache serves every
/// benchmark that asks for the same cameras and angles.
pub fn ensure_default_object(object: &DefaultObject, sensors: &[SensorId], angles: &[u32]) -> anyhow::Result<PathBuf> {
    ensure_object(&crate::in_repo(Path::new(DEFAULT_DATASET_ROOT)), object, sensors, angles, DEFAULT_DATASET_SEED)
}

/// Make sure `root/<object>` holds a capture with at least `sensors` x `angles`; synthesise it
/// (Carmine noise, fixed seed) when the cache is missing or was made for other frames.
pub fn ensure_object(
    root: &Path,
    object: &DefaultObject,
    sensors: &[SensorId],
    angles: &[u32],
    seed: u64,
) -> anyhow::Result<PathBuf> {
    let dir = root.join(&object.name);
    let signature = format!("{DATASET_VERSION}\nseed {seed}\nsensors {sensors:?}\nangles {angles:?}\n");
    cached(&dir, &signature, || {
        let opts = CaptureOptions {
            sensors: sensors.to_vec(),
            angles: angles.to_vec(),
            noise: Some(NoiseProfile::carmine()),
            seed,
        };
        Ok(write_capture(&dir, &object.scene(seed)?, &Rig::bigbird_like(), &opts, &|_, _| {})?)
    })?;
    Ok(dir)
}

/// One scene of the default BOP dataset.
pub struct BopSceneSpec {
    /// Scene folder number.
    pub scene_id: u32,
    /// The rig camera that watches the turntable.
    pub sensor: SensorId,
    /// Turntable angle of each image, degrees.
    pub angles_deg: Vec<f64>,
}

/// The sensor a synthetic scene is rendered with: noise, frame effects, camera and how much of
/// its registered depth is kept.
pub struct SceneSensor {
    /// The depth and colour noise.
    pub noise: NoiseProfile,
    /// The per-frame effects.
    pub effects: FrameEffects,
    /// An SR300-like camera this far from the turntable's centre on the rig camera's line of
    /// sight, instead of the rig's own camera (metres).
    pub sr300_at_m: Option<f64>,
}

impl SceneSensor {
    /// The default datasets' sensor: Carmine noise, real-sensor frame effects, the rig's camera.
    pub fn carmine() -> Self {
        Self { noise: NoiseProfile::carmine(), effects: FrameEffects::REAL_SENSOR, sr300_at_m: None }
    }

    /// The SR300 of the shared shelf sequences: its two cameras (640 x 480 colour at 612 px,
    /// depth at 477 px, the shelf sequences' calibration) 0.55 m from the object, the twins'
    /// noise profile (with its depth warp) and frame effects, and its registered depth's
    /// sparsity ([`sr300_depth_kept`]).
    pub fn sr300_shelf() -> Self {
        Self { noise: NoiseProfile::sr300_shelf(), effects: FrameEffects::SR300_SHELF, sr300_at_m: Some(0.55) }
    }

    /// The rig sensor that takes the scene of rig camera `id`.
    fn rig_sensor(&self, id: SensorId) -> anyhow::Result<RigSensor> {
        let rig = Rig::bigbird_like();
        let base = rig.sensors[&id].clone();
        let Some(distance) = self.sr300_at_m else { return Ok(base) };
        let target = Point3::new(0.0, 0.0, 0.08);
        let eye_before = base.h_color_from_world.inverse() * Point3::origin();
        let eye = target + (eye_before - target).normalize() * distance;
        let rgbd = sr300_rgbd()?;
        Ok(RigSensor { rgbd, h_color_from_world: look_at(eye, target), projector_baseline: 0.05, ir_depth_scale: 10.0 })
    }
}

/// The sensor of the embedded scenes (`--sensor-profile`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum SensorProfile {
    /// The default dataset's Carmine-like sensor.
    Carmine,
    /// A twin of the shared SR300 shelf sequences' sensor and masks.
    Sr300Shelf,
}

impl SensorProfile {
    /// The sensor's noise, effects and camera.
    pub fn sensor(self) -> SceneSensor {
        match self {
            Self::Carmine => SceneSensor::carmine(),
            Self::Sr300Shelf => SceneSensor::sr300_shelf(),
        }
    }

    /// Cache folder of the embedded scenes.
    pub fn folder(self, quick: bool) -> &'static str {
        match (self, quick) {
            (Self::Carmine, true) => "bop-quick",
            (Self::Carmine, false) => "bop-default",
            (Self::Sr300Shelf, true) => "bop-sr300-shelf-quick",
            (Self::Sr300Shelf, false) => "bop-sr300-shelf",
        }
    }

    /// The frame's mask as this sensor's segmentation gives it.
    pub fn mask(self, frame: &mut flowfilter_pipeline::RgbdFrame, scene: &str, (im_id, obj_id): (u32, u32)) {
        if self == Self::Sr300Shelf {
            let seed = crate::realsense::seed_of(scene, 0, &[u64::from(im_id), u64::from(obj_id)]);
            if let Some(mask) = crate::realsense::network_mask(
                &frame.mask,
                &flowfilter_synth::NetworkMaskModel::SHELF_NETWORK,
                seed,
                true,
            ) {
                frame.mask = mask;
            }
        }
    }
}

/// The SR300 of the shared shelf sequences: their `camera.json` (640 x 480 colour at 612 px,
/// depth at 477 px, the extrinsic), 1 mm depth units.
fn sr300_rgbd() -> anyhow::Result<RgbdSensor> {
    let camera = |fx, cx, cy| -> anyhow::Result<CameraModel> {
        Ok(CameraModel::new(Intrinsics::new(fx, fx, cx, cy)?, Distortion::NONE, ImageSize::new(640, 480)?))
    };
    let color_from_depth = Pose::new(Vector3::new(0.0247, 0.00126, 0.00456), Vector3::new(-0.00231, 0.00096, -0.00038));
    let (depth, color) = (camera(477.425, 322.314, 245.856)?, camera(611.686, 317.676, 243.152)?);
    Ok(RgbdSensor::new(depth, color, color_from_depth, 1e-3)?)
}

/// Whether registered depth pixel `(x, y)` of `sensor`'s frames holds a reading: the colour
/// grid samples the depth camera's (SR300: 477 px onto 612) where a depth pixel's centre lands,
/// about 61% of the pixels in rows and columns with regular gaps; of those, blocks of 4 x 4
/// depth pixels read nothing with probability one half (dark and glossy patches, the
/// projector's shadow), leaving about 30%, as the real registered frames hold (25-35% at 0.5 m).
pub fn sr300_depth_kept(x: usize, y: usize, seed: u64, sensor: &RgbdSensor) -> bool {
    let (c, d) = (&sensor.color.intrinsics, &sensor.depth.intrinsics);
    let ratio = d.fx / c.fx;
    let to_depth = |v: f64, cc: f64, cd: f64| ((v - cc) * ratio + cd).round();
    let to_color = |v: f64, cd: f64, cc: f64| ((v - cd) / ratio + cc).round();
    let (ud, vd) = (to_depth(x as f64, c.cx, d.cx), to_depth(y as f64, c.cy, d.cy));
    let on_lattice = to_color(ud, d.cx, c.cx) == x as f64 && to_color(vd, d.cy, c.cy) == y as f64;
    let block = ((ud.max(0.0) as u64) / 4, (vd.max(0.0) as u64) / 4);
    let h = crate::realsense::seed_of("sr300 depth", seed, &[block.0, block.1]);
    on_lattice && h.is_multiple_of(2)
}

/// Make sure `root/<scene_id:06>` holds the BOP scene of `object` (id `obj_id`): `sensor`'s noise and
/// frame effects, depth in 0.1 mm units, fixed seed.
pub fn ensure_bop_scene(
    root: &Path,
    object: &DefaultObject,
    obj_id: u32,
    spec: &BopSceneSpec,
    seed: u64,
    sensor: &SceneSensor,
) -> anyhow::Result<PathBuf> {
    let dir = root.join(format!("{:06}", spec.scene_id));
    let mut signature = format!(
        "{DATASET_VERSION}\nBOP scene of {} (obj_id {obj_id})\nseed {seed}\nsensor {}\nangles {:?}\neffects {:?}\n",
        object.name, spec.sensor, spec.angles_deg, sensor.effects,
    );
    // The default sensor's scenes keep the signature they were cached under.
    if sensor.noise.name != NoiseProfile::carmine().name {
        signature.push_str(&format!("noise {}\ncamera {:?}\n", sensor.noise.name, sensor.sr300_at_m));
    }
    cached(&dir, &signature, || {
        let opts = BopSceneOptions {
            angles_deg: spec.angles_deg.clone(),
            noise: Some(sensor.noise.clone()),
            effects: sensor.effects,
            seed,
            obj_id,
            depth_scale_mm: 0.1,
        };
        write_bop_scene(&dir, &object.scene(seed)?, &sensor.rig_sensor(spec.sensor)?, &opts, &|_, _| {})?;
        if sensor.sr300_at_m.is_some() {
            sparsify_depth(&dir, seed, &sr300_rgbd()?)?;
        }
        Ok(())
    })?;
    Ok(dir)
}

/// Keep only the readings [`sr300_depth_kept`] keeps in every depth image of the BOP scene `dir`.
fn sparsify_depth(dir: &Path, seed: u64, sensor: &RgbdSensor) -> anyhow::Result<()> {
    for entry in std::fs::read_dir(dir.join("depth"))? {
        let path = entry?.path();
        let mut depth = image::open(&path).with_context(|| format!("reading {}", path.display()))?.into_luma16();
        for (x, y, p) in depth.enumerate_pixels_mut() {
            if !sr300_depth_kept(x as usize, y as usize, seed, sensor) {
                p.0[0] = 0;
            }
        }
        depth.save(&path).with_context(|| format!("writing {}", path.display()))?;
    }
    Ok(())
}
