//! `cargo xtask bench-bop`: in every BOP scene, every object seen in images `i` and `i + gap`
//! (each gap asked for, the visible fraction above a threshold in both), registered from the
//! first view to the second with every method and scored against `T_ab = T_b * inv(T_a)`,
//! beside the "no motion" answer.
//!
//! Without `--data` it runs on the embedded synthetic BOP dataset (`target/bop-default/test`):
//! per default object, scene `k` (camera NP3, turntable angles 0, 3, ..., 30 degrees: the gaps
//! 1, 5, 10 are 3, 15 and 30 degrees) and scene `100 + k` (camera NP2, angles 0, 0.25, ..., 2.5:
//! 0.25, 1.25 and 2.5 degrees), with Carmine depth noise and the real-sensor frame effects.

use crate::dataset::{BopSceneSpec, DefaultObject, SensorProfile, embedded_objects, ensure_bop_scene};
use crate::pairs::{Methods, PairJob, PairResult, RunArgs, progress};
use crate::report::{ReportSpec, ShardRun, write_outputs};
use crate::sequence::{Sequence, is_sequence, open_sequence};
use crate::shard::Shard;
use crate::{dir_name, in_repo};
use anyhow::{Context, bail};
use clap::Args;
use flowfilter_bigbird::SensorId;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Arguments of `bench-bop`.
#[derive(Args)]
pub struct BopBenchArgs {
    /// A BOP split folder (e.g. `ycbv/test`: one folder per scene) or one scene folder, or a
    /// folder of YCB-Video frames (`NNNNNN-color.png`, `-depth.png`, `-label.png`, `-gt.json`,
    /// as `../shared/data/ycb-video/0001`); default: the embedded synthetic BOP dataset.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Scene ids to run (folder names as numbers), comma separated; default: all.
    #[arg(long, value_delimiter = ',')]
    pub scenes: Option<Vec<u32>>,
    /// Image gaps: pairs are images `i` and `i + gap` (default 1,5,10; 1,4 with --quick).
    #[arg(long, value_delimiter = ',')]
    pub gaps: Option<Vec<u32>>,
    /// Methods, comma separated.
    #[arg(long, value_delimiter = ',', default_value = "icp-pt2pl,cpd,filterreg-pt2pt,flowfilter")]
    pub methods: Vec<String>,
    /// Pipeline configuration shared by the methods (its `method` key is replaced by each name).
    #[arg(long, default_value = "configs/flowfilter.toml")]
    pub pipeline: PathBuf,
    /// Smallest visible fraction (`visib_fract` of `scene_gt_info.json`) of an object in both
    /// images; 0.1 is the BOP benchmark's own threshold for test targets.
    #[arg(long, default_value_t = 0.1)]
    pub min_visib: f64,
    /// Small embedded dataset for CI: the procedural objects, 5 images per scene, gaps 1 and 4.
    #[arg(long)]
    pub quick: bool,
    /// Directories of textured meshes (`*/textured.obj`) to add to the embedded dataset
    /// (default: ../shared/data/ycb when present; not used with --quick).
    #[arg(long)]
    pub meshes: Option<PathBuf>,
    /// The sensor the embedded scenes are rendered with: `carmine` (the default dataset), or
    /// `sr300-shelf`, a twin of the shared RealSense SR300 shelf sequences (their noise profile
    /// with its depth warp, exposure and white-balance changes; masks with a segmentation
    /// network's defects, `NetworkMaskModel::SHELF_NETWORK` without missing masks), cached apart.
    #[arg(long, value_enum, default_value_t = SensorProfile::Carmine)]
    pub sensor_profile: SensorProfile,
    /// Outputs, voxel size, check.
    #[command(flatten)]
    pub run: RunArgs,
}

/// A frame of a scene: an image and the object whose mask it uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
struct BopKey {
    im_id: u32,
    obj_id: u32,
}

impl fmt::Display for BopKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:06}/obj_{:06}", self.im_id, self.obj_id)
    }
}

