//! The depth stage on a synthesised Carmine-noise frame: 640x480 raw depth -> filtered,
//! registered, interpolated 1280x1024 depth and an object cloud with normals.
//! Run: `cargo bench -p flowfilter-depth --bench depth`.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::{DepthConfig, DepthStage, NormalMethod};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame};

fn main() {
    divan::main();
}

#[divan::bench(args = ["organized", "knn"], sample_count = 20)]
fn depth_stage(bencher: divan::Bencher, normals: &str) {
    let scene = Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1);
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    let frame = render_frame(&scene, &rig, sensor, 30, Some(&NoiseProfile::carmine()), 1);
    let mut config = DepthConfig::default();
    config.cloud.normals = if normals == "knn" { NormalMethod::Knn } else { NormalMethod::Organized };
    let stage = DepthStage::new(config).unwrap();
    let rgbd = rig.sensors[&sensor].rgbd;
    stage.process(&frame.raw_depth, &frame.color, &frame.mask, &rgbd).unwrap(); // warm the ray cache
    bencher.bench(|| stage.process(&frame.raw_depth, &frame.color, &frame.mask, &rgbd).unwrap());
}
