//! The commented configurations in `configs/` parse, document the real defaults, and bad
//! files are errors naming the key and the file.

use flowfilter_pipeline::{PipelineConfig, PipelineError};
use std::path::{Path, PathBuf};

fn configs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../configs")
}

#[test]
fn every_shipped_config_parses_and_builds_a_pipeline() {
    let mut methods = std::collections::BTreeMap::new();
    for entry in std::fs::read_dir(configs_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "toml") {
            let c = PipelineConfig::from_file(&path).unwrap_or_else(|e| panic!("{e}"));
            flowfilter_pipeline::Pipeline::from_config(c.clone()).unwrap();
            methods.insert(path.file_stem().unwrap().to_string_lossy().into_owned(), c.method);
        }
    }
    let want = [
        ("cpd", "cpd"),
        ("cpd-full-cloud", "cpd"),
        ("filterreg", "filterreg-pt2pt"),
        ("flowfilter", "flowfilter"),
        ("flowfilter-fast", "flowfilter"),
        ("icp", "icp-pt2pl"),
    ]
    .map(|(f, m)| (f.to_string(), m.to_string()));
    assert_eq!(methods, std::collections::BTreeMap::from(want));
}

#[test]
fn flowfilter_toml_documents_the_defaults() {
    let c = PipelineConfig::from_file(&configs_dir().join("flowfilter.toml")).unwrap();
    assert_eq!(c, PipelineConfig::default());
}

/// A section that sets some of FilterReg's keys leaves the others at FilterReg's defaults: the
/// limit of E-step switches stays unset, for Flow Filter to take its own (12) and FilterReg alone
/// its own (9), not one of them the other's.
#[test]
fn a_partial_filterreg_section_leaves_each_runner_its_switch_limit() {
    let text = "[registration.flowfilter.filterreg]\nw = 0.1\n[registration.filterreg]\nw = 0.2\n";
    let c = PipelineConfig::from_toml_str(text, Path::new("partial.toml")).unwrap();
    assert_eq!(c.registration.flowfilter.filterreg.max_e_step_switches, None);
    assert_eq!(c.registration.filterreg.max_e_step_switches, None);
    let set = "[registration.flowfilter.filterreg]\nmax_e_step_switches = 0\n";
    let c = PipelineConfig::from_toml_str(set, Path::new("set.toml")).unwrap();
    assert_eq!(c.registration.flowfilter.filterreg.max_e_step_switches, Some(0));
}

#[test]
fn unknown_keys_are_named_with_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.toml");
    std::fs::write(&path, "method = \"cpd\"\n\n[registration.cpd]\nmax_iteratons = 3\n").unwrap();
    let e = PipelineConfig::from_file(&path).unwrap_err();
    let msg = e.to_string();
    assert!(matches!(e, PipelineError::Config { .. }));
    assert!(msg.contains("bad.toml") && msg.contains("max_iteratons") && msg.contains("line 4"), "{msg}");
}

#[test]
fn bad_values_are_named() {
    let origin = Path::new("x.toml");
    for (text, needle) in [
        ("method = \"ransac\"", "method"),
        ("[flow]\nestimator = \"farneback\"", "farneback"),
        ("[cloud]\nvoxel_m = -1.0", "cloud.voxel_m"),
        ("[depth.gaussian_filter]\nwindow = 4", "gaussian_filter.window"),
        ("[flow.lk]\nwindow = 20", "lk.window"),
        ("[flow.dis]\npatch_stride = 0", "patch_stride"),
        ("method = 3", "method"),
        ("[judge]\nratio = 2.0", "judge.ratio"),
        ("[judge]\nambiguity_tolerance = -1.0", "judge.ambiguity_tolerance"),
        ("[judge.sweep]\nsweep_deg = [-6.0]", "judge.sweep"),
        ("[judge]\ncandidate_pixels = 0", "judge.candidate_pixels"),
        ("[judge.gate]\nfraction = 1.5", "judge.gate.fraction"),
        ("[judge.gate]\nmin_pairs = 0", "judge.gate.min_pairs"),
        ("[flow]\nunguided_below_deg = -1.0", "flow.unguided_below_deg"),
        ("[align]\ntruncation = 0.0", "align.truncation"),
        ("[align]\nmax_pixels = 10", "align.max_pixels"),
        ("[align]\nrow_shear_sd = -0.001", "align.row_shear_sd"),
        ("[align]\ndepth_step_at_1m_m = -1.0", "align.depth_step_at_1m_m"),
        ("[flow.wide]\nmin_motion_px = -1.0", "flow.wide"),
        ("[flow.wide.search]\nlevel = 0", "flow.wide"),
        ("[flow.wide.search]\nmin_overlap = 1.5", "flow.wide"),
        ("[report]\nmax_bound_deg = -1.0", "report.max_bound_deg"),
    ] {
        let msg = PipelineConfig::from_toml_str(text, origin).unwrap_err().to_string();
        assert!(msg.contains("x.toml") && msg.contains(needle), "{text}: {msg}");
    }
    let missing = PipelineConfig::from_file(Path::new("/nonexistent/c.toml")).unwrap_err().to_string();
    assert!(missing.contains("/nonexistent/c.toml") && missing.contains("cannot read"), "{missing}");
}

