//! Per-step timing of a frame's preparation (the depth stage, then the registration cloud's
//! thinning) on a real frame from files, whole (no mask): the median of `N` runs (default 40).
//!
//! ```sh
//! RAYON_NUM_THREADS=1 cargo run --release -p flowfilter-pipeline --example frame_timing -- \
//!     ../shared/data/realsense-shelf/shelf-A 2
//! ```
//!
//! Arguments: a folder with `camera.json` and `frame-NNNNNN.{color,depth}.png`, and the frame
//! number (default 0).

use flowfilter_camera::CameraFile;
use flowfilter_depth::DepthStage;
use flowfilter_pipeline::{CloudThinning, FrameFiles, MaskSource, Pipeline, PipelineConfig};
use std::path::PathBuf;
use std::time::Instant;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let folder = PathBuf::from(args.next().ok_or("usage: frame_timing FOLDER [FRAME]")?);
    let number: usize = args.next().map_or(Ok(0), |n| n.parse())?;
    let runs: usize = std::env::var("N").ok().and_then(|v| v.parse().ok()).unwrap_or(40).max(1);
    let camera = CameraFile::from_file(&folder.join("camera.json"))?;
    let file = |kind: &str| folder.join(format!("frame-{number:06}.{kind}.png"));
    let frame =
        FrameFiles { color: file("color"), depth: file("depth"), mask: MaskSource::None }.load(&camera, "frame")?;
    let config = PipelineConfig::default();
    let stage = DepthStage::new(config.depth.clone())?;
    let pipeline = Pipeline::from_config(config.clone())?;
    let mut steps: Vec<(&str, Vec<f64>)> = vec![];
    let (mut thinning, mut prepare, mut points) = (vec![], vec![], 0);
    for _ in 0..runs {
        let out = stage.process(&frame.depth, &frame.color, &frame.mask, &frame.sensor)?;
        for (i, &(name, ms)) in out.stats.timings_ms.iter().enumerate() {
            if steps.len() <= i {
                steps.push((name, vec![]));
            }
            steps[i].1.push(ms);
        }
        let start = Instant::now();
        let mut cloud = out.cloud;
        (points, cloud.colors) = (cloud.len(), None);
        std::hint::black_box(CloudThinning::thin(&cloud, &config.cloud));
        thinning.push(start.elapsed().as_secs_f64() * 1e3);
        let start = Instant::now();
        std::hint::black_box(pipeline.prepare(&frame)?);
        prepare.push(start.elapsed().as_secs_f64() * 1e3);
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let mut line: Vec<String> = steps.iter_mut().map(|(name, v)| format!("{name} {:.2}", median(v))).collect();
    line.push(format!("thinning {:.2}", median(&mut thinning)));
    println!("{points} points; median ms of {runs} runs: {}", line.join(", "));
    println!("the whole preparation (Pipeline::prepare): {:.2} ms", median(&mut prepare));
    Ok(())
}