/// Run the benchmark scene by scene.
pub fn run(args: &BopBenchArgs) -> anyhow::Result<()> {
    let gaps = args.gaps.clone().unwrap_or_else(|| if args.quick { vec![1, 4] } else { vec![1, 5, 10] });
    if gaps.is_empty() || gaps.contains(&0) {
        bail!("--gaps: give one or more gaps of at least 1 image");
    }
    if !(0.0..=1.0).contains(&args.min_visib) {
        bail!("--min-visib: expected a fraction in [0, 1], found {}", args.min_visib);
    }
    let configs = crate::pairs::method_configs(&args.pipeline, &args.methods, args.run.voxel)?;
    let mut methods = Methods::new(&args.methods, &configs)?;
    methods.record_failures(args.run.rerun.as_deref(), args.run.rerun_limit)?;
    let started = Instant::now();
    let Scenes { all: all_scenes, dirs: scene_dirs, names } = scene_dirs(args)?;
    let mut results: Vec<PairResult> = vec![];
    let mut skipped: Vec<(String, String)> = vec![];
    for dir in &scene_dirs {
        let label = dir_name(dir);
        let scene = match open_sequence(dir) {
            Ok(s) => s,
            Err(e) => {
                tracing::warn!(scene = %label, error = %e, "skipping scene");
                skipped.push((label, e.to_string()));
                continue;
            }
        };
        let jobs = scene_jobs(scene.as_ref(), &label, &gaps, args.min_visib, &names);
        if jobs.is_empty() {
            skipped.push((label, format!("no object is visible in two images {gaps:?} apart")));
            continue;
        }
        let mut frames: Vec<BopKey> = jobs.iter().flat_map(|j| [j.model, j.target]).collect();
        frames.sort();
        frames.dedup();
        let profile = if args.data.is_none() { args.sensor_profile } else { SensorProfile::Carmine };
        let load = |k: BopKey| {
            scene.frame(k.im_id, k.obj_id).map(|mut f| {
                profile.mask(&mut f, &label, (k.im_id, k.obj_id));
                f
            })
        };
        let prepared = methods.prepare(&frames, &load, &format!("scene {label}"));
        results.append(&mut methods.run(&jobs, &prepared, &load, &format!("scene {label}"))?);
    }
    // A shard may hold no pair (more shards than scenes, or only skipped scenes): the merge
    // decides whether the run as a whole has any.
    if results.is_empty() && args.run.shard.is_none() {
        bail!("no pair to run: {}", skipped.iter().map(|(g, e)| format!("{g}: {e}")).collect::<Vec<_>>().join("; "));
    }
    let spec = ReportSpec {
        bench: "bench-bop",
        dataset: args.data.as_ref().map_or_else(
            || format!("embedded synthetic BOP scenes ({})", default_root(args).display()),
            |d| d.display().to_string(),
        ),
        protocol: serde_json::json!({
            "scenes": all_scenes,
            "gaps": gaps,
            "methods": args.methods,
            "pipeline": args.pipeline,
            "min_visib": args.min_visib,
            "voxel": args.run.voxel,
            "sensor_profile": args.data.is_none().then(|| format!("{:?}", args.sensor_profile)),
        }),
        protocol_line: format!(
            "{} scene(s), gaps {:?}, visible fraction >= {}, pipeline {}",
            all_scenes.len(),
            gaps,
            args.min_visib,
            args.pipeline.display()
        ),
        step_label: "image gap",
        methods: &args.methods,
        references: &[],
        appendix: String::new(),
        out: &args.run.out,
        check: args.run.check,
        shard: args.run.shard.map(|shard| ShardRun { shard, group_field: "camera", all_groups: all_scenes.clone() }),
    };
    methods.finish_recording()?;
    write_outputs(&spec, &results, &skipped, started.elapsed().as_secs_f64())?;
    Ok(())
}

