//! The depth stage on one synthesised frame: filtered depth registered to the colour camera,
//! an organised cloud with normals, thinned by a voxel grid and written as PLY.
//! Run: `cargo run --release -p flowfilter-depth --example depth_to_ply -- OUT.ply`.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::cloud::voxel_downsample;
use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args().nth(1).ok_or("usage: depth_to_ply OUT.ply")?;
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).expect("NP1..NP5");
    let scene = Scene::new(procedural("can", 2)?.placed_on_table(0.0, 0.0), 2);
    let frame = render_frame(&scene, &rig, sensor, 45, Some(&NoiseProfile::carmine()), 7);
    let stage = DepthStage::new(DepthConfig::default())?;
    let processed = stage.process(&frame.raw_depth, &frame.color, &frame.mask, &rig.sensors[&sensor].rgbd)?;
    let cloud = voxel_downsample(&processed.cloud, 0.003);
    println!(
        "{} points ({} before the 3 mm voxel grid); stage steps (ms): {:?}",
        cloud.len(),
        processed.cloud.len(),
        processed.stats.timings_ms
    );
    write_ply(&cloud, out.as_ref(), PlyFormat::BinaryLittleEndian)?;
    Ok(())
}
