//! Batch estimation: a list of frame pairs read from CSV, and [`Shard`], the partition of such a
//! list (or of a benchmark's groups) over processes that a scheduler launches.
//!
//! The pair list (`pairs.csv`) has a header naming its columns, in any order:
//!
//! | column | required | what |
//! | --- | --- | --- |
//! | `model_color`, `model_depth`, `target_color`, `target_depth` | yes | the two frames' files (as `estimate --model-color ...`) |
//! | `camera` | yes | the camera file |
//! | `id` | no | the pair's name in the output (default: its row number, from 1) |
//! | `model_mask`, `target_mask` | no | masks (binary PNG, or label images with `label`) |
//! | `label` | no | the object's label in label-image masks |
//! | `gt` | no | the true motion (a JSON or text 4x4 file) |
//!
//! Relative paths are relative to the CSV file's folder; empty cells are absent values.

use crate::error::{PipelineError, input_error};
use crate::source::{FrameFiles, MaskSource};
use std::collections::BTreeMap;
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;

/// Shard `index` (1-based) of `count`: every `count`-th group of work, dealt round-robin.
///
/// ```
/// use flowfilter_pipeline::batch::Shard;
/// let shard: Shard = "2/3".parse()?;
/// assert_eq!(shard.select(&["a", "b", "c", "d", "e"]), ["b", "e"]);
/// # Ok::<(), String>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub struct Shard {
    /// 1..=count.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
}

impl FromStr for Shard {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let parsed = s.split_once('/').and_then(|(k, n)| Some((k.trim().parse().ok()?, n.trim().parse().ok()?)));
        match parsed {
            Some((index, count)) if count >= 1 && (1..=count).contains(&index) => Ok(Self { index, count }),
            _ => Err(format!("'{s}': expected K/N with 1 <= K <= N (e.g. 2/3)")),
        }
    }
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl Shard {
    /// The whole work: shard 1 of 1.
    pub const ALL: Self = Self { index: 1, count: 1 };

    /// Whether group `i` (0-based, in the work's order) belongs to this shard.
    pub fn owns(&self, i: usize) -> bool {
        i % self.count == self.index - 1
    }

    /// This shard's groups, in order.
    pub fn select<T: Clone>(&self, groups: &[T]) -> Vec<T> {
        groups.iter().enumerate().filter(|(i, _)| self.owns(*i)).map(|(_, g)| g.clone()).collect()
    }

    /// The directory a shard writes into (`shard-K-of-N`).
    pub fn dir_name(&self) -> String {
        format!("shard-{}-of-{}", self.index, self.count)
    }
}

/// One pair of a batch: two frames of one camera.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BatchPair {
    /// Its name in the output.
    pub id: String,
    /// The model frame's files.
    pub model: FrameFiles,
    /// The target frame's files.
    pub target: FrameFiles,
    /// The camera file.
    pub camera: PathBuf,
    /// The true motion's file, when known.
    pub gt: Option<PathBuf>,
}

impl BatchPair {
    /// The group of pairs that share this pair's model frame (a shard prepares it once).
    pub fn group_key(&self) -> &Path {
        &self.model.color
    }
}

/// The pairs of a CSV pair list (see the module documentation).
///
/// # Errors
/// [`PipelineError::Input`] naming the file, and the line and column at fault: a missing
/// required column, an empty required cell, a label that is not a number, a repeated id.
pub fn read_pairs(path: &Path) -> Result<Vec<BatchPair>, PipelineError> {
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_path(path)
        .map_err(|e| input_error(path, format!("cannot read the pair list: {e}")))?;
    let headers = reader.headers().map_err(|e| input_error(path, format!("no header line: {e}")))?.clone();
    let column = |name: &str| headers.iter().position(|h| h == name);
    for required in ["model_color", "model_depth", "target_color", "target_depth", "camera"] {
        if column(required).is_none() {
            return Err(input_error(
                path,
                format!("no '{required}' column (found: {})", headers.iter().collect::<Vec<_>>().join(", ")),
            ));
        }
    }
    let base = path.parent().unwrap_or(Path::new("."));
    let mut pairs = vec![];
    let mut ids: BTreeMap<String, usize> = BTreeMap::new();
    for (row, record) in reader.records().enumerate() {
        let line = row + 2;
        let record = record.map_err(|e| input_error(path, format!("line {line}: {e}")))?;
        let cell = |name: &str| column(name).and_then(|i| record.get(i)).filter(|v| !v.is_empty());
        let file = |name: &str| cell(name).map(|v| base.join(v));
        let required = |name: &str| file(name).ok_or_else(|| input_error(path, format!("line {line}: empty '{name}'")));
        let label = cell("label")
            .map(|v| {
                v.parse::<u16>()
                    .map_err(|_| input_error(path, format!("line {line}: label '{v}' is not a number 0-65535")))
            })
            .transpose()?;
        let mask = |name: &str| match (file(name), label) {
            (None, _) => MaskSource::None,
            (Some(path), None) => MaskSource::Binary(path),
            (Some(path), Some(id)) => MaskSource::Label { path, id },
        };
        let id = cell("id").map_or_else(|| (row + 1).to_string(), str::to_string);
        if let Some(first) = ids.insert(id.clone(), line) {
            return Err(input_error(path, format!("line {line}: id '{id}' is also on line {first}")));
        }
        pairs.push(BatchPair {
            id,
            model: FrameFiles {
                color: required("model_color")?,
                depth: required("model_depth")?,
                mask: mask("model_mask"),
            },
            target: FrameFiles {
                color: required("target_color")?,
                depth: required("target_depth")?,
                mask: mask("target_mask"),
            },
            camera: required("camera")?,
            gt: file("gt"),
        });
    }
    Ok(pairs)
}