/// Every (image, image + gap, object) of a scene whose object is annotated once in both images
/// and visible enough in both (an object without `scene_gt_info.json` counts as visible).
fn scene_jobs(
    scene: &dyn Sequence,
    label: &str,
    gaps: &[u32],
    min_visib: f64,
    names: &BTreeMap<u32, String>,
) -> Vec<PairJob<BopKey>> {
    let visible = |im: u32, obj: u32| {
        let list = scene.instances(im);
        let mut of_obj = list.iter().filter(|i| i.0 == obj);
        match (of_obj.next(), of_obj.next()) {
            (Some(i), None) => i.1.is_none_or(|v| v >= min_visib),
            _ => false, // absent, or several instances: which one moved where is ambiguous
        }
    };
    let mut jobs = vec![];
    let ids = scene.image_ids();
    for &gap in gaps {
        for &a in &ids {
            let b = a + gap;
            let mut objects: Vec<u32> = scene.instances(a).iter().map(|i| i.0).collect();
            objects.sort_unstable();
            objects.dedup();
            for obj in objects {
                if !(visible(a, obj) && visible(b, obj)) {
                    continue;
                }
                jobs.push(PairJob {
                    object: names
                        .get(&obj)
                        .cloned()
                        .or_else(|| scene.object_name(obj))
                        .unwrap_or_else(|| format!("obj_{obj:06}")),
                    camera: label.to_string(),
                    from: a,
                    to: b,
                    step: gap,
                    model: BopKey { im_id: a, obj_id: obj },
                    target: BopKey { im_id: b, obj_id: obj },
                    truth: scene.relative_motion(a, b, obj),
                });
            }
        }
    }
    jobs
}

/// Where the embedded dataset is cached.
fn default_root(args: &BopBenchArgs) -> PathBuf {
    in_repo(&Path::new("target").join(args.sensor_profile.folder(args.quick)).join("test"))
}

/// The run's scenes: every scene (labels, in order), this shard's folders, and the object names
/// known for their ids.
struct Scenes {
    all: Vec<String>,
    dirs: Vec<PathBuf>,
    names: BTreeMap<u32, String>,
}

/// Whether a scene (by folder name) is one `--scenes` asks for.
fn wanted(args: &BopBenchArgs, label: &str) -> bool {
    args.scenes.as_ref().is_none_or(|w| label.parse::<u32>().is_ok_and(|i| w.contains(&i)))
}

/// The scene folders (filtered by `--scenes`, then this shard's) and the object names known for
/// their ids.
fn scene_dirs(args: &BopBenchArgs) -> anyhow::Result<Scenes> {
    let shard = args.run.shard.unwrap_or(Shard::ALL);
    let mut dirs = match &args.data {
        None => return default_dataset(args, shard),
        Some(root) if is_sequence(root) => vec![root.clone()],
        Some(root) => {
            let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
                .with_context(|| format!("reading {}", root.display()))?
                .filter_map(Result::ok)
                .map(|e| e.path())
                .filter(|p| is_sequence(p))
                .collect();
            dirs.sort();
            if dirs.is_empty() {
                bail!(
                    "{}: no scene folders (BOP folders holding scene_gt.json, or YCB-Video frames NNNNNN-gt.json)",
                    root.display()
                );
            }
            dirs
        }
    };
    if args.scenes.is_some() {
        dirs.retain(|d| wanted(args, &dir_name(d)));
        if dirs.is_empty() {
            bail!("--scenes {:?}: none of these scenes is in the dataset", args.scenes.as_deref().unwrap_or_default());
        }
    }
    Ok(Scenes { all: dirs.iter().map(|d| dir_name(d)).collect(), dirs: shard.select(&dirs), names: BTreeMap::new() })
}

/// The embedded dataset's scenes of one object (see the module documentation).
fn default_scenes(k: u32, quick: bool) -> [BopSceneSpec; 2] {
    let (coarse, fine) = if quick { (4, 4) } else { (10, 10) };
    let np = |i| SensorId::new(i).expect("NP2 and NP3 exist");
    [
        BopSceneSpec { scene_id: k, sensor: np(3), angles_deg: (0..=coarse).map(|i| 3.0 * f64::from(i)).collect() },
        BopSceneSpec {
            scene_id: 100 + k,
            sensor: np(2),
            angles_deg: (0..=fine).map(|i| 0.25 * f64::from(i)).collect(),
        },
    ]
}

