//! The embedded default dataset: synthesised once in the BigBIRD layout, cached under `target/`.

use anyhow::Context;
use flowfilter_bigbird::SensorId;
use flowfilter_synth::{CaptureOptions, NoiseProfile, Rig, Scene, TexturedMesh, procedural, write_capture};
use std::path::{Path, PathBuf};

/// Bumped whenever the synthesiser's output changes, to invalidate caches.
const DATASET_VERSION: &str = "flowfilter-default-dataset v4 (mip-mapped textures, label print at millimetre scale)";

/// Where an object comes from.
pub enum ObjectSource {
    /// A procedural object by name.
    Procedural(String),
    /// A textured OBJ.
    Mesh(PathBuf),
}

/// One object of the default dataset.
pub struct DefaultObject {
    /// Directory name.
    pub name: String,
    /// Its source.
    pub source: ObjectSource,
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
    let marker = dir.join(".synth-signature");
    if std::fs::read_to_string(&marker).ok().as_deref() == Some(signature.as_str()) {
        return Ok(dir);
    }
    if dir.exists() {
        std::fs::remove_dir_all(&dir).with_context(|| format!("clearing stale cache {}", dir.display()))?;
    }
    let mesh = match &object.source {
        ObjectSource::Procedural(name) => procedural(name, seed)?,
        ObjectSource::Mesh(path) => TexturedMesh::load_obj(path)?,
    };
    let scene = Scene::new(mesh.placed_on_table(0.01, -0.005), seed);
    let opts = CaptureOptions {
        sensors: sensors.to_vec(),
        angles: angles.to_vec(),
        noise: Some(NoiseProfile::carmine()),
        seed,
    };
    write_capture(&dir, &scene, &Rig::bigbird_like(), &opts, &|_, _| {})
        .with_context(|| format!("synthesising {}", dir.display()))?;
    std::fs::write(&marker, signature).with_context(|| format!("writing {}", marker.display()))?;
    Ok(dir)
}
