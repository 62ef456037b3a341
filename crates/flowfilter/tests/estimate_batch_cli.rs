//! `flowfilter estimate-batch`: every pair of a CSV list, one JSON line each; the same lines as
//! `estimate --json`; shards that together are the whole run; a crashed run resumed; bad rows.

use serde_json::Value;
use std::path::Path;
use std::process::Command;

fn flowfilter(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_flowfilter")).args(args).output().unwrap();
    (out.status.code().unwrap_or(-1), String::from_utf8_lossy(&out.stderr).into())
}

/// The output's lines by id, times removed.
fn lines(path: &Path) -> Vec<(String, Value)> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|l| {
            let mut v: Value = serde_json::from_str(l).unwrap();
            if let Some(e) = v.get_mut("estimate") {
                e.as_object_mut().unwrap().remove("stage_ms");
            }
            (v["id"].as_str().unwrap().to_string(), v)
        })
        .collect()
}

fn sorted(mut v: Vec<(String, Value)>) -> Vec<(String, Value)> {
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn batches_shards_and_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    let scene = dir.join("bop");
    let (code, err) = flowfilter(&[
        "synth",
        "--procedural",
        "box",
        "--format",
        "bop",
        "--cameras",
        "NP3",
        "--angles",
        "0,3,6,9",
        "--out",
        scene.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let f = |kind: &str, im: u32| format!("bop/000003/{kind}/{im:06}.png");
    let m = |im: u32| format!("bop/000003/mask_visib/{im:06}_000000.png");
    let mut csv = String::from("id,model_color,model_depth,model_mask,target_color,target_depth,target_mask,camera\n");
    for (id, a, b) in [("p01", 0, 1), ("p02", 0, 2), ("p12", 1, 2), ("p13", 1, 3), ("p23", 2, 3)] {
        csv += &format!(
            "{id},{},{},{},{},{},{},bop/000003/scene_camera.json\n",
            f("rgb", a),
            f("depth", a),
            m(a),
            f("rgb", b),
            f("depth", b),
            m(b)
        );
    }
    std::fs::write(dir.join("pairs.csv"), &csv).unwrap();
    let pairs = dir.join("pairs.csv");
    let pairs = pairs.to_str().unwrap();
    let whole = dir.join("whole.jsonl");
    let (code, err) = flowfilter(&["estimate-batch", "--pairs", pairs, "--out", whole.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    let all = lines(&whole);
    assert_eq!(all.iter().map(|(id, _)| id.as_str()).collect::<Vec<_>>(), ["p01", "p02", "p12", "p13", "p23"]);

    // A line is what `estimate --json` prints for the pair.
    let single = Command::new(env!("CARGO_BIN_EXE_flowfilter"))
        .current_dir(dir)
        .args(["estimate", "--model-color", &f("rgb", 1), "--model-depth", &f("depth", 1), "--model-mask", &m(1)])
        .args(["--target-color", &f("rgb", 3), "--target-depth", &f("depth", 3), "--target-mask", &m(3)])
        .args(["--camera", "bop/000003/scene_camera.json", "--json"])
        .output()
        .unwrap();
    let mut single: Value = serde_json::from_slice(&single.stdout).unwrap();
    single.as_object_mut().unwrap().remove("stage_ms");
    assert_eq!(all[3].1["estimate"], single);

    // Two shards (pairs grouped by model frame: 0, 1, 2 dealt to shards 1, 2, 1) are the whole.
    let mut merged = vec![];
    for k in 1..=2 {
        let out = dir.join(format!("shard{k}.jsonl"));
        let shard = format!("{k}/2");
        let (code, err) =
            flowfilter(&["estimate-batch", "--pairs", pairs, "--out", out.to_str().unwrap(), "--shard", &shard]);
        assert_eq!(code, 0, "{err}");
        merged.extend(lines(&out));
    }
    assert_eq!(sorted(merged), sorted(all.clone()));
    let shard1: Vec<String> = lines(&dir.join("shard1.jsonl")).into_iter().map(|(id, _)| id).collect();
    assert_eq!(shard1, ["p01", "p02", "p23"]);

    // A crash: two lines written, the third cut off halfway. The run resumes after the two.
    let text = std::fs::read_to_string(&whole).unwrap();
    let keep: usize = text.split_inclusive('\n').take(2).map(str::len).sum();
    let crashed = dir.join("crashed.jsonl");
    std::fs::write(&crashed, &text[..keep + 40]).unwrap();
    let (code, err) = flowfilter(&["estimate-batch", "--pairs", pairs, "--out", crashed.to_str().unwrap()]);
    assert_eq!(code, 0, "{err}");
    assert!(err.contains("2 already in") && err.contains("3 to run") && err.contains("unfinished last line"), "{err}");
    assert_eq!(lines(&crashed), all);
    // Run again: nothing left to do, nothing written.
    let (code, err) = flowfilter(&["estimate-batch", "--pairs", pairs, "--out", crashed.to_str().unwrap()]);
    assert!(code == 0 && err.contains("0 to run"), "{err}");
    assert_eq!(lines(&crashed), all);

    // A pair whose file is missing gets an error line and exit code 2; the others run.
    std::fs::write(dir.join("bad.csv"), csv.replace(&f("depth", 3), "bop/000003/depth/missing.png")).unwrap();
    let bad_out = dir.join("bad.jsonl");
    let (code, _) = flowfilter(&[
        "estimate-batch",
        "--pairs",
        dir.join("bad.csv").to_str().unwrap(),
        "--out",
        bad_out.to_str().unwrap(),
    ]);
    assert_eq!(code, 2);
    let bad = lines(&bad_out);
    assert!(bad[3].1["error"].as_str().unwrap().contains("missing.png"), "{:?}", bad[3]);
    assert!(bad.iter().filter(|(_, v)| v.get("estimate").is_some()).count() == 3);
    // A list without a required column is refused before any work.
    std::fs::write(dir.join("nocam.csv"), "model_color,model_depth,target_color,target_depth\na,b,c,d\n").unwrap();
    let (code, err) =
        flowfilter(&["estimate-batch", "--pairs", dir.join("nocam.csv").to_str().unwrap(), "--out", "x.jsonl"]);
    assert!(code == 1 && err.contains("no 'camera' column"), "{err}");
}
