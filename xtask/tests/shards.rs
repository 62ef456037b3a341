//! A benchmark run as one process and as three shards (separate processes) merged: the same
//! per-pair errors and the same summary tables, timings aside; and the merge's refusals.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

fn xtask(cwd: &Path, args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_xtask")).args(args).current_dir(cwd).output().expect("xtask runs")
}

fn ok(cwd: &Path, args: &[&str]) {
    let out = xtask(cwd, args);
    assert!(out.status.success(), "xtask {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
}

fn only_dir(root: &Path) -> PathBuf {
    let mut dirs: Vec<PathBuf> =
        std::fs::read_dir(root).unwrap().map(|e| e.unwrap().path()).filter(|p| p.is_dir()).collect();
    assert_eq!(dirs.len(), 1, "{dirs:?}");
    dirs.pop().unwrap()
}

/// results.json without what measures time.
fn untimed(path: &Path) -> (Vec<Value>, Vec<Value>) {
    let v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let strip = |items: &Value, keys: &[&str]| -> Vec<Value> {
        items
            .as_array()
            .unwrap()
            .iter()
            .map(|item| {
                let mut item = item.clone();
                for k in keys {
                    item.as_object_mut().unwrap().remove(*k);
                }
                item
            })
            .collect()
    };
    (strip(&v["pairs"], &["seconds", "stage_ms"]), strip(&v["summary"], &["mean_seconds", "mean_stage_ms"]))
}

/// summary.md's accuracy tables (what comes before the per-stage times), the run's duration
/// removed.
fn tables(path: &Path) -> String {
    let md = std::fs::read_to_string(path).unwrap();
    let head = md.split("| method | depth (per frame)").next().unwrap();
    head.lines().filter(|l| !l.contains(" failed, ")).collect::<Vec<_>>().join("\n")
}

#[test]
fn three_shards_merged_are_the_single_run() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path();
    // The quick protocol (CI's), without CPD (the slowest method in a debug build): CI runs
    // the quick protocol with every method sharded in the release build (`.ci/run`).
    let base = ["bench-bigbird", "--quick", "--methods", "icp-pt2pl,filterreg-pt2pt,flowfilter", "--check"];
    ok(cwd, &[&base[..], &["--out", "single"]].concat());
    // Three shards in three processes at once, as a scheduler would start them.
    let children: Vec<_> = (1..=3)
        .map(|k| {
            let shard = format!("{k}/3");
            Command::new(env!("CARGO_BIN_EXE_xtask"))
                .args(base)
                .args(["--out", "shards", "--shard", &shard])
                .current_dir(cwd)
                .output()
        })
        .collect();
    for c in children {
        let c = c.unwrap();
        assert!(c.status.success(), "{}", String::from_utf8_lossy(&c.stderr));
    }
    // One shard per procedural object, each with its own manifest.
    for k in 1..=3 {
        let m: Value = serde_json::from_str(
            &std::fs::read_to_string(cwd.join(format!("shards/shard-{k}-of-3/shard.json"))).unwrap(),
        )
        .unwrap();
        assert_eq!(m["groups"].as_array().unwrap().len(), 1, "{m}");
    }
    ok(
        cwd,
        &[
            "bench-merge",
            "shards",
            "--out",
            "merged",
            "--check",
            "--compare",
            only_dir(&cwd.join("single")).to_str().unwrap(),
        ],
    );
    let (single, merged) = (only_dir(&cwd.join("single")), only_dir(&cwd.join("merged")));
    let (pairs_1, summary_1) = untimed(&single.join("results.json"));
    let (pairs_3, summary_3) = untimed(&merged.join("results.json"));
    // 3 objects x 3 base angles x 3 steps, 3 methods and "no motion".
    assert_eq!(pairs_1.len(), 27 * 4);
    assert_eq!(pairs_1, pairs_3);
    assert_eq!(summary_1, summary_3);
    assert_eq!(tables(&single.join("summary.md")), tables(&merged.join("summary.md")));
    for f in ["pairs.csv", "error_vs_step.svg", "per_object.svg", "stage_times.svg"] {
        assert!(merged.join(f).is_file(), "{f}");
    }

    // A shard killed before it finished (no manifest) is refused, naming it.
    let partial = cwd.join("shards/shard-2-of-3/shard.json");
    let saved = std::fs::read_to_string(&partial).unwrap();
    std::fs::remove_file(&partial).unwrap();
    let out = xtask(cwd, &["bench-merge", "shards", "--out", "refused"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("shard-2-of-3") && err.contains("did not finish"), "{err}");
    // A missing shard is named.
    std::fs::write(&partial, &saved).unwrap();
    let out = xtask(cwd, &["bench-merge", "shards/shard-1-of-3", "shards/shard-3-of-3", "--out", "refused"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("missing shard(s) 2/3"), "{err}");
    // A shard given twice is named.
    let out = xtask(cwd, &["bench-merge", "shards", "shards/shard-1-of-3", "--out", "refused"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("shard 1/3 is given twice"), "{err}");
    // Shards of another protocol are refused.
    let mut other: Value = serde_json::from_str(&saved).unwrap();
    other["protocol"]["steps"] = serde_json::json!([3]);
    std::fs::write(&partial, serde_json::to_string(&other).unwrap()).unwrap();
    let out = xtask(cwd, &["bench-merge", "shards", "--out", "refused"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("protocol differs"), "{err}");
    // A damaged results.json (rows lost) is refused.
    std::fs::write(&partial, &saved).unwrap();
    let results = cwd.join("shards/shard-2-of-3/results.json");
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&results).unwrap()).unwrap();
    v["pairs"].as_array_mut().unwrap().pop();
    std::fs::write(&results, serde_json::to_string(&v).unwrap()).unwrap();
    let out = xtask(cwd, &["bench-merge", "shards", "--out", "refused"]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("damaged"), "{err}");
    assert!(!cwd.join("refused").exists() || std::fs::read_dir(cwd.join("refused")).unwrap().next().is_none());
    // The shard re-run alone replaces its output, and the merge is the single run again.
    ok(cwd, &[&base[..], &["--out", "shards", "--shard", "2/3"]].concat());
    ok(cwd, &["bench-merge", "shards", "--out", "merged-again"]);
    let (pairs_again, _) = untimed(&only_dir(&cwd.join("merged-again")).join("results.json"));
    assert_eq!(pairs_1, pairs_again);
}

/// The repository root.
fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// `deploy/run-shard.sh` (what the Slurm and Kubernetes launchers run) takes the shard from each
/// scheduler's variables; the manifests agree with it.
#[test]
fn launchers_map_scheduler_indexes_to_shards() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("out");
    let run = |script: &str, env: &[(&str, &str)]| {
        let mut c = Command::new("bash");
        c.arg(root().join(script)).arg(&out).args(["bench-bigbird", "--quick", "--methods", "icp-pt2pl"]);
        c.env("FLOWFILTER_XTASK", env!("CARGO_BIN_EXE_xtask"));
        for v in ["FLOWFILTER_SHARD", "SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT", "JOB_COMPLETION_INDEX", "SHARDS"]
        {
            c.env_remove(v);
        }
        c.envs(env.iter().copied());
        c.output().unwrap()
    };
    let shard_of = |dir: &str| -> Value {
        serde_json::from_str::<Value>(&std::fs::read_to_string(out.join(dir).join("shard.json")).unwrap()).unwrap()["shard"].clone()
    };
    // A Slurm array task (ids from 1), through the batch script itself.
    let o = run(
        "deploy/slurm/bench.sbatch",
        &[("SLURM_ARRAY_TASK_ID", "2"), ("SHARDS", "3"), ("SLURM_SUBMIT_DIR", root().to_str().unwrap())],
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(shard_of("shard-2-of-3"), serde_json::json!({ "index": 2, "count": 3 }));
    // A Kubernetes Indexed Job pod (indexes from 0).
    let o = run("deploy/run-shard.sh", &[("JOB_COMPLETION_INDEX", "2"), ("SHARDS", "3")]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(shard_of("shard-3-of-3"), serde_json::json!({ "index": 3, "count": 3 }));
    // The Ray driver's (and a user's) explicit shard.
    let o = run("deploy/run-shard.sh", &[("FLOWFILTER_SHARD", "1/3")]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The three merge.
    ok(tmp.path(), &["bench-merge", out.to_str().unwrap(), "--out", "merged"]);
    // No shard given: refused with the ways to give one.
    let o = run("deploy/run-shard.sh", &[]);
    assert_eq!(o.status.code(), Some(64));
    assert!(String::from_utf8_lossy(&o.stderr).contains("FLOWFILTER_SHARD=K/N"));
    // The Indexed Job runs the script with as many shards as completions.
    let job = std::fs::read_to_string(root().join("deploy/k8s/bench-indexed-job.yaml")).unwrap();
    let value = |key: &str| {
        job.lines().find_map(|l| l.trim().strip_prefix(key).map(|v| v.trim().trim_matches('"').to_string()))
    };
    assert_eq!(value("completionMode:").as_deref(), Some("Indexed"));
    let completions = value("completions:").unwrap();
    assert_eq!(value("parallelism:"), Some(completions.clone()));
    let shards_line = job.lines().position(|l| l.contains("name: SHARDS")).unwrap();
    assert!(job.lines().nth(shards_line + 1).unwrap().contains(&format!("\"{completions}\"")));
    assert!(job.contains("deploy/run-shard.sh"));
}

/// bench-bop sharded by scene: two shards merged are the single run.
#[test]
fn bop_scenes_shard_and_merge() {
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path();
    let base = ["bench-bop", "--quick", "--methods", "icp-pt2pl", "--gaps", "1", "--check"];
    ok(cwd, &[&base[..], &["--out", "single"]].concat());
    for k in ["1/2", "2/2"] {
        ok(cwd, &[&base[..], &["--out", "shards", "--shard", k]].concat());
    }
    let single = only_dir(&cwd.join("single"));
    ok(cwd, &["bench-merge", "shards", "--out", "merged", "--compare", single.to_str().unwrap()]);
    // Scenes 1, 2, 3, 101, 102, 103 dealt round-robin.
    let m: Value =
        serde_json::from_str(&std::fs::read_to_string(cwd.join("shards/shard-2-of-2/shard.json")).unwrap()).unwrap();
    assert_eq!(m["groups"], serde_json::json!(["000002", "000101", "000103"]));
    assert_eq!(untimed(&single.join("results.json")), untimed(&only_dir(&cwd.join("merged")).join("results.json")));
}

/// `bench-real` shards by sequence: two shards of two real sequences merged are the single run
/// (skipped when the shared data is absent).
#[test]
fn real_sequences_shard_and_merge() {
    let data = root().join("../shared/data/realsense-shelf");
    if !data.is_dir() {
        eprintln!("skipping: {} is absent (the shared data sits beside the repository)", data.display());
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    let cwd = tmp.path();
    let data = data.to_str().unwrap();
    let base =
        ["bench-real", "--quick", "--data", data, "--sequences", "shelf-A,tote", "--methods", "flowfilter", "--check"];
    ok(cwd, &[&base[..], &["--out", "single"]].concat());
    for k in ["1/2", "2/2"] {
        ok(cwd, &[&base[..], &["--out", "shards", "--shard", k]].concat());
    }
    ok(cwd, &["bench-merge", "shards", "--out", "merged"]);
    let (pairs_1, summary_1) = untimed(&only_dir(&cwd.join("single")).join("results.json"));
    let (pairs_2, summary_2) = untimed(&only_dir(&cwd.join("merged")).join("results.json"));
    assert!(pairs_1.iter().any(|p| p["object"] == "region") && pairs_1.iter().any(|p| p["camera"] == "tote"));
    assert_eq!(pairs_1, pairs_2);
    assert_eq!(summary_1, summary_2);
}
