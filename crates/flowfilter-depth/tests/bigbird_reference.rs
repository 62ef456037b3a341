//! Our splat registration with the BigBIRD discontinuity filter agrees with the numpy reference
//! of the public BigBIRD tools (`tools/peers/bigbird_register.py`) on the h5py fixture.

use flowfilter_bigbird::{BigBirdObject, read_depth};
use flowfilter_camera::RayTable;
use flowfilter_depth::filter::{bigbird_discontinuity, metric_depth};
use flowfilter_depth::register::{project_depth_grid, splat};
use std::path::Path;

#[test]
fn splat_registration_matches_the_bigbird_tools() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures");
    let obj = BigBirdObject::open(root.join("bigbird/latest/tiny_spheres")).unwrap();
    let mut frames = 0;
    for id in obj.frames() {
        let f = obj.load_frame(id).unwrap();
        let sensor = obj.rgbd_sensor(&f).unwrap();
        let reference = read_depth(&root.join(format!("peers/bigbird_registered/{id}.h5"))).unwrap();
        // BigBIRD's threshold is 1000 raw units.
        let d = metric_depth(&f.depth, sensor.metres_per_unit);
        let (d, _) = bigbird_discontinuity(&d, 7, 1000.0 * sensor.metres_per_unit);
        let projected = project_depth_grid(&d, (0, 0), &sensor, &RayTable::new(&sensor.depth));
        let (w, h) = (f.color.width() as usize, f.color.height() as usize);
        let ours = splat(&projected, w, h, None);
        let (mut both, mut only_ours, mut only_ref, mut max_err) = (0usize, 0usize, 0usize, 0.0f64);
        for (z, r) in ours.as_slice().iter().zip(reference.as_slice()) {
            match (*z > 0.0, *r > 0) {
                (true, true) => {
                    both += 1;
                    max_err = max_err.max((f64::from(*z) - f64::from(*r) * 1e-4).abs());
                }
                (true, false) => only_ours += 1,
                (false, true) => only_ref += 1,
                _ => {}
            }
        }
        println!(
            "{id}: {both} pixels in both, {only_ours} only ours, {only_ref} only reference, max |dz| {:.3} mm",
            max_err * 1e3
        );
        assert!(both > 100, "{id}");
        assert!(max_err < 1e-3, "{id}: {max_err}");
        assert!((only_ours + only_ref) as f64 <= 0.01 * both as f64, "{id}: coverage differs");
        frames += 1;
    }
    assert_eq!(frames, 6);
}
