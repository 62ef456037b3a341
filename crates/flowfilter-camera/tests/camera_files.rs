//! Camera files written by other tools: the real YCB-Video frames' `-gt.json` of
//! `../shared/data/ycb-video` (skipped with a message when the shared data is absent).

use flowfilter_camera::{CameraFile, CameraFileLayout};
use std::path::Path;

#[test]
fn the_ycb_video_sample_reads_as_a_registered_camera() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/ycb-video/0001/000001-gt.json");
    if !path.is_file() {
        eprintln!("skipping: {} is absent (the shared data sits beside the repository)", path.display());
        return;
    }
    let camera = CameraFile::from_file(&path).unwrap();
    assert_eq!(camera.layout, CameraFileLayout::Flowfilter);
    assert!((camera.intrinsics.fx - 1066.778).abs() < 1e-9 && (camera.intrinsics.cy - 241.3109).abs() < 1e-9);
    assert_eq!(camera.metres_per_unit, Some(1e-4));
    // The file gives no size: the 640x480 images do.
    let sensor = camera.registered_sensor(Some((640, 480))).unwrap();
    assert_eq!(sensor.color.size.width, 640);
    assert!(camera.registered_sensor(None).is_err());
}
