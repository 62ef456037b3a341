//! How much of a region's rotation error its own depth explains: for every region pair that
//! `cargo xtask bench-real --save-masks DIR` wrote, the region's estimate, a reference motion
//! (the whole frames' estimate of the same pair, or the calibrated poses' motion), and the tilt
//! the region's depth asks for under that reference: the model frame's region moved by the
//! reference onto the target frame's depth, the depth differences fitted by a plane over the
//! region's image, and that plane's slopes read as the turn about the camera's x and y axes
//! that would take them up. A depth sensor that bends a patch's depth from one view to the next
//! pulls a registration of the patch by that turn.
//!
//! ```sh
//! cargo xtask bench-real --gaps 1 --no-whole --methods flowfilter --save-masks target/region-masks
//! cargo run --release -p flowfilter-pipeline --example region_tilt -- target/region-masks 1 whole
//! ```
//!
//! Arguments: the masks' folder (one folder per sequence, as `--save-masks` writes them), the
//! pairs' frame gap (default 1), the reference (`whole`, the default, or `calibrated`); the
//! sequences are read from `../shared/data/realsense-shelf` (`FLOWFILTER_REAL` to change it).
//! Prints one row per pair, then, over the pairs within 5 deg of the reference: the correlation
//! of the region's tilt error with the depth's tilt, the slope of the one on the other, and the
//! median tilt error with none, half and all of the depth's tilt taken out.

use flowfilter_camera::CameraFile;
use flowfilter_pipeline::{FrameFiles, MaskSource, Pipeline, PipelineConfig, Pose, PreparedFrame};
use nalgebra::{Matrix3, Rotation3, Translation3, UnitQuaternion, Vector2, Vector3};
use std::path::{Path, PathBuf};

type Error = Box<dyn std::error::Error>;

fn main() -> Result<(), Error> {
    let mut args = std::env::args().skip(1);
    let masks = PathBuf::from(args.next().ok_or("usage: region_tilt MASKS [GAP] [whole|calibrated]")?);
    let gap: usize = args.next().map_or(Ok(1), |g| g.parse())?;
    let whole_reference = args.next().is_none_or(|r| r == "whole");
    let data = PathBuf::from(std::env::var("FLOWFILTER_REAL").unwrap_or("../shared/data/realsense-shelf".into()));
    let pipeline = Pipeline::from_config(PipelineConfig::default())?;
    let mut rows = vec![];
    println!("sequence from to region | depth tilt x y (deg) | tilt error x y (deg) | geodesic error (deg)");
    let mut sequences: Vec<_> = std::fs::read_dir(&masks)?.filter_map(Result::ok).map(|e| e.path()).collect();
    sequences.sort();
    for seq_masks in sequences.iter().filter(|p| p.is_dir()) {
        let name = seq_masks.file_name().ok_or("a masks folder without a name")?.to_string_lossy().into_owned();
        let sequence = Sequence::open(&data.join(&name))?;
        let mut models: Vec<String> = std::fs::read_dir(seq_masks)?
            .filter_map(Result::ok)
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".model.png"))
            .collect();
        models.sort();
        for model_mask in models {
            // `frame-NNNNNN.region-K.model.png`
            let from: usize = model_mask.get(6..12).ok_or("not a frame-NNNNNN mask")?.parse()?;
            let region = model_mask.trim_end_matches(".model.png").rsplit('-').next().unwrap_or_default().to_string();
            let to = from + gap;
            let target_mask = seq_masks.join(format!("frame-{to:06}.region-{region}.target.png"));
            let masked = |n: usize, mask: &Path| sequence.frame(n, MaskSource::Binary(mask.to_path_buf()));
            let model = pipeline.prepare(&masked(from, &seq_masks.join(&model_mask))?)?;
            let target_source = if target_mask.exists() { MaskSource::Binary(target_mask) } else { MaskSource::None };
            let target = pipeline.prepare(&sequence.frame(to, target_source)?)?;
            let estimate = pipeline.estimate_prepared(&model, &target)?.pose;
            let whole_target = pipeline.prepare(&sequence.frame(to, MaskSource::None)?)?;
            let reference = if whole_reference {
                let whole_model = pipeline.prepare(&sequence.frame(from, MaskSource::None)?)?;
                pipeline.estimate_prepared(&whole_model, &whole_target)?.pose
            } else {
                sequence.motion(from, to)?
            };
            let Some(depth) = depth_tilt(&model, &whole_target, &reference) else { continue };
            let error = (estimate.rotation * reference.rotation.inverse()).scaled_axis();
            let deg = |v: f64| v.to_degrees();
            println!(
                "{name} {from} {to} {region} | {:.2} {:.2} | {:.2} {:.2} | {:.2}",
                deg(depth.x),
                deg(depth.y),
                deg(error.x),
                deg(error.y),
                deg(error.norm())
            );
            if error.norm().to_degrees() <= 5.0 {
                rows.push((depth.map(f64::to_degrees), Vector2::new(deg(error.x), deg(error.y))));
            }
        }
    }
    summarise(&rows);
    Ok(())
}

/// One shared sequence: its camera and calibrated poses.
struct Sequence {
    dir: PathBuf,
    camera: CameraFile,
    poses: serde_json::Value,
}

