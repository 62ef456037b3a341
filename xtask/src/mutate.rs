//! `cargo xtask mutate`: a seeded random-mutation run of every input parser.
//!
//! Valid seed inputs of each format (PLY clouds, `.flo` flow, PBM masks, a BigBIRD object's
//! HDF5/JPEG/PBM files, PNG frames with a camera file, pipeline and noise-profile TOML, camera
//! JSON, pair-list CSV) are mutated at random (bits flipped, bytes set to edge values, cuts,
//! insertions, repeated chunks, numbers in text replaced by NaN, infinities, huge or negative
//! values) and fed to the parsers through their public API. A parser may refuse an input with
//! an error; it may not panic. Every panic is saved under `OUT/panics/` with its message.
//! Stable Rust has no coverage-guided fuzzer here (no nightly), hence seeded mutation.

use anyhow::Context;
use clap::Args;
use flowfilter_bigbird::{BigBirdObject, pbm};
use flowfilter_pipeline::batch::read_pairs;
use flowfilter_pipeline::depth::ply::{PlyFormat, read_ply, write_ply};
use flowfilter_pipeline::flow::{FlowField, flo};
use flowfilter_pipeline::{CameraFile, FrameFiles, MaskSource, PipelineConfig, PointCloud};
use flowfilter_synth::NoiseProfile;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Arguments of `mutate`.
#[derive(Args)]
pub struct MutateArgs {
    /// How long to run, seconds (CI: 20; the documented long run: 600).
    #[arg(long, default_value_t = 60.0)]
    pub seconds: f64,
    /// Seed of the mutations (the same seed and duration give the same first inputs).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Where panicking inputs are saved (`OUT/panics/`).
    #[arg(long, default_value = "target/mutate")]
    pub out: PathBuf,
}

/// A parser called on a case directory and the mutated file in it: whether it accepted it.
type Parser = dyn Fn(&Path, &Path) -> bool;

/// One format: its seed files and how its parser is called on a (mutated) file.
struct Target {
    name: &'static str,
    /// The seeds are the files of one directory (an object, a frame): each case holds all of
    /// them, one mutated. Otherwise a case is the one mutated file.
    together: bool,
    /// Seed inputs: (file name, bytes).
    seeds: Vec<(String, Vec<u8>)>,
    /// Parse the file at the given path inside the scratch directory: whether it was accepted
    /// (errors are fine).
    parse: Box<Parser>,
}

/// Run `mutate`.
pub fn run(args: &MutateArgs) -> anyhow::Result<()> {
    let root = crate::repo_root();
    let scratch = tempfile::tempdir().context("creating a scratch directory")?;
    let targets = targets(&root, scratch.path())?;
    let panics: Arc<Mutex<Vec<String>>> = Arc::default();
    let hook_panics = panics.clone();
    let previous = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let location = info.location().map_or(String::new(), |l| format!(" at {}:{}", l.file(), l.line()));
        hook_panics.lock().expect("not poisoned").push(format!("{info}{location}"));
    }));
    check_seeds(&targets, scratch.path())?;
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let (start, budget) = (Instant::now(), Duration::from_secs_f64(args.seconds.max(0.0)));
    // Per target: inputs, accepted, panics.
    let mut counts: BTreeMap<&str, (usize, usize, usize)> = BTreeMap::new();
    let mut saved = 0usize;
    while start.elapsed() < budget {
        let target = &targets[rng.random_range(0..targets.len())];
        let (name, seed) = &target.seeds[rng.random_range(0..target.seeds.len())];
        let input = mutate(seed, &mut rng);
        let case = scratch.path().join("case");
        let _ = std::fs::remove_dir_all(&case);
        std::fs::create_dir_all(&case)?;
        let file = case.join(name);
        write_case(&case, target, name, &input)?;
        let before = panics.lock().expect("not poisoned").len();
        let outcome = catch_unwind(AssertUnwindSafe(|| (target.parse)(&case, &file)));
        let entry = counts.entry(target.name).or_default();
        entry.0 += 1;
        entry.1 += usize::from(outcome.as_ref().is_ok_and(|accepted| *accepted));
        if outcome.is_err() || panics.lock().expect("not poisoned").len() > before {
            entry.2 += 1;
            saved += 1;
            let dir = args.out.join("panics");
            std::fs::create_dir_all(&dir)?;
            std::fs::write(dir.join(format!("{}-{saved}-{name}", target.name)), &input)?;
        }
    }
    std::panic::set_hook(previous);
    let total: usize = counts.values().map(|c| c.0).sum();
    println!("mutate: {total} inputs in {:.0} s (seed {})", start.elapsed().as_secs_f64(), args.seed);
    for (name, (n, ok, p)) in &counts {
        println!("  {name:<16} {n:>7} inputs, {ok:>7} accepted, {p} panics");
    }
    let messages = panics.lock().expect("not poisoned").clone();
    if messages.is_empty() {
        println!("no panic");
        Ok(())
    } else {
        for m in messages.iter().take(20) {
            eprintln!("panic: {m}");
        }
        anyhow::bail!("{} inputs panicked (saved under {})", messages.len(), args.out.join("panics").display())
    }
}

