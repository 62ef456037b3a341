//! Writes partial-view registration cases from the synthesiser for the peers harness:
//! `fixtures/peers/registration/partial_{k}_{source,target}.ply` and `partial_{k}.json` (truth).
//! Run: `cargo run --release -p flowfilter-registration --example partial_view_cases`.

use flowfilter_bigbird::SensorId;
use flowfilter_depth::cloud::voxel_downsample;
use flowfilter_depth::ply::{PlyFormat, write_ply};
use flowfilter_depth::{DepthConfig, DepthStage};
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame, world_from_table};
use std::path::Path;

fn main() {
    let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/peers/registration");
    std::fs::create_dir_all(&out).unwrap();
    let rig = Rig::bigbird_like();
    let stage = DepthStage::new(DepthConfig::default()).unwrap();
    let noise = NoiseProfile::carmine();
    let cases = [("box", 3u8, 0u32, 15u32), ("can", 3, 30, 60), ("bottle", 2, 90, 111)];
    for (k, (object, cam, a, b)) in cases.into_iter().enumerate() {
        let scene = Scene::new(procedural(object, 10 + k as u64).unwrap().placed_on_table(0.01, -0.005), 10 + k as u64);
        let sensor = SensorId::new(cam).unwrap();
        let s = &rig.sensors[&sensor];
        let cloud = |angle: u32| {
            let f = render_frame(&scene, &rig, sensor, angle, Some(&noise), 10 + k as u64);
            let mut c = stage.process(&f.raw_depth, &f.color, &f.mask, &s.rgbd).unwrap().cloud;
            c.colors = None;
            c.pixels = None;
            voxel_downsample(&c, 0.006)
        };
        let (source, target) = (cloud(a), cloud(b));
        let h = |angle: u32| s.h_color_from_world * world_from_table(f64::from(angle));
        let truth = h(b) * h(a).inverse();
        let stem = format!("partial_{k}");
        write_ply(
            &PointCloud::from_points(source.points.clone()),
            &out.join(format!("{stem}_source.ply")),
            PlyFormat::BinaryLittleEndian,
        )
        .unwrap();
        write_ply(&target, &out.join(format!("{stem}_target.ply")), PlyFormat::BinaryLittleEndian).unwrap();
        let m = truth.to_homogeneous();
        let rows: Vec<Vec<f64>> = (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect()).collect();
        let description = format!(
            "synthesised partial views: procedural {object}, {sensor}, turntable {a} -> {b} deg, Carmine noise, depth stage, 6 mm voxels ({} / {} points)",
            source.len(),
            target.len()
        );
        let json = format!("{{\"truth\": {rows:?}, \"description\": \"{description}\"}}\n");
        std::fs::write(out.join(format!("{stem}.json")), json).unwrap();
        println!("{stem}: {description}");
    }
}

use flowfilter_geometry::PointCloud;
