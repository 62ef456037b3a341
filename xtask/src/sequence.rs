//! The image sequences `bench-bop` reads: BOP scene folders, and folders of YCB-Video frames as
//! the original dataset and `../shared/data/ycb-video` ship them (`NNNNNN-color.png`,
//! `-depth.png` registered to colour, `-label.png` with one class id per pixel, and `-gt.json`
//! with `K`, `depth_png_units_per_metre` and per object `class_id`, `name` and
//! `T_camera_from_object`).

use flowfilter_pipeline::bop::BopScene;
use flowfilter_pipeline::geometry::rigid_from_matrix;
use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, Pose, RgbdFrame};
use nalgebra::Matrix4;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Annotated images of one camera's sequence, with per-object masks and true poses.
pub trait Sequence: Sync {
    /// The images with annotations, in order.
    fn image_ids(&self) -> Vec<u32>;
    /// Every annotated instance of an image: object id and visible fraction when known (an
    /// object may appear more than once).
    fn instances(&self, im: u32) -> Vec<(u32, Option<f64>)>;
    /// The object's name, when the sequence gives one.
    fn object_name(&self, obj: u32) -> Option<String>;
    /// Image `im` with the mask of object `obj`.
    fn frame(&self, im: u32, obj: u32) -> Result<RgbdFrame, String>;
    /// The object's motion from image `a` to image `b` in the camera frame.
    fn relative_motion(&self, a: u32, b: u32, obj: u32) -> Result<Pose, String>;
}

impl Sequence for BopScene {
    fn image_ids(&self) -> Vec<u32> {
        BopScene::image_ids(self)
    }

    fn instances(&self, im: u32) -> Vec<(u32, Option<f64>)> {
        BopScene::instances(self, im).iter().map(|i| (i.obj_id, i.visib_fract)).collect()
    }

    fn object_name(&self, _obj: u32) -> Option<String> {
        None
    }

    fn frame(&self, im: u32, obj: u32) -> Result<RgbdFrame, String> {
        BopScene::frame(self, im, obj).map_err(|e| e.to_string())
    }

    fn relative_motion(&self, a: u32, b: u32, obj: u32) -> Result<Pose, String> {
        BopScene::relative_motion(self, a, b, obj).map_err(|e| e.to_string())
    }
}

/// One YCB-Video frame's annotation.
struct YcbvImage {
    camera: CameraFile,
    /// Class id -> (name, `T_camera_from_object`).
    objects: BTreeMap<u32, (String, Pose)>,
}

/// A folder of YCB-Video frames.
pub struct YcbVideoFrames {
    dir: PathBuf,
    images: BTreeMap<u32, YcbvImage>,
}

/// Whether `dir` holds YCB-Video frames (`NNNNNN-gt.json`).
pub fn is_ycbv_folder(dir: &Path) -> bool {
    std::fs::read_dir(dir).is_ok_and(|rd| rd.filter_map(Result::ok).any(|e| gt_image_id(&e.path()).is_some()))
}

fn gt_image_id(path: &Path) -> Option<u32> {
    path.file_name()?.to_str()?.strip_suffix("-gt.json")?.parse().ok()
}

fn read_image(path: &Path) -> Result<YcbvImage, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: cannot read: {e}", path.display()))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| format!("{}: not JSON: {e}", path.display()))?;
    let camera = CameraFile::from_json_value(&v, &path.display().to_string()).map_err(|e| e.to_string())?;
    let list = v["objects"].as_array().ok_or_else(|| format!("{}: no 'objects' list", path.display()))?;
    let mut objects = BTreeMap::new();
    for (i, o) in list.iter().enumerate() {
        let bad = |what: &str| format!("{}: objects[{i}]: {what}", path.display());
        let id = o["class_id"]
            .as_u64()
            .and_then(|v| u32::try_from(v).ok())
            .ok_or_else(|| bad("'class_id' must be a whole number"))?;
        let name = o["name"].as_str().map_or_else(|| format!("class_{id}"), str::to_string);
        let m: Option<Vec<f64>> = (0..16).map(|k| o["T_camera_from_object"][k / 4][k % 4].as_f64()).collect();
        let m = m.ok_or_else(|| bad("'T_camera_from_object' must be 4 rows of 4 numbers"))?;
        let pose = rigid_from_matrix(&Matrix4::from_row_slice(&m))
            .map_err(|e| bad(&format!("'T_camera_from_object': {e}")))?;
        objects.insert(id, (name, pose));
    }
    Ok(YcbvImage { camera, objects })
}