/// The pairs of `shard`: groups of pairs that share a model frame, in order of first
/// appearance, dealt round-robin.
pub fn shard_pairs(pairs: &[BatchPair], shard: Shard) -> Vec<&BatchPair> {
    let mut groups: Vec<&Path> = vec![];
    for p in pairs {
        if !groups.contains(&p.group_key()) {
            groups.push(p.group_key());
        }
    }
    pairs.iter().filter(|p| shard.owns(groups.iter().position(|g| *g == p.group_key()).unwrap_or(0))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_parse_and_partition_the_groups() {
        assert_eq!("2/3".parse::<Shard>().unwrap(), Shard { index: 2, count: 3 });
        for bad in ["0/3", "4/3", "1/0", "3", "a/b", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
        let groups: Vec<usize> = (0..10).collect();
        let parts: Vec<Vec<usize>> = (1..=3).map(|k| Shard { index: k, count: 3 }.select(&groups)).collect();
        assert_eq!(parts[0], [0, 3, 6, 9]);
        let mut all: Vec<usize> = parts.concat();
        all.sort_unstable();
        assert_eq!(all, groups);
        assert_eq!(Shard::ALL.select(&groups), groups);
    }

    #[test]
    fn pair_lists_are_read_with_their_errors_named() {
        let dir = tempfile::tempdir().unwrap();
        let csv = dir.path().join("pairs.csv");
        std::fs::write(
            &csv,
            "id,model_color,model_depth,target_color,target_depth,camera,model_mask,target_mask,label,gt\n\
             a,c0.png,d0.png,c1.png,d1.png,cam.json,m0.png,m1.png,2,gt01.txt\n\
             b,c0.png,d0.png,c2.png,d2.png,cam.json,,,,\n\
             c,c1.png,d1.png,c2.png,d2.png,cam.json,,,,\n",
        )
        .unwrap();
        let pairs = read_pairs(&csv).unwrap();
        assert_eq!(pairs.len(), 3);
        assert_eq!(pairs[0].model.mask, MaskSource::Label { path: dir.path().join("m0.png"), id: 2 });
        assert_eq!(pairs[1].model.mask, MaskSource::None);
        assert_eq!(pairs[0].gt, Some(dir.path().join("gt01.txt")));
        // Pairs a and b share their model frame: one shard gets both.
        let ids = |s: &str| shard_pairs(&pairs, s.parse().unwrap()).iter().map(|p| p.id.clone()).collect::<Vec<_>>();
        assert_eq!(ids("1/2"), ["a", "b"]);
        assert_eq!(ids("2/2"), ["c"]);
        std::fs::write(&csv, "model_color,model_depth,target_color,camera\nx,y,z,w\n").unwrap();
        let e = read_pairs(&csv).unwrap_err().to_string();
        assert!(e.contains("pairs.csv") && e.contains("no 'target_depth' column"), "{e}");
        std::fs::write(&csv, "model_color,model_depth,target_color,target_depth,camera\nx,y,z,,w\n").unwrap();
        let e = read_pairs(&csv).unwrap_err().to_string();
        assert!(e.contains("line 2: empty 'target_depth'"), "{e}");
        std::fs::write(&csv, "id,model_color,model_depth,target_color,target_depth,camera\nq,x,y,z,v,w\nq,x,y,z,v,w\n")
            .unwrap();
        let e = read_pairs(&csv).unwrap_err().to_string();
        assert!(e.contains("line 3: id 'q' is also on line 2"), "{e}");
    }
}
