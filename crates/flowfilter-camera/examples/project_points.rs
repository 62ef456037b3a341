//! Project 3-D points through a distorted pinhole camera and back-project the pixels.
//! Run: `cargo run -p flowfilter-camera --example project_points`.

use flowfilter_camera::{CameraModel, Distortion, ImageSize, Intrinsics};
use flowfilter_geometry::Point3;

fn main() -> Result<(), flowfilter_camera::CameraError> {
    // A Kinect-like colour camera with mild barrel distortion (OpenCV's k1, k2, p1, p2, k3).
    let camera = CameraModel::new(
        Intrinsics::new(525.0, 525.0, 319.5, 239.5)?,
        Distortion::from_slice(&[0.18, -0.4, 0.0005, -0.001, 0.2])?,
        ImageSize::new(640, 480)?,
    );
    for p in [Point3::new(0.0, 0.0, 1.0), Point3::new(0.25, -0.15, 0.9), Point3::new(-0.4, 0.3, 1.2)] {
        match camera.project(&p) {
            Some(px) => {
                let back = camera.backproject(&px, p.z).expect("the pixel undistorts");
                println!("{p:?} -> pixel ({:.2}, {:.2}) -> back {:.2e} m off", px.x, px.y, (back - p).norm());
            }
            None => println!("{p:?} is outside the image"),
        }
    }
    Ok(())
}