/// Every seed, unmutated, is accepted by its parser (else the run would test only refusals).
fn check_seeds(targets: &[Target], scratch: &Path) -> anyhow::Result<()> {
    for target in targets {
        for (name, bytes) in &target.seeds {
            let case = scratch.join("seed-check");
            let _ = std::fs::remove_dir_all(&case);
            std::fs::create_dir_all(&case)?;
            write_case(&case, target, name, bytes)?;
            anyhow::ensure!(
                (target.parse)(&case, &case.join(name)),
                "{}: the seed {name} is not accepted",
                target.name
            );
        }
    }
    Ok(())
}

/// Write one case: the BigBIRD target copies its whole object and replaces one file.
fn write_case(case: &Path, target: &Target, name: &str, input: &[u8]) -> anyhow::Result<()> {
    if target.together {
        for (other, bytes) in &target.seeds {
            let p = case.join(other);
            std::fs::create_dir_all(p.parent().expect("inside the case"))?;
            std::fs::write(p, bytes)?;
        }
    }
    let p = case.join(name);
    std::fs::create_dir_all(p.parent().expect("inside the case"))?;
    std::fs::write(p, input)?;
    Ok(())
}

/// A mutated copy of `seed`: one to four edits.
fn mutate(seed: &[u8], rng: &mut ChaCha8Rng) -> Vec<u8> {
    let mut v = seed.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        let len = v.len().max(1);
        let at = rng.random_range(0..len).min(v.len());
        match rng.random_range(0..8) {
            0 => {
                if !v.is_empty() {
                    let i = at.min(v.len() - 1);
                    v[i] ^= 1 << rng.random_range(0..8);
                }
            }
            1 => {
                if !v.is_empty() {
                    let i = at.min(v.len() - 1);
                    v[i] = [0u8, 0xFF, 0x7F, 0x80, b'-', b'9'][rng.random_range(0..6)];
                }
            }
            2 => v.truncate(at),
            3 => {
                let n = rng.random_range(1..64);
                let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                v.splice(at..at, bytes);
            }
            4 => {
                let end = (at + rng.random_range(1..256)).min(v.len());
                v.drain(at..end);
            }
            5 => {
                let end = (at + rng.random_range(1..512)).min(v.len());
                let chunk = v[at..end].to_vec();
                v.splice(at..at, chunk);
            }
            6 => replace_number(&mut v, rng),
            _ => {
                // A 4- or 8-byte field set to an edge value (counts, sizes, offsets).
                let edge: [u8; 8] = [u64::MAX, 0, u64::from(u32::MAX), 1 << 40][rng.random_range(0..4)].to_le_bytes();
                let n = if rng.random() { 4 } else { 8 };
                for (k, b) in edge.iter().take(n).enumerate() {
                    if let Some(slot) = v.get_mut(at + k) {
                        *slot = *b;
                    }
                }
            }
        }
    }
    v
}

