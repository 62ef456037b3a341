//! What `ObjectWriter` writes reads back identically through the same reader.

mod common;

use flowfilter_bigbird::{BigBirdObject, H5Format, ObjectWriter, inspect};
use flowfilter_geometry::Pose;

#[test]
fn rewriting_the_h5py_fixture_reads_back_identically() {
    let src = BigBirdObject::open(common::fixture("latest")).unwrap();
    for format in [H5Format::V18, H5Format::V110] {
        let tmp = tempfile::tempdir().unwrap();
        let w = ObjectWriter::create(tmp.path().join("copy"), format).unwrap().with_jpeg_quality(100);
        w.write_calibration(&src.calibration).unwrap();
        w.write_turntable(&src.turntable).unwrap();
        for (angle, pose) in &src.table_poses {
            w.write_table_pose(*angle, pose).unwrap();
        }
        for id in src.frames() {
            let f = src.load_frame(id).unwrap();
            w.write_color(id, &f.color).unwrap();
            w.write_depth(id, &f.depth).unwrap();
            w.write_mask(id, &f.mask).unwrap();
        }
        assert!(inspect(w.dir()).is_ok(), "{format:?}: {:?}", inspect(w.dir()).problems);
        // The depth intrinsics under both names real BigBIRD files use (public loaders read
        // `NP{c}_depth_K`).
        let bytes = std::fs::read(w.dir().join("calibration.h5")).unwrap();
        let file = hdf5_reader::Hdf5File::from_vec(bytes).unwrap();
        let (_, names) = file.root_group().unwrap().member_names().unwrap();
        for id in src.calibration.sensors.keys() {
            for key in [format!("{id}_ir_K"), format!("{id}_depth_K")] {
                assert!(names.contains(&key), "{format:?}: no {key} in {names:?}");
            }
        }
        let back = BigBirdObject::open(w.dir()).unwrap();
        let close = |a: &Pose, b: &Pose| (a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-12;
        assert_eq!(back.calibration.sensors.len(), src.calibration.sensors.len());
        for (id, a) in &src.calibration.sensors {
            let b = &back.calibration.sensors[id];
            assert_eq!((a.rgb_k, a.rgb_d, a.depth_k), (b.rgb_k, b.rgb_d, b.depth_k), "{id}");
            assert_eq!((a.ir_depth_scale, a.ir_depth_bias), (b.ir_depth_scale, b.ir_depth_bias), "{id}");
            // Both spellings of the depth intrinsics are written back as `_ir_K`.
            assert_eq!(b.depth_k_key, format!("{id}_ir_K"));
            assert!(close(&a.h_from_np5, &b.h_from_np5) && close(&a.h_ir_from_np5, &b.h_ir_from_np5), "{id}");
        }
        assert_eq!(back.turntable, src.turntable);
        for (angle, a) in &src.table_poses {
            let b = &back.table_poses[angle];
            assert!(close(&a.h_table_from_reference, &b.h_table_from_reference), "angle {angle}");
            assert_eq!(a.board_frame_offset, b.board_frame_offset);
        }
        assert_eq!(back.frames().collect::<Vec<_>>(), src.frames().collect::<Vec<_>>());
        for id in src.frames() {
            let (a, b) = (src.load_frame(id).unwrap(), back.load_frame(id).unwrap());
            assert_eq!(a.depth, b.depth, "{format:?} {id}: depth");
            assert_eq!(a.mask, b.mask, "{format:?} {id}: mask");
            let max_diff = a.color.as_raw().iter().zip(b.color.as_raw()).map(|(x, y)| x.abs_diff(*y)).max().unwrap();
            assert!(max_diff <= 12, "{format:?} {id}: JPEG re-encoding at quality 100 differs by {max_diff}");
        }
        for sensor in src.sensors() {
            let (a, b) = (src.relative_motion(sensor, 0, 30).unwrap(), back.relative_motion(sensor, 0, 30).unwrap());
            assert!((a.to_homogeneous() - b.to_homogeneous()).abs().max() < 1e-12);
        }
    }
}
