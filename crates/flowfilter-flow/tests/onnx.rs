//! `OnnxFlow` (feature `onnx`) on the tiny test networks of `tools/peers/onnx_models.py`:
//! tract's output equals onnxruntime's within 1e-4, and contracts that do not match the network
//! are typed errors naming the problem.
#![cfg(feature = "onnx")]

use flowfilter_flow::lk::{Gray, to_gray};
use flowfilter_flow::onnx::{OnnxContract, OnnxFlow};
use flowfilter_flow::{FlowError, FlowEstimator};
use std::path::{Path, PathBuf};

fn models() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/models")
}

fn pair() -> (Gray, Gray) {
    let open = |n: &str| to_gray(&image::open(models().join(n)).unwrap().to_rgb8());
    (open("pair_a.png"), open("pair_b.png"))
}

fn reference(name: &str) -> Vec<f32> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(models().join("reference.json")).unwrap()).unwrap();
    v[name].as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect()
}

#[test]
fn tract_matches_onnxruntime_on_both_networks() {
    let (a, b) = pair();
    for (name, out_size) in [("tiny_warp", (64, 48)), ("tiny_concat", (32, 24))] {
        let net = OnnxFlow::load(&models().join(format!("{name}.onnx"))).unwrap();
        let out = net.network_output(&a, &b).unwrap();
        assert_eq!(out.output_size, out_size, "{name}");
        let expected = reference(name);
        assert_eq!(out.values.len(), expected.len(), "{name}");
        let worst = out.values.iter().zip(&expected).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        println!("{name}: {} values, max |tract - onnxruntime| = {worst:.2e}", expected.len());
        assert!(worst < 1e-4, "{name}: {worst}");
        // The dense field has the image's size and carries the network's flow.
        let f = net.dense(&a, &b, None).unwrap();
        assert_eq!((f.width(), f.height()), (64, 48));
        assert!(f.flow.as_slice().iter().all(|v| v[0].is_finite() && v[1].is_finite()));
        assert_eq!(net.name(), format!("onnx:{name}.onnx"));
    }
}

#[test]
fn dynamic_sizes_are_padded_to_the_contract_multiple() {
    let (a, b) = pair();
    let crop = |g: &Gray| Gray::from_fn(61, 45, |x, y| *g.at(x, y));
    let net = OnnxFlow::load(&models().join("tiny_concat.onnx")).unwrap();
    let out = net.network_output(&crop(&a), &crop(&b)).unwrap();
    assert_eq!(out.input_size, (64, 48));
    let f = net.dense(&crop(&a), &crop(&b), None).unwrap();
    assert_eq!((f.width(), f.height()), (61, 45));
}

fn contract(name: &str) -> OnnxContract {
    OnnxContract::from_file(&models().join(format!("{name}.toml"))).unwrap()
}

fn model_error(r: Result<OnnxFlow, FlowError>) -> String {
    match r {
        Err(e @ FlowError::Model { .. }) => e.to_string(),
        other => panic!("expected a model error, got {other:?}"),
    }
}

#[test]
fn contracts_that_do_not_match_the_network_are_named_errors() {
    let warp = models().join("tiny_warp.onnx");
    let (a, b) = pair();
    // An input name the network does not have.
    let mut c = contract("tiny_warp");
    c.input.names = vec!["image1".into(), "to".into()];
    let msg = model_error(OnnxFlow::with_contract(&warp, c));
    assert!(
        msg.contains("'image1' is not an input") && msg.contains("from, to") && msg.contains("tiny_warp.onnx"),
        "{msg}"
    );
    // One input named where the network has two.
    let mut c = contract("tiny_warp");
    c.input.names = vec!["from".into()];
    let msg = model_error(OnnxFlow::with_contract(&warp, c));
    assert!(msg.contains("2 inputs"), "{msg}");
    // An output name the network does not have.
    let mut c = contract("tiny_warp");
    c.output.name = "flow_up".into();
    assert!(model_error(OnnxFlow::with_contract(&warp, c)).contains("'flow_up' is not an output"));
    // Three channels where the network takes one: caught when the plan is built.
    let mut c = contract("tiny_warp");
    c.input.channels = 3;
    let e = OnnxFlow::with_contract(&warp, c).unwrap().dense(&a, &b, None).unwrap_err();
    assert!(matches!(e, FlowError::Model { .. }) && e.to_string().contains("does not accept"), "{e}");
    // A resolution the output does not have.
    let mut c = contract("tiny_warp");
    c.output.downsample = 2;
    let e = OnnxFlow::with_contract(&warp, c).unwrap().dense(&a, &b, None).unwrap_err();
    assert!(e.to_string().contains("has shape [1, 2, 48, 64]"), "{e}");
    // A contract that contradicts itself, and a missing sidecar.
    let mut c = contract("tiny_concat");
    c.input.mean = vec![0.5];
    assert!(
        model_error(OnnxFlow::with_contract(&models().join("tiny_concat.onnx"), c)).contains("input.mean has 1 values")
    );
    let dir = tempfile::tempdir().unwrap();
    let lonely = dir.path().join("m.onnx");
    std::fs::copy(&warp, &lonely).unwrap();
    assert!(model_error(OnnxFlow::load(&lonely)).contains("cannot read the contract"));
    // Not an ONNX file at all.
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, b"not a model").unwrap();
    std::fs::copy(models().join("tiny_warp.toml"), dir.path().join("junk.toml")).unwrap();
    assert!(model_error(OnnxFlow::load(&junk)).contains("cannot load"));
    // Images of different sizes.
    let net = OnnxFlow::load(&warp).unwrap();
    assert!(matches!(net.dense(&a, &Gray::filled(10, 10, 0.5), None), Err(FlowError::SizeMismatch { .. })));
}