#[test]
fn bench_protocols_name_known_methods_and_configs() {
    // The protocols of configs/bench/ are read by xtask; here: every method they name builds.
    // A method may be "registrar@label" with its own entry in [method_configs].
    for entry in std::fs::read_dir(configs_dir().join("bench")).unwrap() {
        let path = entry.unwrap().path();
        let v: toml::Value = toml::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        let pipeline = v["pipeline"].as_str().unwrap();
        let base = PipelineConfig::from_file(&configs_dir().join("..").join(pipeline)).unwrap();
        for m in v["methods"].as_array().unwrap() {
            let label = m.as_str().unwrap();
            let config = match v.get("method_configs").and_then(|t| t.get(label)) {
                Some(p) => match PipelineConfig::from_file(&configs_dir().join("..").join(p.as_str().unwrap())) {
                    Ok(c) => c,
                    // Our network needs the `onnx` build (shipped_configs_need_the_onnx_feature).
                    Err(e) if !cfg!(feature = "onnx") && e.to_string().contains("estimator 'net'") => continue,
                    Err(e) => panic!("{}: {e}", path.display()),
                },
                None => base.clone(),
            };
            let c = PipelineConfig { method: label.split('@').next().unwrap().into(), ..config };
            flowfilter_pipeline::Pipeline::from_config(c).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        }
    }
}

#[test]
fn shipped_configs_need_the_onnx_feature() {
    // configs/onnx/: pipelines with our network; they build exactly when the feature is on, and
    // without it the error says how to get it.
    for entry in std::fs::read_dir(configs_dir().join("onnx")).unwrap() {
        let path = entry.unwrap().path();
        let c = PipelineConfig::from_file(&path);
        if cfg!(feature = "onnx") {
            flowfilter_pipeline::Pipeline::from_config(c.unwrap()).unwrap();
        } else {
            let msg = c.map(|_| ()).unwrap_err().to_string();
            assert!(msg.contains("net") && msg.contains("onnx"), "{}: {msg}", path.display());
        }
    }
}

#[test]
fn validation_checks_names_without_building_and_the_pipeline_builds_each_stage_once() {
    // An ONNX estimator is checked by name when the file is read, and loaded only when the
    // pipeline is built: a missing model is reported then, naming the file.
    let text = "[flow]\nestimator = \"onnx:/no/such/model.onnx\"\n";
    let parsed = PipelineConfig::from_toml_str(text, Path::new("onnx.toml"));
    if cfg!(feature = "onnx") {
        let config = parsed.unwrap();
        let e = flowfilter_pipeline::Pipeline::from_config(config).err().expect("no such model").to_string();
        assert!(e.contains("/no/such/model"), "{e}");
    } else {
        let e = parsed.unwrap_err().to_string();
        assert!(e.contains("onnx.toml") && e.contains("flow.estimator") && e.contains("onnx"), "{e}");
    }
    // A method that reads no correspondences builds no flow estimator: an ONNX name that
    // would fail to load does not matter to it.
    if cfg!(feature = "onnx") {
        let config =
            PipelineConfig::from_toml_str(&format!("method = \"icp-pt2pl\"\n{text}"), Path::new("x.toml")).unwrap();
        let p = flowfilter_pipeline::Pipeline::from_config(config).unwrap();
        assert_eq!(p.method(), "icp-pt2pl");
    }
}
