//! Damaged or inconsistent object directories give typed errors that name the file and the
//! problem; `inspect` lists every problem at once. Nothing panics.

mod common;

use flowfilter_bigbird::{BigBirdError, BigBirdObject, FrameId, SensorId, inspect};
use hdf5_pure::FileBuilder;
use std::path::Path;

fn frame(c: u8, angle: u32) -> FrameId {
    FrameId { sensor: SensorId::new(c).unwrap(), angle }
}

fn truncate(path: &Path, keep: usize) {
    let bytes = std::fs::read(path).unwrap();
    std::fs::write(path, &bytes[..keep.min(bytes.len())]).unwrap();
}

fn write_pose_file(path: &Path, matrix: [f64; 16]) {
    let mut b = FileBuilder::new();
    b.create_dataset("H_table_from_reference_camera").with_f64_data(&matrix).with_shape(&[4, 4]);
    b.create_dataset("board_frame_offset").with_f64_data(&[0.0; 3]).with_shape(&[3]);
    b.write(path).unwrap();
}

const IDENTITY: [f64; 16] = [1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.];

#[test]
fn missing_directory_and_missing_file_name_the_path() {
    let err = BigBirdObject::open("/nonexistent/object").unwrap_err();
    assert!(matches!(err, BigBirdError::NotFound { .. }));
    assert!(err.to_string().contains("/nonexistent/object"), "{err}");

    let (_tmp, dir) = common::scratch_copy("earliest");
    std::fs::remove_file(dir.join("calibration.h5")).unwrap();
    let err = BigBirdObject::open(&dir).unwrap_err();
    assert!(err.to_string().contains("calibration.h5") && err.to_string().contains("not found"), "{err}");

    let (_tmp, dir) = common::scratch_copy("earliest");
    std::fs::remove_file(dir.join("masks/NP1_3_mask.pbm")).unwrap();
    let obj = BigBirdObject::open(&dir).unwrap();
    let err = obj.load_frame(frame(1, 3)).unwrap_err();
    assert!(err.to_string().contains("NP1_3_mask.pbm"), "{err}");
    assert!(matches!(obj.load_frame(frame(3, 0)), Err(BigBirdError::NotPresent { .. })));
}

#[test]
fn missing_dataset_names_the_key() {
    let (_tmp, dir) = common::scratch_copy("latest");
    let mut b = FileBuilder::new();
    b.create_dataset("center").with_f64_data(&[0.0; 3]).with_shape(&[3]);
    b.write(dir.join("poses/turntable.h5")).unwrap();
    let err = BigBirdObject::open(&dir).unwrap_err();
    assert!(matches!(&err, BigBirdError::MissingDataset { key, .. } if key == "normal"), "{err}");
    assert!(err.to_string().contains("turntable.h5"), "{err}");
}

#[test]
fn wrong_shape_and_dtype_say_expected_and_found() {
    let (_tmp, dir) = common::scratch_copy("latest");
    let mut b = FileBuilder::new();
    b.create_dataset("depth").with_u16_data(&[1, 2, 3, 4]).with_shape(&[4]);
    b.write(dir.join("NP1_0.h5")).unwrap();
    let mut b = FileBuilder::new();
    b.create_dataset("depth").with_f32_data(&[1.0; 6]).with_shape(&[2, 3]);
    b.write(dir.join("NP1_3.h5")).unwrap();
    let obj = BigBirdObject::open(&dir).unwrap();
    let err = obj.load_frame(frame(1, 0)).unwrap_err();
    assert!(matches!(&err, BigBirdError::Shape { found, .. } if found == &[4]), "{err}");
    assert!(err.to_string().contains("expected 2-D"), "{err}");
    let err = obj.load_frame(frame(1, 3)).unwrap_err();
    assert!(
        matches!(&err, BigBirdError::Dtype { expected, found, .. } if expected == "uint16" && found == "float32"),
        "{err}"
    );
    assert!(err.to_string().contains("NP1_3.h5"), "{err}");

    write_pose_file(&dir.join("poses/NP5_30_pose.h5"), IDENTITY);
    let mut b = FileBuilder::new();
    b.create_dataset("H_table_from_reference_camera").with_f64_data(&[0.0; 9]).with_shape(&[3, 3]);
    b.create_dataset("board_frame_offset").with_f64_data(&[0.0; 3]).with_shape(&[3]);
    b.write(dir.join("poses/NP5_3_pose.h5")).unwrap();
    let err = BigBirdObject::open(&dir).unwrap_err();
    assert!(err.to_string().contains("shape [3, 3], expected [4, 4]"), "{err}");
}

