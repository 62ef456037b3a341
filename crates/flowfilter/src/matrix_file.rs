//! Rigid transforms read from files (`register --init`, `estimate --gt`): a text of 16 numbers
//! (row-major, separated by spaces, commas or newlines), or a JSON 4x4 array of rows, bare or
//! under `transform`.

use anyhow::{Context, bail};
use flowfilter_geometry::{Pose, rigid_from_matrix};
use nalgebra::Matrix4;
use std::path::Path;

/// The rigid transform in `path`.
pub fn read_pose(path: &Path) -> anyhow::Result<Pose> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let values = match serde_json::from_str::<serde_json::Value>(&text) {
        Ok(v) => json_rows(v.get("transform").unwrap_or(&v))
            .with_context(|| format!("{}: field 'transform': expected 4 rows of 4 numbers", path.display()))?,
        Err(_) => text
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(|s| s.parse::<f64>().with_context(|| format!("{}: '{s}' is not a number", path.display())))
            .collect::<Result<_, _>>()?,
    };
    if values.len() != 16 {
        bail!("{}: expected 16 numbers (a 4x4 matrix, row-major), found {}", path.display(), values.len());
    }
    rigid_from_matrix(&Matrix4::from_row_slice(&values))
        .with_context(|| format!("{}: not a rigid transform", path.display()))
}

/// The 16 numbers of a JSON array of 4 rows of 4 (row-major); `None` for anything else.
fn json_rows(v: &serde_json::Value) -> Option<Vec<f64>> {
    let rows = v.as_array().filter(|r| r.len() == 4)?;
    rows.iter()
        .map(|row| row.as_array().filter(|c| c.len() == 4))
        .collect::<Option<Vec<_>>>()?
        .into_iter()
        .flatten()
        .map(serde_json::Value::as_f64)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_accepted_form_gives_the_same_pose_and_bad_files_are_named() {
        let tmp = tempfile::tempdir().unwrap();
        let write = |name: &str, text: &str| {
            let p = tmp.path().join(name);
            std::fs::write(&p, text).unwrap();
            p
        };
        let rows = "[[0, -1, 0, 0.1], [1, 0, 0, 0.2], [0, 0, 1, 0.3], [0, 0, 0, 1]]";
        let forms = [
            write("bare.json", rows),
            write("wrapped.json", &format!("{{\"transform\": {rows}}}")),
            write("matrix.txt", "0 -1 0 0.1\n1 0 0 0.2\n0 0 1 0.3\n0 0 0 1\n"),
            write("commas.txt", "0,-1,0,0.1,1,0,0,0.2,0,0,1,0.3,0,0,0,1"),
        ];
        let poses: Vec<Pose> = forms.iter().map(|p| read_pose(p).unwrap()).collect();
        assert!(poses.iter().all(|p| *p == poses[0]));
        assert!((poses[0].rotation.angle().to_degrees() - 90.0).abs() < 1e-9);
        for (name, text, needle) in [
            ("short.txt", "1 0 0 0 0 1 0 0 0 0 1 0", "expected 16 numbers"),
            ("word.txt", "1 0 x", "'x' is not a number"),
            ("rows.json", "{\"transform\": [[1, 0, 0]]}", "4 rows of 4"),
            ("scaled.txt", "2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1", "not a rigid transform"),
        ] {
            let e = format!("{:#}", read_pose(&write(name, text)).unwrap_err());
            assert!(e.contains(name) && e.contains(needle), "{name}: {e}");
        }
    }
}
