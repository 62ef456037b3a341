//! Rendering cost of one frame (colour 1280x1024 + depth 640x480), noise-free and noisy.
//! Run: `cargo bench -p flowfilter-synth --bench render`.

use flowfilter_bigbird::SensorId;
use flowfilter_synth::{NoiseProfile, Rig, Scene, TexturedMesh, procedural, render_frame};
use std::path::Path;

fn main() {
    divan::main();
}

fn scene(name: &str) -> Option<Scene> {
    let mesh = match name {
        "ycb_cracker_box_16k" => {
            let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ycb/003_cracker_box/textured.obj");
            if !p.exists() {
                eprintln!("skipping {name}: ../shared/data/ycb is absent");
                return None;
            }
            TexturedMesh::load_obj(p).unwrap().placed_on_table(0.0, 0.0)
        }
        other => procedural(other, 1).unwrap(),
    };
    Some(Scene::new(mesh, 1))
}

#[divan::bench(args = ["box", "can", "ycb_cracker_box_16k"], sample_count = 10)]
fn frame_noise_free(bencher: divan::Bencher, name: &str) {
    let Some(scene) = scene(name) else { return };
    let rig = Rig::bigbird_like();
    let sensor = SensorId::new(3).unwrap();
    bencher.bench(|| render_frame(&scene, &rig, sensor, 30, None, 1));
}

#[divan::bench(args = ["box", "ycb_cracker_box_16k"], sample_count = 10)]
fn frame_carmine_noise(bencher: divan::Bencher, name: &str) {
    let Some(scene) = scene(name) else { return };
    let rig = Rig::bigbird_like();
    let noise = NoiseProfile::carmine();
    let sensor = SensorId::new(3).unwrap();
    bencher.bench(|| render_frame(&scene, &rig, sensor, 30, Some(&noise), 1));
}