/// Synthesise (once, cached) the embedded dataset's scenes of this shard.
fn default_dataset(args: &BopBenchArgs, shard: Shard) -> anyhow::Result<Scenes> {
    let objects: Vec<DefaultObject> = embedded_objects(args.quick, args.meshes.as_deref());
    let root = default_root(args);
    let sensor = args.sensor_profile.sensor();
    let mut work: Vec<(u32, &DefaultObject, BopSceneSpec)> = objects
        .iter()
        .zip(1u32..)
        .flat_map(|(o, k)| default_scenes(k, args.quick).into_iter().map(move |s| (k, o, s)))
        .filter(|(_, _, spec)| wanted(args, &spec.scene_id.to_string()))
        .collect();
    if work.is_empty() {
        bail!("--scenes {:?}: none of these scenes is in the dataset", args.scenes.as_deref().unwrap_or_default());
    }
    // Scene folders are named by their six-digit id: their order is the ids'.
    work.sort_by_key(|(_, _, spec)| spec.scene_id);
    let all = work.iter().map(|(_, _, spec)| format!("{:06}", spec.scene_id)).collect();
    let mine: Vec<_> = work.iter().enumerate().filter(|(i, _)| shard.owns(*i)).map(|(_, w)| w).collect();
    let bar = progress(mine.len() as u64, "synthesising the default BOP scenes (cached)");
    let dirs = mine
        .par_iter()
        .map(|(k, o, spec)| {
            let d = ensure_bop_scene(&root, o, *k, spec, 7, &sensor);
            bar.inc(1);
            d
        })
        .collect::<anyhow::Result<Vec<_>>>()?;
    bar.finish();
    let names = objects.iter().zip(1u32..).map(|(o, k)| (k, o.name.clone())).collect();
    Ok(Scenes { all, dirs, names })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn copy_dir(from: &Path, to: &Path) {
        std::fs::create_dir_all(to).unwrap();
        for e in std::fs::read_dir(from).unwrap() {
            let p = e.unwrap().path();
            let target = to.join(p.file_name().unwrap());
            if p.is_dir() { copy_dir(&p, &target) } else { std::fs::copy(&p, &target).map(|_| ()).unwrap() }
        }
    }

    /// Outputs to `out`, checked, whole (no shard, no recording).
    pub(super) fn checked_run(out: PathBuf) -> RunArgs {
        RunArgs { out, voxel: None, check: true, shard: None, rerun: None, rerun_limit: 20 }
    }

    /// Run `args` and read the `results.json` it wrote (the only run in its output folder).
    pub(super) fn run_results(args: &BopBenchArgs) -> serde_json::Value {
        run(args).unwrap();
        let run_dir = std::fs::read_dir(&args.run.out).unwrap().next().unwrap().unwrap().path();
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("results.json")).unwrap()).unwrap()
    }

    fn args(data: PathBuf, out: PathBuf) -> BopBenchArgs {
        BopBenchArgs {
            data: Some(data),
            scenes: None,
            gaps: Some(vec![1, 2]),
            methods: vec!["icp-pt2pl".into(), "flowfilter".into()],
            pipeline: PathBuf::from("configs/flowfilter.toml"),
            min_visib: 0.1,
            quick: false,
            meshes: None,
            sensor_profile: SensorProfile::Carmine,
            run: RunArgs { out, voxel: Some(0.002), check: true, shard: None, rerun: None, rerun_limit: 20 },
        }
    }

    /// `--sensor-profile sr300-shelf`: the embedded scenes rendered again with the SR300's
    /// cameras, noise and sparse registered depth (cached apart from the default ones), the
    /// masks with a segmentation network's defects, the profile in the report.
    #[test]
    fn the_sr300_profile_renders_its_own_scenes() {
        let tmp = tempfile::tempdir().unwrap();
        let args = BopBenchArgs {
            data: None,
            scenes: Some(vec![1]),
            gaps: Some(vec![4]),
            methods: vec!["icp-pt2pl".into()],
            pipeline: PathBuf::from("configs/flowfilter.toml"),
            min_visib: 0.1,
            quick: true,
            meshes: None,
            sensor_profile: SensorProfile::Sr300Shelf,
            run: checked_run(tmp.path().into()),
        };
        let v = run_results(&args);
        assert_eq!(v["protocol"]["sensor_profile"], "Sr300Shelf");
        let scene = default_root(&args).join("000001");
        assert!(scene.ends_with("bop-sr300-shelf-quick/test/000001"), "{}", scene.display());
        let depth = image::open(scene.join("depth/000000.png")).unwrap().into_luma16();
        assert_eq!(depth.dimensions(), (640, 480));
        let mask = image::open(scene.join("mask_visib/000000_000000.png")).unwrap().into_luma8();
        let inside: Vec<u16> =
            depth.pixels().zip(mask.pixels()).filter(|(_, m)| m.0[0] > 0).map(|(d, _)| d.0[0]).collect();
        let valid = inside.iter().filter(|&&d| d > 0).count() as f64 / inside.len() as f64;
        assert!((0.2..0.45).contains(&valid), "{valid}");
        // The network's defects move the masks the pipeline is given.
        let frame = open_sequence(&scene).unwrap().frame(0, 1).unwrap();
        let mut defective = frame.clone();
        args.sensor_profile.mask(&mut defective, "000001", (0, 1));
        assert_eq!(defective.mask.dims(), frame.mask.dims());
        assert_ne!(defective.mask.as_slice(), frame.mask.as_slice());
    }

    /// A target frame of sparse registered depth (the SR300's lattice and dropped blocks) that
    /// comes without a mask is prepared as densely as one with its mask: the flow finds as many
    /// pairs with depth at both ends, and the estimate is as close. Before, such a frame's mask
    /// was its pixels with depth, no hole was filled, and 74 pairs of 1242 tracked survived
    /// (630 with the mask); tracks from one mask on these scenes ended up to 22 deg off.
    #[test]
    fn a_sparse_frame_without_a_mask_is_filled_as_a_masked_one() {
        use flowfilter_pipeline::bop::BopScene;
        use flowfilter_pipeline::{MaskSource, Pipeline, PipelineConfig};
        let tmp = tempfile::tempdir().unwrap();
        let object = &embedded_objects(true, None)[0];
        let spec = BopSceneSpec { scene_id: 1, sensor: SensorId::new(3).unwrap(), angles_deg: vec![0.0, 3.0] };
        let sensor = crate::dataset::SceneSensor::sr300_shelf();
        let dir = ensure_bop_scene(tmp.path(), object, 1, &spec, 7, &sensor).unwrap();
        let scene = BopScene::open(&dir).unwrap();
        let (model, masked) = (scene.frame(0, 1).unwrap(), scene.frame(1, 1).unwrap());
        let mut files = scene.files(1, 1).unwrap();
        files.mask = MaskSource::None;
        let unmasked = files.load(&scene.camera(1).unwrap(), "unmasked").unwrap();
        assert!(unmasked.mask.as_slice().iter().all(|m| *m), "a frame without a mask covers the image");
        let truth = scene.relative_motion(0, 1, 1).unwrap();
        let pipeline = Pipeline::from_config(PipelineConfig::default()).unwrap();
        let (a, b) = (pipeline.estimate(&model, &masked).unwrap(), pipeline.estimate(&model, &unmasked).unwrap());
        let pairs = |e: &flowfilter_pipeline::Estimate| e.correspondences.map_or(0, |c| c.consistent);
        assert!(pairs(&a) >= 200, "{:?}", a.correspondences);
        assert!(
            pairs(&b) as f64 >= 0.7 * pairs(&a) as f64,
            "masked {:?}, unmasked {:?}",
            a.correspondences,
            b.correspondences
        );
        let error = |e: &flowfilter_pipeline::Estimate| flowfilter_eval::geodesic_error_deg(&e.pose, &truth);
        assert!(error(&b) < 0.5, "unmasked target {} deg off (masked {})", error(&b), error(&a));
    }

    /// The BOP fixture (written by tools/peers/bop_fixture.py) beside a scene without
    /// scene_camera.json: the broken scene is skipped with its reason, every pair of the other runs
    /// with the "no motion" row, and the outputs are written.
    #[test]
    fn bop_scenes_run_pair_by_pair_and_broken_scenes_are_skipped() {
        let tmp = tempfile::tempdir().unwrap();
        let data = tmp.path().join("test");
        copy_dir(&crate::repo_root().join("fixtures/bop/000001"), &data.join("000001"));
        copy_dir(&crate::repo_root().join("fixtures/bop/000001"), &data.join("000002"));
        std::fs::remove_file(data.join("000002/scene_camera.json")).unwrap();
        let out = tmp.path().join("results");
        run(&args(data.clone(), out.clone())).unwrap();
        let run_dir = std::fs::read_dir(&out).unwrap().next().unwrap().unwrap().path();
        let v: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run_dir.join("results.json")).unwrap()).unwrap();
        assert_eq!(v["schema"], "flowfilter bench-bop results v3");
        let skipped = v["skipped"].as_array().unwrap();
        assert!(skipped.len() == 1 && skipped[0].as_str().unwrap().contains("scene_camera.json"), "{skipped:?}");
        // Gap 1: the plate (7) in 0->1 and 1->2, the box (3) in 0->1 (it leaves after image 1);
        // gap 2: the plate in 0->2. Two methods and "no motion" each.
        let pairs = v["pairs"].as_array().unwrap();
        assert_eq!(pairs.len(), 4 * 3);
        let plate: Vec<(u64, u64)> = pairs
            .iter()
            .filter(|p| p["object"] == "obj_000007" && p["method"] == "no-motion")
            .map(|p| (p["from"].as_u64().unwrap(), p["to"].as_u64().unwrap()))
            .collect();
        assert_eq!(plate, [(0, 1), (1, 2), (0, 2)]);
        // "No motion" scores the true motion itself.
        for p in pairs.iter().filter(|p| p["method"] == "no-motion") {
            let (e, m) = (p["errors"]["geodesic_error_deg"].as_f64().unwrap(), p["motion_deg"].as_f64().unwrap());
            assert!((e - m).abs() < 1e-9, "{p}");
        }
        for f in ["pairs.csv", "summary.md", "error_vs_step.svg", "per_object.svg", "stage_times.svg"] {
            assert!(run_dir.join(f).is_file(), "{f} missing");
        }
        // --scenes selects by folder number; a scene that is not there is an error.
        let mut only = args(data.clone(), tmp.path().join("r2"));
        only.scenes = Some(vec![5]);
        let e = run(&only).unwrap_err().to_string();
        assert!(e.contains("--scenes [5]"), "{e}");
    }
}

