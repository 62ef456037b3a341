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
//! cargo run --release -p flowfilter-track --example region_tilt -- target/region-masks 1 whole
//! ```
//!
//! Arguments: the masks' folder (one folder per sequence, as `--save-masks` writes them), the
//! pairs' frame gap (default 1), the reference (`whole`, the default, or `calibrated`); the
//! sequences are read from `../shared/data/realsense-shelf` (`FLOWFILTER_REAL` to change it).
//! Prints one row per pair, then, over the pairs within 5 deg of the reference: the correlation
//! of the region's tilt error with the depth's tilt, the slope of the one on the other, the
//! median tilt error with none, half and all of the depth's tilt taken out, and how much of what
//! the depth's share leaves a plane over the image explains (a lens or extrinsic calibration
//! error would grow with the region's place in the image).

use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, Pipeline, PipelineConfig, Pose, PreparedFrame};
use flowfilter_track::tum::read_calibrated_poses;
use nalgebra::{Matrix3, Vector2, Vector3};
use std::collections::hash_map::Entry;
use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};

type Error = Box<dyn std::error::Error>;

fn main() -> Result<(), Error> {
    let mut args = std::env::args().skip(1);
    let masks = PathBuf::from(args.next().ok_or("usage: region_tilt MASKS [GAP] [whole|calibrated]")?);
    let gap: usize = args.next().map_or(Ok(1), |g| g.parse())?;
    let whole_reference = args.next().is_none_or(|r| r == "whole");
    let data = PathBuf::from(std::env::var("FLOWFILTER_REAL").unwrap_or("../shared/data/realsense-shelf".into()));
    let pipeline = Pipeline::from_config(PipelineConfig::default())?;
    let mut rows: Vec<Row> = vec![];
    println!(
        "sequence from to region | depth tilt x y (deg) | tilt error x y (deg) | geodesic error (deg) | centre x y (px)"
    );
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
        // Each pair's whole target frame and reference, made once for both of its regions.
        let mut pairs: HashMap<usize, (PreparedFrame, Pose)> = HashMap::new();
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
            if let Entry::Vacant(slot) = pairs.entry(from) {
                let whole_target = pipeline.prepare(&sequence.frame(to, MaskSource::None)?)?;
                let reference = if whole_reference {
                    let whole_model = pipeline.prepare(&sequence.frame(from, MaskSource::None)?)?;
                    pipeline.estimate_prepared(&whole_model, &whole_target)?.pose
                } else {
                    sequence.motion(from, to)?
                };
                slot.insert((whole_target, reference));
            }
            let (whole_target, reference) = &pairs[&from];
            let Some(depth) = depth_tilt(&model, whole_target, reference) else { continue };
            let error = (estimate.rotation * reference.rotation.inverse()).scaled_axis();
            let deg = |v: f64| v.to_degrees();
            let centre = mask_centre(&model.mask);
            println!(
                "{name} {from} {to} {region} | {:.2} {:.2} | {:.2} {:.2} | {:.2} | {:.0} {:.0}",
                deg(depth.x),
                deg(depth.y),
                deg(error.x),
                deg(error.y),
                deg(error.norm()),
                centre.x,
                centre.y
            );
            if error.norm().to_degrees() <= 5.0 {
                rows.push(Row {
                    depth: depth.map(f64::to_degrees),
                    error: Vector2::new(deg(error.x), deg(error.y)),
                    centre,
                });
            }
        }
    }
    summarise(&rows);
    Ok(())
}

/// One shared sequence: its camera and calibrated camera poses.
struct Sequence {
    dir: PathBuf,
    camera: CameraFile,
    poses: BTreeMap<u64, Pose>,
}

impl Sequence {
    fn open(dir: &Path) -> Result<Self, Error> {
        let camera = CameraFile::from_file(&dir.join("camera.json"))?;
        let poses = read_calibrated_poses(&dir.join("poses.json"))?;
        Ok(Self { dir: dir.to_path_buf(), camera, poses })
    }

    fn frame(&self, n: usize, mask: MaskSource) -> Result<flowfilter_pipeline::RgbdFrame, Error> {
        let file = |kind: &str| self.dir.join(format!("frame-{n:06}.{kind}.png"));
        Ok(FrameFiles { color: file("color"), depth: file("depth"), mask }.load(&self.camera, &format!("{n}"))?)
    }