/// Replace a number in text with an edge value.
fn replace_number(v: &mut Vec<u8>, rng: &mut ChaCha8Rng) {
    let starts: Vec<usize> =
        (0..v.len()).filter(|&i| v[i].is_ascii_digit() && (i == 0 || !v[i - 1].is_ascii_digit())).collect();
    if starts.is_empty() {
        return;
    }
    let s = starts[rng.random_range(0..starts.len())];
    let e = (s..v.len()).find(|&i| !(v[i].is_ascii_digit() || v[i] == b'.')).unwrap_or(v.len());
    let edge = ["nan", "inf", "-inf", "-1", "0", "1e308", "-1e308", "99999999999999999999", "1e-320", "4294967296"];
    v.splice(s..e, edge[rng.random_range(0..edge.len())].bytes());
}

/// Every format's seeds and parser.
fn targets(root: &Path, scratch: &Path) -> anyhow::Result<Vec<Target>> {
    let read = |p: PathBuf| std::fs::read(&p).with_context(|| format!("reading seed {}", p.display()));
    let mut ply = vec![];
    for name in ["ours_ascii.ply", "ours_binary.ply", "open3d_ascii.ply", "open3d_binary.ply"] {
        ply.push((name.to_string(), read(root.join("fixtures/ply").join(name))?));
    }
    let small = PointCloud {
        points: (0..20).map(|i| flowfilter_pipeline::Point3::new(i as f64 * 0.01, 0.0, 1.0)).collect(),
        normals: Some(vec![flowfilter_pipeline::geometry::Vector3::z(); 20]),
        colors: Some(vec![[10, 20, 30]; 20]),
        pixels: None,
    };
    let p = scratch.join("seed.ply");
    write_ply(&small, &p, PlyFormat::BinaryLittleEndian)?;
    ply.push(("seed.ply".into(), read(p)?));
    let mut field = FlowField::zeros(7, 5);
    field.flow.as_mut_slice()[3] = [1.5, -2.0];
    let object = root.join("fixtures/bigbird/latest/tiny_spheres");
    let mut bigbird = vec![];
    for entry in walk(&object)? {
        let rel = entry.strip_prefix(&object)?.to_string_lossy().into_owned();
        bigbird.push((rel, read(entry)?));
    }
    let masks: Vec<(String, Vec<u8>)> = bigbird.iter().filter(|(n, _)| n.ends_with(".pbm")).cloned().collect();
    let mut configs = vec![];
    for name in ["flowfilter.toml", "icp.toml", "cpd.toml", "filterreg.toml"] {
        configs.push((name.to_string(), read(root.join("configs").join(name))?));
    }
    let cameras = vec![
        ("bop.json".into(), br#"{"cam_K": [1066.7, 0.0, 312.9, 0.0, 1067.4, 241.3, 0.0, 0.0, 1.0], "depth_scale": 0.1}"#.to_vec()),
        (
            "open3d.json".into(),
            br#"{"width": 640, "height": 480, "intrinsic_matrix": [525.0, 0.0, 0.0, 0.0, 525.0, 0.0, 319.5, 239.5, 1.0]}"#
                .to_vec(),
        ),
    ];
    let pairs = vec![(
        "pairs.csv".into(),
        b"id,model_color,model_depth,target_color,target_depth,camera\na,m.png,md.png,t.png,td.png,cam.json\n".to_vec(),
    )];
    Ok(vec![
        Target { name: "ply", together: false, seeds: ply, parse: Box::new(|_, f| read_ply(f).is_ok()) },
        Target {
            name: "flo",
            together: false,
            seeds: vec![("seed.flo".into(), flo::encode(&field))],
            parse: Box::new(|_, f| flo::decode(&std::fs::read(f).unwrap_or_default(), f).is_ok()),
        },
        Target {
            name: "pbm",
            together: false,
            seeds: masks,
            parse: Box::new(|_, f| pbm::decode(&std::fs::read(f).unwrap_or_default()).is_ok()),
        },
        Target { name: "bigbird", together: true, seeds: bigbird, parse: Box::new(|dir, _| parse_bigbird(dir)) },
        Target {
            name: "png-frame",
            together: true,
            seeds: png_frame()?,
            parse: Box::new(|dir, _| parse_png_frame(dir)),
        },
        Target {
            name: "pipeline-toml",
            together: false,
            seeds: configs,
            parse: Box::new(|_, f| {
                PipelineConfig::from_toml_str(&String::from_utf8_lossy(&std::fs::read(f).unwrap_or_default()), f)
                    .is_ok()
            }),
        },
        Target {
            name: "noise-toml",
            together: false,
            seeds: vec![("carmine.toml".into(), flowfilter_synth::CARMINE_TOML.as_bytes().to_vec())],
            parse: Box::new(|_, f| {
                NoiseProfile::from_toml(&String::from_utf8_lossy(&std::fs::read(f).unwrap_or_default()), "mutated")
                    .is_ok()
            }),
        },
        Target {
            name: "camera-json",
            together: false,
            seeds: cameras,
            parse: Box::new(|_, f| CameraFile::from_file(f).is_ok_and(|c| c.model(Some((640, 480))).is_ok())),
        },
        Target { name: "pairs-csv", together: false, seeds: pairs, parse: Box::new(|_, f| read_pairs(f).is_ok()) },
    ])
}

/// Open, inspect and load every frame of the (mutated) BigBIRD object in `dir`: accepted when
/// inspect finds no problem.
fn parse_bigbird(dir: &Path) -> bool {
    let report = flowfilter_bigbird::inspect(dir);
    if let Ok(object) = BigBirdObject::open(dir) {
        for id in object.frames().collect::<Vec<_>>() {
            if let Ok(frame) = flowfilter_pipeline::load_bigbird_frame(&object, id) {
                let _ = flowfilter_pipeline::frame_checks::check_depth(&frame);
            }
        }
        let _ = object.relative_motion(flowfilter_bigbird::SensorId::ALL[0], 0, 3);
    }
    report.is_ok()
}

/// A frame of PNG files (colour, 16-bit depth, mask) with a camera file.
fn png_frame() -> anyhow::Result<Vec<(String, Vec<u8>)>> {
    let encode = |img: image::DynamicImage| -> anyhow::Result<Vec<u8>> {
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Png)?;
        Ok(bytes.into_inner())
    };
    let color = image::RgbImage::from_fn(32, 24, |x, y| image::Rgb([(x * 8) as u8, (y * 10) as u8, 77]));
    let depth =
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_fn(32, 24, |x, _| image::Luma([6000 + x as u16]));
    let mask =
        image::GrayImage::from_fn(32, 24, |x, y| image::Luma([if (8..24).contains(&x) && y > 4 { 255 } else { 0 }]));
    Ok(vec![
        ("color.png".into(), encode(color.into())?),
        ("depth.png".into(), encode(image::DynamicImage::ImageLuma16(depth))?),
        ("mask.png".into(), encode(mask.into())?),
        (
            "camera.json".into(),
            br#"{"cam_K": [30.0, 0.0, 15.5, 0.0, 30.0, 11.5, 0.0, 0.0, 1.0], "depth_scale": 0.1}"#.to_vec(),
        ),
    ])
}

/// Load the (mutated) PNG frame in `dir`.
fn parse_png_frame(dir: &Path) -> bool {
    let Ok(camera) = CameraFile::from_file(&dir.join("camera.json")) else { return false };
    let files = FrameFiles {
        color: dir.join("color.png"),
        depth: dir.join("depth.png"),
        mask: MaskSource::Binary(dir.join("mask.png")),
    };
    files.load(&camera, "mutated").is_ok_and(|frame| flowfilter_pipeline::frame_checks::check_depth(&frame).is_ok())
}

/// Every file under `dir`, sorted.
fn walk(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut out = vec![];
    for entry in std::fs::read_dir(dir)? {
        let p = entry?.path();
        if p.is_dir() { out.extend(walk(&p)?) } else { out.push(p) }
    }
    out.sort();
    Ok(out)
}
