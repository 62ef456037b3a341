//! BOP datasets (the BOP toolkit's scene-wise format: YCB-Video, LINEMOD, T-LESS, HOPE, ...):
//! one scene folder's frames, per-object visible masks and ground-truth poses.
//!
//! A scene folder holds `scene_camera.json` (per image: `cam_K` row-wise, `depth_scale` =
//! millimetres per depth unit), `scene_gt.json` (per image, per annotated instance: `obj_id`,
//! `cam_R_m2c` row-wise, `cam_t_m2c` in millimetres), optionally `scene_gt_info.json`
//! (`visib_fract`, pixel counts), and the images `rgb/` (or `gray/`) `{im_id:06d}.png|jpg`,
//! `depth/{im_id:06d}.png` (16-bit, registered to colour) and the masks
//! `mask_visib/` (or `mask/`) `{im_id:06d}_{gt_id:06d}.png`, `gt_id` being the instance's
//! index in the image's `scene_gt.json` list.

use crate::error::{PipelineError, input_error};
use crate::frame::RgbdFrame;
use crate::source::{FrameFiles, MaskSource};
use flowfilter_camera::CameraFile;
use flowfilter_geometry::{Pose, rigid_from_matrix};
use nalgebra::Matrix4;
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One annotated object instance of an image.
#[derive(Debug, Clone, PartialEq)]
pub struct BopInstance {
    /// The object's id.
    pub obj_id: u32,
    /// Its index in the image's `scene_gt.json` list (the mask file's second number).
    pub gt_id: usize,
    /// `T_cam_from_obj` in metres.
    pub cam_from_obj: Pose,
    /// Its visible fraction (`scene_gt_info.json`), when given.
    pub visib_fract: Option<f64>,
}

/// A BOP scene folder, its annotations read.
#[derive(Debug, Clone)]
pub struct BopScene {
    dir: PathBuf,
    cameras: BTreeMap<u32, Value>,
    instances: BTreeMap<u32, Vec<BopInstance>>,
    color_dir: &'static str,
    mask_dir: &'static str,
}

/// A JSON file's top-level object keyed by image id.
fn read_by_image(path: &Path) -> Result<BTreeMap<u32, Value>, PipelineError> {
    let text = std::fs::read_to_string(path).map_err(|e| input_error(path, format!("cannot read: {e}")))?;
    let value: Value = serde_json::from_str(&text).map_err(|e| input_error(path, format!("not JSON: {e}")))?;
    let object = value.as_object().ok_or_else(|| input_error(path, "expected an object keyed by image id"))?;
    object
        .iter()
        .map(|(k, v)| {
            let id = k.parse::<u32>().map_err(|_| input_error(path, format!("key '{k}' is not an image id")))?;
            Ok((id, v.clone()))
        })
        .collect()
}

/// Numbers of a JSON array of length `n`, or an error naming the file, image and key.
fn numbers(path: &Path, im_id: u32, key: &str, v: Option<&Value>, n: usize) -> Result<Vec<f64>, PipelineError> {
    v.and_then(Value::as_array)
        .filter(|a| a.len() == n)
        .and_then(|a| a.iter().map(Value::as_f64).collect())
        .ok_or_else(|| input_error(path, format!("image {im_id}: '{key}' must be an array of {n} numbers")))
}

fn instances_of(
    path: &Path,
    im_id: u32,
    list: &Value,
    info: Option<&Value>,
) -> Result<Vec<BopInstance>, PipelineError> {
    let entries =
        list.as_array().ok_or_else(|| input_error(path, format!("image {im_id}: expected a list of instances")))?;
    entries
        .iter()
        .enumerate()
        .map(|(gt_id, e)| {
            let obj_id =
                e.get("obj_id").and_then(Value::as_u64).and_then(|v| u32::try_from(v).ok()).ok_or_else(|| {
                    input_error(path, format!("image {im_id}, instance {gt_id}: 'obj_id' must be a whole number"))
                })?;
            let r = numbers(path, im_id, "cam_R_m2c", e.get("cam_R_m2c"), 9)?;
            let t = numbers(path, im_id, "cam_t_m2c", e.get("cam_t_m2c"), 3)?;
            // BOP translations are millimetres.
            let m = Matrix4::new(
                r[0],
                r[1],
                r[2],
                t[0] * 1e-3,
                r[3],
                r[4],
                r[5],
                t[1] * 1e-3,
                r[6],
                r[7],
                r[8],
                t[2] * 1e-3,
                0.0,
                0.0,
                0.0,
                1.0,
            );
            let cam_from_obj = rigid_from_matrix(&m).map_err(|e| {
                input_error(
                    path,
                    format!("image {im_id}, instance {gt_id}: cam_R_m2c/cam_t_m2c is not a rigid transform: {e}"),
                )
            })?;
            let visib_fract =
                info.and_then(|i| i.get(gt_id)).and_then(|i| i.get("visib_fract")).and_then(Value::as_f64);
            Ok(BopInstance { obj_id, gt_id, cam_from_obj, visib_fract })
        })
        .collect()
}

