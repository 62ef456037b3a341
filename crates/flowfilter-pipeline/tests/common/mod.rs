//! Synthesised turntable frames shared by the pipeline's tests.

use flowfilter_bigbird::SensorId;
use flowfilter_geometry::Pose;
use flowfilter_pipeline::RgbdFrame;
use flowfilter_synth::{NoiseProfile, Rig, Scene, procedural, render_frame, world_from_table};

/// Camera `camera` of `rig` at turntable `angle`, with the Carmine noise profile.
pub fn frame(scene: &Scene, rig: &Rig, camera: u8, angle: u32) -> RgbdFrame {
    let sensor = SensorId::new(camera).unwrap();
    let f = render_frame(scene, rig, sensor, angle, Some(&NoiseProfile::carmine()), 7);
    RgbdFrame {
        label: format!("{sensor}_{angle}"),
        color: f.color,
        depth: f.raw_depth,
        mask: f.mask,
        sensor: rig.sensors[&sensor].rgbd,
    }
}

/// The true motion from angle `a` to angle `b` in camera `camera`'s colour frame.
pub fn truth(rig: &Rig, camera: u8, a: u32, b: u32) -> Pose {
    let s = &rig.sensors[&SensorId::new(camera).unwrap()];
    let h = |angle: u32| s.h_color_from_world * world_from_table(f64::from(angle));
    h(b) * h(a).inverse()
}

/// The procedural box on the turntable.
pub fn box_scene() -> Scene {
    Scene::new(procedural("box", 1).unwrap().placed_on_table(0.01, -0.005), 1)
}
