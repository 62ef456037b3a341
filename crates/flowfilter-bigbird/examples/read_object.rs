//! Open a BigBIRD-layout object directory, list its frames and print the ground-truth motion
//! between two of them. Run:
//! `cargo run -p flowfilter-bigbird --example read_object -- fixtures/bigbird/latest/tiny_spheres`.

use flowfilter_bigbird::{BigBirdObject, FrameId};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args().nth(1).ok_or("usage: read_object OBJECT_DIR")?;
    let object = BigBirdObject::open(&dir)?;
    let frames: Vec<FrameId> = object.frames().collect();
    println!("{dir}: {} frames", frames.len());
    let (Some(first), Some(last)) = (frames.first(), frames.iter().rev().find(|f| f.sensor == frames[0].sensor)) else {
        return Err("no frames".into());
    };
    let frame = object.load_frame(*first)?;
    println!(
        "{first}: colour {}x{}, depth {}x{}",
        frame.color.width(),
        frame.color.height(),
        frame.depth.width(),
        frame.depth.height()
    );
    let motion = object.relative_motion(first.sensor, first.angle, last.angle)?;
    println!("{first} -> {last}: the object turned {:.2} deg", motion.rotation.angle().to_degrees());
    Ok(())
}