impl BopScene {
    /// Open a scene folder and read its annotations.
    ///
    /// # Errors
    /// [`PipelineError::Input`] naming the file: a missing `scene_camera.json` or
    /// `scene_gt.json`, malformed JSON or fields, no `rgb/` or `gray/` folder.
    pub fn open(dir: &Path) -> Result<Self, PipelineError> {
        let cameras = read_by_image(&dir.join("scene_camera.json"))?;
        let gt_path = dir.join("scene_gt.json");
        let gt = read_by_image(&gt_path)?;
        let info_path = dir.join("scene_gt_info.json");
        let info = if info_path.is_file() { Some(read_by_image(&info_path)?) } else { None };
        let instances = gt
            .iter()
            .map(|(&im, list)| Ok((im, instances_of(&gt_path, im, list, info.as_ref().and_then(|i| i.get(&im)))?)))
            .collect::<Result<_, PipelineError>>()?;
        let color_dir = ["rgb", "gray"]
            .into_iter()
            .find(|d| dir.join(d).is_dir())
            .ok_or_else(|| input_error(dir, "a BOP scene needs an rgb/ or gray/ folder"))?;
        let mask_dir = if dir.join("mask_visib").is_dir() { "mask_visib" } else { "mask" };
        Ok(Self { dir: dir.to_path_buf(), cameras, instances, color_dir, mask_dir })
    }

    /// The scene folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The images with annotations, in order.
    pub fn image_ids(&self) -> Vec<u32> {
        self.instances.keys().copied().collect()
    }

    /// The annotated instances of an image (empty for an unknown image).
    pub fn instances(&self, im_id: u32) -> &[BopInstance] {
        self.instances.get(&im_id).map_or(&[], Vec::as_slice)
    }

    /// The first instance of `obj_id` in image `im_id`.
    ///
    /// # Errors
    /// [`PipelineError::Input`] naming `scene_gt.json` when the image or the object is absent.
    pub fn instance(&self, im_id: u32, obj_id: u32) -> Result<&BopInstance, PipelineError> {
        let path = self.dir.join("scene_gt.json");
        let list = self.instances.get(&im_id).ok_or_else(|| input_error(&path, format!("no image {im_id}")))?;
        list.iter().find(|i| i.obj_id == obj_id).ok_or_else(|| {
            let present: Vec<u32> = list.iter().map(|i| i.obj_id).collect();
            input_error(&path, format!("image {im_id} has no object {obj_id} (it has {present:?})"))
        })
    }

    /// The camera of image `im_id` (its `scene_camera.json` entry).
    ///
    /// # Errors
    /// [`PipelineError::Input`] for an image without an entry, [`PipelineError::Camera`] for a
    /// malformed one.
    pub fn camera(&self, im_id: u32) -> Result<CameraFile, PipelineError> {
        let path = self.dir.join("scene_camera.json");
        let entry =
            self.cameras.get(&im_id).ok_or_else(|| input_error(&path, format!("no entry for image {im_id}")))?;
        Ok(CameraFile::from_json_value(entry, &format!("{} (image {im_id})", path.display()))?)
    }

    /// The files of image `im_id`: its colour image, its depth and the visible mask of the
    /// first instance of `obj_id`.
    ///
    /// # Errors
    /// As [`BopScene::instance`]; [`PipelineError::Input`] when the colour image is missing.
    pub fn files(&self, im_id: u32, obj_id: u32) -> Result<FrameFiles, PipelineError> {
        let instance = self.instance(im_id, obj_id)?;
        let color = ["png", "jpg"]
            .iter()
            .map(|ext| self.dir.join(self.color_dir).join(format!("{im_id:06}.{ext}")))
            .find(|p| p.is_file())
            .ok_or_else(|| input_error(&self.dir.join(self.color_dir), format!("no image {im_id:06}.png or .jpg")))?;
        Ok(FrameFiles {
            color,
            depth: self.dir.join("depth").join(format!("{im_id:06}.png")),
            mask: MaskSource::Binary(
                self.dir.join(self.mask_dir).join(format!("{im_id:06}_{:06}.png", instance.gt_id)),
            ),
        })
    }

    /// Image `im_id` with the visible mask of the first instance of `obj_id`.
    ///
    /// # Errors
    /// As [`BopScene::files`], [`BopScene::camera`] and [`FrameFiles::load`].
    pub fn frame(&self, im_id: u32, obj_id: u32) -> Result<RgbdFrame, PipelineError> {
        let files = self.files(im_id, obj_id)?;
        let scene = self.dir.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        files.load(&self.camera(im_id)?, &format!("{scene}/{im_id:06}/obj_{obj_id:06}"))
    }

    /// The motion of object `obj_id` from image `a` to image `b` in the camera frame:
    /// `T_ab = T_cam_b_from_obj * inv(T_cam_a_from_obj)` (for a static object and a moving
    /// camera, the camera's motion seen from the object).
    ///
    /// # Errors
    /// As [`BopScene::instance`].
    pub fn relative_motion(&self, a: u32, b: u32, obj_id: u32) -> Result<Pose, PipelineError> {
        Ok(self.instance(b, obj_id)?.cam_from_obj * self.instance(a, obj_id)?.cam_from_obj.inverse())
    }
}