#[test]
fn truncated_or_corrupt_files_are_errors_naming_the_file() {
    let (_tmp, dir) = common::scratch_copy("earliest");
    truncate(&dir.join("NP5_0.h5"), 300);
    truncate(&dir.join("NP5_3.jpg"), 200);
    std::fs::write(dir.join("masks/NP5_30_mask.pbm"), b"P4\n160 128\n\x00\x01").unwrap();
    std::fs::write(dir.join("NP1_0.h5"), b"this is not an HDF5 file at all").unwrap();
    let obj = BigBirdObject::open(&dir).unwrap();
    for (id, file) in [
        (frame(5, 0), "NP5_0.h5"),
        (frame(5, 3), "NP5_3.jpg"),
        (frame(5, 30), "NP5_30_mask.pbm"),
        (frame(1, 0), "NP1_0.h5"),
    ] {
        let err = obj.load_frame(id).unwrap_err();
        assert!(err.to_string().contains(file), "{id}: {err}");
    }
    assert!(matches!(obj.load_frame(frame(5, 30)), Err(BigBirdError::Pbm { .. })));
    assert!(matches!(obj.load_frame(frame(5, 3)), Err(BigBirdError::Image { .. })));
    // Every truncation length of the calibration file is an error, never a panic.
    let cal = dir.join("calibration.h5");
    let full = std::fs::read(&cal).unwrap();
    for keep in (0..full.len()).step_by(997) {
        std::fs::write(&cal, &full[..keep]).unwrap();
        assert!(BigBirdObject::open(&dir).is_err(), "truncated to {keep} bytes");
    }
}

#[test]
fn non_rigid_and_nan_matrices_are_rejected() {
    let (_tmp, dir) = common::scratch_copy("latest");
    let mut scaled = IDENTITY;
    scaled[0] = 2.0;
    write_pose_file(&dir.join("poses/NP5_0_pose.h5"), scaled);
    let err = BigBirdObject::open(&dir).unwrap_err();
    assert!(matches!(&err, BigBirdError::NotRigid { key, .. } if key == "H_table_from_reference_camera"), "{err}");
    assert!(err.to_string().contains("orthonormal"), "{err}");

    let mut reflected = IDENTITY;
    reflected[10] = -1.0;
    write_pose_file(&dir.join("poses/NP5_0_pose.h5"), reflected);
    assert!(BigBirdObject::open(&dir).unwrap_err().to_string().contains("determinant"));

    let mut nan = IDENTITY;
    nan[3] = f64::NAN;
    write_pose_file(&dir.join("poses/NP5_0_pose.h5"), nan);
    let err = BigBirdObject::open(&dir).unwrap_err();
    assert!(matches!(&err, BigBirdError::NonFinite { index: 3, .. }), "{err}");
}

#[test]
fn mask_of_another_size_is_rejected() {
    let (_tmp, dir) = common::scratch_copy("latest");
    let small = flowfilter_geometry::Mask::filled(80, 64, false);
    std::fs::write(dir.join("masks/NP1_30_mask.pbm"), flowfilter_bigbird::pbm::encode(&small)).unwrap();
    let err = BigBirdObject::open(&dir).unwrap().load_frame(frame(1, 30)).unwrap_err();
    assert!(matches!(&err, BigBirdError::MaskSize { .. }), "{err}");
    assert!(err.to_string().contains("mask is 80x64, but the colour image is 160x128"), "{err}");
}

#[test]
fn inspect_lists_every_problem() {
    let (_tmp, dir) = common::scratch_copy("earliest");
    truncate(&dir.join("NP5_0.h5"), 100);
    truncate(&dir.join("NP1_30.jpg"), 100);
    std::fs::remove_file(dir.join("poses/NP5_3_pose.h5")).unwrap();
    std::fs::remove_file(dir.join("poses/turntable.h5")).unwrap();
    let report = inspect(&dir);
    let text: Vec<String> = report.problems.iter().map(ToString::to_string).collect();
    assert_eq!(report.problems.len(), 4, "{text:#?}");
    for file in ["NP5_0.h5", "NP1_30.jpg", "NP5_3_pose.h5", "turntable.h5"] {
        assert!(text.iter().any(|t| t.contains(file)), "{file} not reported: {text:#?}");
    }
    assert_eq!(report.summary.valid_frames, 4);
    let empty = tempfile::tempdir().unwrap();
    let report = inspect(empty.path());
    assert!(report.problems.iter().any(|e| matches!(e, BigBirdError::NoFrames { .. })));
}