#[cfg(test)]
mod real_frames {
    use super::tests::{checked_run, run_results};
    use super::*;

    /// The real YCB-Video frames of `../shared/data/ycb-video/0001` (skipped with a message when
    /// the shared data is absent) run through the same benchmark as a folder of YCB-Video frames:
    /// label masks, the frames' own `-gt.json` as camera and ground truth, object names from it.
    #[test]
    fn ycb_video_frames_run_as_a_sequence() {
        let Some(data) = crate::shared_or_skip("data/ycb-video/0001") else { return };
        let tmp = tempfile::tempdir().unwrap();
        let args = BopBenchArgs {
            data: Some(data),
            scenes: None,
            gaps: Some(vec![4]),
            methods: vec!["flowfilter".into()],
            pipeline: PathBuf::from("configs/flowfilter.toml"),
            min_visib: 0.1,
            quick: false,
            meshes: None,
            sensor_profile: SensorProfile::Carmine,
            run: checked_run(tmp.path().into()),
        };
        let v = run_results(&args);
        let mut objects: Vec<&str> =
            v["pairs"].as_array().unwrap().iter().map(|p| p["object"].as_str().unwrap()).collect();
        objects.dedup();
        assert_eq!(objects, ["002_master_chef_can", "003_cracker_box", "004_sugar_box", "006_mustard_bottle"]);
        // Frame 1 -> 5: true motions of 0.2-0.4 deg, which "no motion" misses by exactly that much.
        for p in v["pairs"].as_array().unwrap() {
            let m = p["motion_deg"].as_f64().unwrap();
            assert!((0.1..0.6).contains(&m), "{p}");
            assert_eq!((p["from"].as_u64(), p["to"].as_u64()), (Some(1), Some(5)));
        }
    }
}
