//! Per-step timing of the depth stage on a synthesised Carmine-noise frame.
//! Run: `cargo run --release -p flowfilter-depth --example depth_timing` (`N=200` for more runs).

use flowfilter_bigbird::SensorId;
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame};

fn main() {
    let scene = Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1);
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    let f = render_frame(&scene, &rig, sensor, 30, Some(&NoiseProfile::carmine()), 1);
    let rgbd = rig.sensors[&sensor].rgbd;
    let stage = DepthStage::new(DepthConfig::default()).unwrap();
    for _ in 0..std::env::var("N").ok().and_then(|v| v.parse().ok()).unwrap_or(5) {
        let start = std::time::Instant::now();
        let out = stage.process(&f.raw_depth, &f.color, &f.mask, &rgbd).unwrap();
        let steps: Vec<String> = out.stats.timings_ms.iter().map(|(n, t)| format!("{n} {t:.2}")).collect();
        println!("total {:.2} ms: {}", start.elapsed().as_secs_f64() * 1e3, steps.join(", "));
    }
}