/// The shipped network (`crates/flowfilter-flow/models/ffnet.onnx`, embedded as `net`) on its fixture pair (a
/// held-out object at the network's 640x512 working size, written by
/// `tools/train-flow/reference.py`): tract reproduces onnxruntime's output, and the flow is as
/// accurate against the exact flow as when the reference was recorded.
#[test]
fn shipped_network_matches_its_reference() {
    let net = flowfilter_flow::net::ffnet().unwrap();
    assert_eq!(net.name(), "net");
    let open = |n: &str| {
        let g = image::open(models().join(n)).unwrap().to_luma8();
        Gray::from_fn(g.width() as usize, g.height() as usize, |x, y| {
            f32::from(g.get_pixel(x as u32, y as u32).0[0]) / 255.0
        })
    };
    let (a, b) = (open("ffnet_pair_a.png"), open("ffnet_pair_b.png"));
    let out = net.network_output(&a, &b).unwrap();
    assert_eq!(out.output_size, (640, 512));
    let r: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(models().join("ffnet_reference.json")).unwrap()).unwrap();
    let (w, h) = out.output_size;
    let points = r["points"].as_array().unwrap();
    let mut worst = 0.0f32;
    for (p, v) in points.iter().zip(r["network"].as_array().unwrap()) {
        let (x, y) = (p[0].as_u64().unwrap() as usize, p[1].as_u64().unwrap() as usize);
        for c in 0..2 {
            worst = worst.max((out.values[c * w * h + y * w + x] - v[c].as_f64().unwrap() as f32).abs());
        }
    }
    println!("{} points, max |tract - onnxruntime| = {worst:.2e} px", points.len());
    assert!(worst < 1e-3, "{worst}");
    // Accuracy through the estimator interface (dense field at the pair's size).
    let f = net.dense(&a, &b, None).unwrap();
    let (mut sum, mut n) = (0.0f64, 0usize);
    for (p, t) in points.iter().zip(r["truth"].as_array().unwrap()) {
        if t.is_null() {
            continue;
        }
        let (x, y) = (p[0].as_u64().unwrap() as usize, p[1].as_u64().unwrap() as usize);
        let e = f.at(x, y).unwrap();
        sum += (f64::from(e[0]) - t[0].as_f64().unwrap()).hypot(f64::from(e[1]) - t[1].as_f64().unwrap());
        n += 1;
    }
    let epe = sum / n as f64;
    let recorded = r["epe_at_points"].as_f64().unwrap();
    println!("EPE at {n} points with exact flow: {epe:.3} px (recorded {recorded:.3})");
    assert!(n > 300 && (epe - recorded).abs() < 0.01, "{epe} vs {recorded}");
}

#[test]
fn networks_from_bytes_report_bad_bytes_and_contracts_by_label() {
    let contract = OnnxContract::from_toml(flowfilter_flow::net::CONTRACT, "ffnet.toml").unwrap();
    let e = OnnxFlow::from_bytes("broken-model", b"not an onnx graph", contract).unwrap_err();
    assert!(matches!(e, FlowError::Model { .. }) && e.to_string().contains("broken-model"), "{e}");
    let e = OnnxContract::from_toml("[input]\nnames = []\nchannels = 1\n[output]\nname = \"flow\"\n", "inline.toml")
        .unwrap_err();
    assert!(e.to_string().contains("inline.toml") && e.to_string().contains("input.names"), "{e}");
}