    /// The calibrated motion of the scene from frame `from`'s camera to frame `to`'s.
    fn motion(&self, from: usize, to: usize) -> Result<Pose, Error> {
        let pose = |n: usize| self.poses.get(&(n as u64)).ok_or(format!("poses.json: no pose of frame {n}"));
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

/// The mean pixel of `mask` (its centre in the image).
fn mask_centre(mask: &flowfilter_pipeline::Mask) -> Vector2<f64> {
    let (w, h) = mask.dims();
    let (mut sum, mut n) = (Vector2::zeros(), 0.0f64);
    for (x, y) in (0..h).flat_map(|y| (0..w).map(move |x| (x, y))).filter(|&(x, y)| *mask.at(x, y)) {
        sum += Vector2::new(x as f64, y as f64);
        n += 1.0;
    }
    sum / n.max(1.0)
}

/// One region pair: the depth's tilt and the estimate's tilt error (degrees, about the camera's
/// x and y axes), and the region's centre in the model image (pixels).
struct Row {
    depth: Vector2<f64>,
    error: Vector2<f64>,
    centre: Vector2<f64>,
}

/// The summary lines over the pairs within 5 deg of the reference.
fn summarise(rows: &[Row]) {
    if rows.len() < 3 {
        println!("{} pairs within 5 deg of the reference: too few to summarise", rows.len());
        return;
    }
    let n = rows.len() as f64;
    let correlation = |a: &dyn Fn(&Row) -> f64, b: &dyn Fn(&Row) -> f64| {
        let (ma, mb) = (rows.iter().map(a).sum::<f64>() / n, rows.iter().map(b).sum::<f64>() / n);
        let cov: f64 = rows.iter().map(|r| (a(r) - ma) * (b(r) - mb)).sum();
        let (va, vb): (f64, f64) =
            rows.iter().fold((0.0, 0.0), |(x, y), r| (x + (a(r) - ma).powi(2), y + (b(r) - mb).powi(2)));
        cov / (va * vb).sqrt()
    };
    let slope = rows.iter().map(|r| r.depth.dot(&r.error)).sum::<f64>()
        / rows.iter().map(|r| r.depth.norm_squared()).sum::<f64>();
    let median = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let without = |k: f64| median(rows.iter().map(|r| (r.error - r.depth * k).norm()).collect());
    println!(
        "{} pairs within 5 deg of the reference: correlation of the tilt error with the depth's tilt {:.2} (x) {:.2} (y), \
         slope {:.2}; median depth tilt {:.2} deg; median tilt error {:.2} deg, {:.2} with half the depth's tilt taken out, \
         {:.2} with all of it",
        rows.len(),
        correlation(&|r| r.depth.x, &|r| r.error.x),
        correlation(&|r| r.depth.y, &|r| r.error.y),
        slope,
        median(rows.iter().map(|r| r.depth.norm()).collect()),
        without(0.0),
        without(0.5),
        without(1.0)
    );
    // What the depth's share leaves, fitted by a plane over the image (a lens or extrinsic error
    // would grow with the region's place in the image).
    let fits: Vec<String> = (0..2)
        .map(|k| {
            let left = |r: &Row| r.error[k] - slope * r.depth[k];
            let (mut a, mut b) = (Matrix3::zeros(), Vector3::zeros());
            for r in rows {
                let x = Vector3::new(1.0, r.centre.x / 320.0 - 1.0, r.centre.y / 240.0 - 1.0);
                a += x * x.transpose();
                b += x * left(r);
            }
            let Some(c) = a.cholesky().map(|ch| ch.solve(&b)) else { return "no fit".into() };
            let mean = rows.iter().map(left).sum::<f64>() / n;
            let total: f64 = rows.iter().map(|r| (left(r) - mean).powi(2)).sum();
            let fitted: f64 = rows
                .iter()
                .map(|r| {
                    (left(r) - (c[0] + c[1] * (r.centre.x / 320.0 - 1.0) + c[2] * (r.centre.y / 240.0 - 1.0))).powi(2)
                })
                .sum();
            format!("{} mean {:.2} deg, R^2 {:.2}", ["x", "y"][k], mean, 1.0 - fitted / total)
        })
        .collect();
    println!("the tilt error less the depth's share against the region's place in the image: {}", fits.join("; "));
}
