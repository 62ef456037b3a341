//! Render a procedural object on the turntable from two angles with sensor noise and write the
//! colour images and masks. Run: `cargo run --release -p flowfilter-synth --example render_views -- OUT_DIR`.

use flowfilter_bigbird::SensorId;
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame};
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = PathBuf::from(std::env::args().nth(1).ok_or("usage: render_views OUT_DIR")?);
    std::fs::create_dir_all(&out)?;
    let rig = Rig::bigbird_like();
    let scene = Scene::new(procedural("bottle", 4)?.placed_on_table(0.0, 0.0), 4);
    let sensor = SensorId::new(2).expect("NP1..NP5");
    for angle in [0, 15] {
        let f = render_frame(&scene, &rig, sensor, angle, Some(&NoiseProfile::carmine()), 7);
        let path = out.join(format!("{sensor}_{angle}.png"));
        f.color.save(&path)?;
        let seen = f.mask.as_slice().iter().filter(|m| **m).count();
        println!("{}: {seen} object pixels", path.display());
    }
    Ok(())
}