impl YcbVideoFrames {
    /// Read every `NNNNNN-gt.json` of a folder.
    ///
    /// # Errors
    /// A message naming the file and the field for a malformed annotation.
    pub fn open(dir: &Path) -> Result<Self, String> {
        let mut images = BTreeMap::new();
        let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: cannot read: {e}", dir.display()))?;
        for path in entries.filter_map(Result::ok).map(|e| e.path()) {
            if let Some(im) = gt_image_id(&path) {
                images.insert(im, read_image(&path)?);
            }
        }
        if images.is_empty() {
            return Err(format!("{}: no NNNNNN-gt.json file", dir.display()));
        }
        Ok(Self { dir: dir.to_path_buf(), images })
    }

    /// The class ids annotated in any image, in order.
    pub fn object_ids(&self) -> Vec<u32> {
        let ids: std::collections::BTreeSet<u32> =
            self.images.values().flat_map(|i| i.objects.keys().copied()).collect();
        ids.into_iter().collect()
    }

    fn image(&self, im: u32) -> Result<&YcbvImage, String> {
        self.images.get(&im).ok_or_else(|| format!("{}: no image {im:06}", self.dir.display()))
    }

    /// `T_camera_from_object` of object `obj` in image `im`.
    pub fn pose(&self, im: u32, obj: u32) -> Result<Pose, String> {
        let image = self.image(im)?;
        image.objects.get(&obj).map(|o| o.1).ok_or_else(|| {
            format!("{}: image {im:06} has no object {obj} (it has {:?})", self.dir.display(), image.objects.keys())
        })
    }
}

impl Sequence for YcbVideoFrames {
    fn image_ids(&self) -> Vec<u32> {
        self.images.keys().copied().collect()
    }

    fn instances(&self, im: u32) -> Vec<(u32, Option<f64>)> {
        self.images.get(&im).map_or_else(Vec::new, |i| i.objects.keys().map(|&id| (id, None)).collect())
    }

    fn object_name(&self, obj: u32) -> Option<String> {
        self.images.values().find_map(|i| i.objects.get(&obj).map(|o| o.0.clone()))
    }

    fn frame(&self, im: u32, obj: u32) -> Result<RgbdFrame, String> {
        let image = self.image(im)?;
        let id = u16::try_from(obj).map_err(|_| format!("class id {obj} is not a label value"))?;
        let file = |suffix: &str| self.dir.join(format!("{im:06}-{suffix}"));
        let files = FrameFiles {
            color: file("color.png"),
            depth: file("depth.png"),
            mask: MaskSource::Label { path: file("label.png"), id },
        };
        files.load(&image.camera, &format!("{im:06}/{obj}")).map_err(|e| e.to_string())
    }

    fn relative_motion(&self, a: u32, b: u32, obj: u32) -> Result<Pose, String> {
        Ok(self.pose(b, obj)? * self.pose(a, obj)?.inverse())
    }
}

/// Open a sequence folder of either kind.
///
/// # Errors
/// Why the folder cannot be read.
pub fn open_sequence(dir: &Path) -> Result<Box<dyn Sequence>, String> {
    if !dir.join("scene_gt.json").is_file() && is_ycbv_folder(dir) {
        return Ok(Box::new(YcbVideoFrames::open(dir)?));
    }
    // A BOP scene, or neither: then the BOP reader says what is missing.
    Ok(Box::new(BopScene::open(dir).map_err(|e| e.to_string())?))
}

/// Whether `dir` is a sequence folder of either kind.
pub fn is_sequence(dir: &Path) -> bool {
    dir.join("scene_gt.json").is_file() || is_ycbv_folder(dir)
}
