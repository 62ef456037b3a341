//! The embedded default datasets: synthesised once in the BigBIRD layout (one object directory
//! per object) and in the BOP layout (scene folders), cached under `target/`.

use anyhow::Context;
use flowfilter_bigbird::SensorId;
use flowfilter_synth::{
    BopSceneOptions, CaptureOptions, FrameEffects, NoiseProfile, Rig, Scene, TexturedMesh, procedural, write_bop_scene,
    write_capture,
};
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

/// Make sure `root/<scene_id:06>` holds the BOP scene of `object` (id `obj_id`): Carmine noise,
/// real-sensor frame effects, depth in 0.1 mm units, fixed seed.
pub fn ensure_bop_scene(
    root: &Path,
    object: &DefaultObject,
    obj_id: u32,
    spec: &BopSceneSpec,
    seed: u64,
) -> anyhow::Result<PathBuf> {
    let dir = root.join(format!("{:06}", spec.scene_id));
    let signature = format!(
        "{DATASET_VERSION}\nBOP scene of {} (obj_id {obj_id})\nseed {seed}\nsensor {}\nangles {:?}\neffects {:?}\n",
        object.name,
        spec.sensor,
        spec.angles_deg,
        FrameEffects::REAL_SENSOR
    );
    cached(&dir, &signature, || {
        let opts = BopSceneOptions {
            angles_deg: spec.angles_deg.clone(),
            noise: Some(NoiseProfile::carmine()),
            effects: FrameEffects::REAL_SENSOR,
            seed,
            obj_id,
            depth_scale_mm: 0.1,
        };
        let rig = Rig::bigbird_like();
        Ok(write_bop_scene(&dir, &object.scene(seed)?, &rig.sensors[&spec.sensor], &opts, &|_, _| {})?)
    })?;
    Ok(dir)
}