impl Sequence {
    fn open(dir: &Path) -> Result<Self, Error> {
        let camera = CameraFile::from_file(&dir.join("camera.json"))?;
        let poses = serde_json::from_str(&std::fs::read_to_string(dir.join("poses.json"))?)?;
        Ok(Self { dir: dir.to_path_buf(), camera, poses })
    }

    fn frame(&self, n: usize, mask: MaskSource) -> Result<flowfilter_pipeline::RgbdFrame, Error> {
        let file = |kind: &str| self.dir.join(format!("frame-{n:06}.{kind}.png"));
        Ok(FrameFiles { color: file("color"), depth: file("depth"), mask }.load(&self.camera, &format!("{n}"))?)
    }

    /// The calibrated motion of the scene from frame `from`'s camera to frame `to`'s.
    fn motion(&self, from: usize, to: usize) -> Result<Pose, Error> {
        let pose = |n: usize| -> Result<Pose, Error> {
            let m = &self.poses["camera_to_world_calibrated"][n.to_string()];
            let at = |r: usize, c: usize| m[r][c].as_f64().ok_or("poses.json: not a 4x4 matrix");
            let r = Matrix3::from_fn(|r, c| at(r, c).unwrap_or(f64::NAN));
            let t = Translation3::new(at(0, 3)?, at(1, 3)?, at(2, 3)?);
            Ok(Pose::from_parts(t, UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r))))
        };
        Ok(pose(to)?.inverse() * pose(from)?)
    }
}

/// The turn about the target camera's x and y axes (radians) that takes up the tilt of the
/// depth differences between `model`'s region moved by `motion` and `target`'s depth (within 1 cm
/// of each other): `z_target - z_moved ~ a + b (x - x0) + c (y - y0)` in normalised image
/// coordinates, read as `(c, -b) / z`. `None` with fewer than 100 such pixels.
fn depth_tilt(model: &PreparedFrame, target: &PreparedFrame, motion: &Pose) -> Option<Vector2<f64>> {
    let (w, h) = model.mask.dims();
    let mut seen = vec![];
    for (x, y) in (0..h).step_by(2).flat_map(|y| (0..w).step_by(2).map(move |x| (x, y))) {
        let z = f64::from(*model.depth.at(x, y));
        if !*model.mask.at(x, y) || z <= 0.0 {
            continue;
        }
        let Some(q) = model.rays.backproject(x, y, z).map(|p| motion * p) else { continue };
        let Some(px) = target.sensor.color.project(&q) else { continue };
        let (u, v) = (px.x.round(), px.y.round());
        if u < 0.0 || v < 0.0 || u as usize >= w || v as usize >= h {
            continue;
        }
        let seen_z = f64::from(*target.depth.at(u as usize, v as usize));
        if seen_z > 0.0 && (seen_z - q.z).abs() <= 0.01 {
            seen.push((q.x / q.z, q.y / q.z, seen_z - q.z, q.z));
        }
    }
    if seen.len() < 100 {
        return None;
    }
    let n = seen.len() as f64;
    let mean = |f: fn(&(f64, f64, f64, f64)) -> f64| seen.iter().map(f).sum::<f64>() / n;
    let (x0, y0, z0) = (mean(|s| s.0), mean(|s| s.1), mean(|s| s.3));
    let (mut a, mut b) = (Matrix3::zeros(), Vector3::zeros());
    for s in &seen {
        let row = Vector3::new(1.0, s.0 - x0, s.1 - y0);
        a += row * row.transpose();
        b += row * s.2;
    }
    let plane = a.cholesky()?.solve(&b);
    Some(Vector2::new(plane[2] / z0, -plane[1] / z0))
}

/// The summary lines over `(depth tilt, tilt error)` pairs (degrees).
fn summarise(rows: &[(Vector2<f64>, Vector2<f64>)]) {
    if rows.len() < 3 {
        println!("{} pairs within 5 deg of the reference: too few to summarise", rows.len());
        return;
    }
    let correlation = |k: usize| {
        let n = rows.len() as f64;
        let (mx, my) = (rows.iter().map(|r| r.0[k]).sum::<f64>() / n, rows.iter().map(|r| r.1[k]).sum::<f64>() / n);
        let cov: f64 = rows.iter().map(|r| (r.0[k] - mx) * (r.1[k] - my)).sum();
        let (vx, vy): (f64, f64) =
            rows.iter().fold((0.0, 0.0), |(a, b), r| (a + (r.0[k] - mx).powi(2), b + (r.1[k] - my).powi(2)));
        cov / (vx * vy).sqrt()
    };
    let slope = rows.iter().map(|r| r.0.dot(&r.1)).sum::<f64>() / rows.iter().map(|r| r.0.norm_squared()).sum::<f64>();
    let median_without = |k: f64| {
        let mut v: Vec<f64> = rows.iter().map(|r| (r.1 - r.0 * k).norm()).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mut depth: Vec<f64> = rows.iter().map(|r| r.0.norm()).collect();
    depth.sort_by(f64::total_cmp);
    println!(
        "{} pairs within 5 deg of the reference: correlation of the tilt error with the depth's tilt {:.2} (x) {:.2} (y), \
         slope {:.2}; median depth tilt {:.2} deg; median tilt error {:.2} deg, {:.2} with half the depth's tilt taken out, \
         {:.2} with all of it",
        rows.len(),
        correlation(0),
        correlation(1),
        slope,
        depth[depth.len() / 2],
        median_without(0.0),
        median_without(0.5),
        median_without(1.0)
    );
}
